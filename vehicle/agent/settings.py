"""Mission parameters: one validated model, set from defaults, a TOML file, ``--set`` and MAVLink.

Each setting has a unit, a default, a help text, the short MAVLink parameter
id (at most 16 characters) under which standard parameter editors see it, and
a range. The floors keep missions possible (a copter asked to fly at 1e-30 m
never left the ground, and said nothing); the ceilings keep them sane.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from vehicle.protocol.map_bounds import MAX_RESOLUTION, MAX_SIDE, MAX_SPACE, MIN_RESOLUTION


def _setting(default: float, unit: str, help: str, param_id: str, **bounds) -> float:
    return Field(default, description=help, json_schema_extra={"unit": unit, "param_id": param_id}, **bounds)


class Settings(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    altitude: float = _setting(4.0, "m", "operating height above the start's ground (copter)", "SCN_ALTITUDE",
                               ge=0.5, le=120)
    speed: float = _setting(2.5, "m/s", "cruise speed", "SCN_SPEED", ge=0.1, le=20)
    space_size: float = _setting(100.0, "m", "half-width of the memory map and of the allowed space around home",
                                 "SCN_SPACE_SIZE", ge=1, le=MAX_SPACE)
    resolution: float = _setting(10.0, "cells/m", "memory-map resolution", "SCN_RESOLUTION",
                                 ge=MIN_RESOLUTION, le=MAX_RESOLUTION)
    padding: float = _setting(0.5, "m", "clearance kept between the vehicle body and obstacles when planning",
                              "SCN_PADDING", ge=0, le=20)
    closeness: float = _setting(2.0, "m", "distance at which a waypoint counts as reached and an obstacle as "
                                "too close", "SCN_CLOSENESS", ge=0.1, le=50)
    farness: float = _setting(100.0, "m", "readings beyond this are ignored", "SCN_FARNESS", ge=0.1, le=1000)
    yaw_step: float = _setting(10.0, "deg", "yaw increment while scanning", "SCN_YAW_STEP", ge=1, le=180)
    monitor_period: float = _setting(0.25, "s", "how often the monitor and the mission step", "SCN_MON_PERIOD",
                                     ge=0.05, le=5)
    time_limit: float = _setting(600.0, "s", "simulated time limit of a headless run", "SCN_TIME_LIMIT",
                                 ge=1, le=86400)
    separation: float = _setting(2.0, "m", "gap kept between the bodies of two vehicles of a team", "SCN_SEPARATION",
                                 ge=0.5, le=50)
    share_maps: float = _setting(1.0, "0/1", "1: take the team-mates' map updates into the memory map; 0: map alone",
                                 "SCN_SHARE_MAPS", ge=0, le=1)
    drop_depth: float = _setting(0.3, "m", "ground that drops away deeper than this ahead (seen by a sonar looking "
                                 "down) is an obstacle", "SCN_DROP_DEPTH", ge=0.05, le=20)
    max_slope: float = _setting(20.0, "deg", "ground ahead that rises more steeply than this is an obstacle (a rover "
                                "cannot drive up it)", "SCN_MAX_SLOPE", ge=1, le=80)
    # radio tomography (--mission rti, vehicle.agent.missions.rti)
    rti_planner: float = _setting(0.0, "0/1", "rti: 0 (or 'uncertainty'): where the image is least sure; 1 (or "
                                  "'perimeter'): pairs across the region stepping round it", "RTI_PLANNER", ge=0, le=1)
    rti_x0: float = _setting(0.0, "m", "rti: the region's west edge (all four edges 0: the scene's object nearest "
                             "the start)", "RTI_X0", ge=-MAX_SPACE, le=MAX_SPACE)
    rti_y0: float = _setting(0.0, "m", "rti: the region's south edge", "RTI_Y0", ge=-MAX_SPACE, le=MAX_SPACE)
    rti_x1: float = _setting(0.0, "m", "rti: the region's east edge", "RTI_X1", ge=-MAX_SPACE, le=MAX_SPACE)
    rti_y1: float = _setting(0.0, "m", "rti: the region's north edge", "RTI_Y1", ge=-MAX_SPACE, le=MAX_SPACE)
    rti_dwell: float = _setting(3.0, "s", "rti: time the team holds at a pair of spots while the radios measure",
                                "RTI_DWELL", ge=0.5, le=600)
    rti_offset: float = _setting(1.5, "m", "rti: how far outside the region the spots lie", "RTI_OFFSET",
                                 ge=0.5, le=50)
    rti_wait: float = _setting(60.0, "s", "rti: how long a vehicle at its spot waits for a late partner before "
                               "it counts as lost", "RTI_WAIT", ge=1, le=3600)
    rti_rounds: float = _setting(40.0, "pairs", "rti: pairs of spots measured before the mission is done",
                                 "RTI_ROUNDS", ge=1, le=10000)

    @field_validator("rti_planner", mode="before")
    @classmethod
    def _planner_by_name(cls, value):
        """--set rti_planner=perimeter as well as =1."""
        names = {"uncertainty": 0.0, "perimeter": 1.0}
        return names.get(value.strip().lower(), value) if isinstance(value, str) else value

    @model_validator(mode="after")
    def _region(self) -> Settings:
        edges = (self.rti_x0, self.rti_y0, self.rti_x1, self.rti_y1)
        if any(edges) and not (self.rti_x1 > self.rti_x0 and self.rti_y1 > self.rti_y0):
            raise ValueError(f"the rti region {','.join(f'{v:g}' for v in edges)} has no area (need rti_x0 < "
                             "rti_x1 and rti_y0 < rti_y1, or all four 0 for the object nearest the start)")
        return self

    @model_validator(mode="after")
    def _map_fits_the_stream(self) -> Settings:
        """A ground station refuses maps over MAX_SIDE cells a side (what a hostile stream could claim), so the
        vehicle never makes one."""
        side = round(2 * self.space_size * self.resolution)
        if side > MAX_SIDE:
            raise ValueError(f"space_size {self.space_size:g} m at resolution {self.resolution:g} cells/m makes a "
                             f"map {side} cells a side; at most {MAX_SIDE} (2 * space_size * resolution)")
        return self

    @classmethod
    def describe(cls) -> list[tuple[str, float, str, str, str, tuple[float, float]]]:
        """(name, default, unit, help, param_id, (lowest, highest)) for every setting, in declaration order."""
        rows = []
        for name, info in cls.model_fields.items():
            extra = info.json_schema_extra or {}
            lowest = next(bound.ge for bound in info.metadata if hasattr(bound, "ge"))
            highest = next(bound.le for bound in info.metadata if hasattr(bound, "le"))
            rows.append((name, info.default, extra["unit"], info.description, extra["param_id"], (lowest, highest)))
        return rows

    @classmethod
    def param_ids(cls) -> dict[str, str]:
        """MAVLink parameter id -> setting name."""
        return {param_id: name for name, _, _, _, param_id, _ in cls.describe()}

    def updated(self, values: dict[str, object]) -> Settings:
        """A copy with some settings changed; unknown names or bad values raise SettingsError."""
        unknown = sorted(set(values) - set(type(self).model_fields))
        if unknown:
            raise SettingsError(f"unknown setting {', '.join(unknown)}; known: {', '.join(type(self).model_fields)}")
        try:
            return type(self).model_validate({**self.model_dump(), **values})
        except ValidationError as error:
            raise SettingsError(_explain(error)) from None

    def with_config(self, path: str | Path) -> Settings:
        """Settings from a TOML file: ``name = value`` at the top level or under ``[settings]``."""
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
            raise SettingsError(f"{path}: {error}") from None
        data = data.get("settings", data)
        return self.updated(data)

    def with_assignments(self, assignments: list[str]) -> Settings:
        """Apply ``name=value`` strings as given with ``--set``."""
        values: dict[str, object] = {}
        for text in assignments:
            name, sep, value = text.partition("=")
            if not sep or not name.strip():
                raise SettingsError(f"--set wants name=value, not {text!r}")
            values[name.strip()] = value.strip()
        return self.updated(values)


class SettingsError(ValueError):
    pass


def _explain(error: ValidationError) -> str:
    parts = []
    for item in error.errors():
        where = ".".join(str(p) for p in item["loc"])
        if not where:  # a rule across settings: its message names them
            parts.append(item["msg"].removeprefix("Value error, "))
            continue
        parts.append(f"{where}: {item['msg']} (got {item.get('input')!r})")
    return "; ".join(parts)


def scene_defaults(hints: dict[str, str]) -> dict[str, str]:
    """The settings among a scene's hints (its WorldInfo ``name=value`` strings); others are not ours."""
    return {name: value for name, value in hints.items() if name in Settings.model_fields}


def load_settings(config: str | Path | None = None, assignments: list[str] | None = None,
                  scene_hints: dict[str, str] | None = None, **explicit: float | None) -> Settings:
    """Defaults, then the scene's suggestions, then the TOML file, then ``--set`` pairs, then options given."""
    settings = Settings()
    if scene_hints:
        settings = settings.updated(scene_defaults(scene_hints))
    if config:
        settings = settings.with_config(config)
    if assignments:
        settings = settings.with_assignments(assignments)
    given = {name: value for name, value in explicit.items() if value is not None}
    return settings.updated(given) if given else settings
