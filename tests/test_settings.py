"""Mission parameters (vehicle.settings): defaults, ``--set``, TOML files, scene hints, MAVLink ids."""

import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from vehicle.agent.settings import Settings, SettingsError, load_settings, scene_defaults
from vehicle.lab.presets import PRESETS
from vehicle.protocol.map_bounds import MAX_SIDE
from vehicle.world.scene import parse_scene

ROOT = Path(__file__).resolve().parents[1]


def documented_table() -> dict[str, tuple[str, float, tuple[float, float]]]:
    """name -> (unit, default, (lowest, highest)) from the mission-parameter table of docs/missions.md."""
    text = (ROOT / "docs" / "missions.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \| ([^|]+) \| ([-\d.e]+) to ([-\d.e]+) \|", text,
                      flags=re.MULTILINE)
    assert rows, "no parameter table in docs/missions.md"
    return {name: (unit.strip(), float(default), (float(lo), float(hi))) for name, unit, default, lo, hi in rows}


def test_defaults_and_ranges_match_the_documented_table():
    table = documented_table()
    described = {name: (unit, default, bounds) for name, default, unit, _, _, bounds in Settings.describe()}
    assert described == table


def test_defaults_are_the_documented_values():
    s = Settings()
    assert (s.altitude, s.speed, s.space_size, s.resolution, s.padding) == (4.0, 2.5, 100, 10, 0.5)
    assert (s.closeness, s.farness, s.yaw_step, s.monitor_period, s.time_limit) == (2.0, 100, 10, 0.25, 600)


def test_describe_lists_every_setting_in_order_with_help():
    names = [row[0] for row in Settings.describe()]
    assert names == list(Settings.model_fields)
    assert all(row[3] for row in Settings.describe())  # help text


def test_mavlink_param_ids_fit_16_characters_and_are_unique():
    ids = [row[4] for row in Settings.describe()]
    assert all(0 < len(i) <= 16 for i in ids)
    assert all(re.fullmatch(r"[A-Z0-9_]+", i) for i in ids)
    assert len(set(ids)) == len(ids)
    assert sorted(Settings.param_ids().values()) == sorted(Settings.model_fields)


# ---- --set --------------------------------------------------------------------------------------
def test_set_assignments_are_parsed_and_converted():
    s = Settings().with_assignments(["speed=3", " padding = 1.25 ", "yaw_step=15"])
    assert s.speed == 3.0 and s.padding == 1.25 and s.yaw_step == 15.0
    assert isinstance(s.speed, float)
    assert Settings().speed == 2.5  # the original is untouched


def test_a_later_set_wins():
    assert Settings().with_assignments(["speed=3", "speed=4"]).speed == 4


@pytest.mark.parametrize("assignment, message", [
    ("speed=fast", "speed"),
    ("speed=0", "speed"),  # must be positive
    ("monitor_period=0.01", "monitor_period"),
    ("padding=-1", "padding"),
    # floors below which a mission cannot work: a copter that never leaves the ground, a vehicle too slow to
    # get anywhere, a waypoint never reached, a scan of 3.6e32 steps, a map of one cell
    ("altitude=0.2", "altitude"),
    ("speed=1e-30", "speed"),
    ("closeness=1e-6", "closeness"),
    ("yaw_step=1e-6", "yaw_step"),
    ("space_size=0.001", "space_size"),
    ("farness=1e-6", "farness"),
    ("time_limit=1e-30", "time_limit"),
])
def test_bad_values_are_refused_with_the_setting_named(assignment, message):
    with pytest.raises(SettingsError, match=message):
        Settings().with_assignments([assignment])


def test_a_map_bigger_than_a_ground_station_takes_is_refused_both_ways():
    """A station refuses map streams over MAX_SIDE cells a side; the settings never make one."""
    with pytest.raises(SettingsError, match=f"at most {MAX_SIDE}"):
        Settings().with_assignments(["space_size=1000"])  # 20,000 cells a side at 10 cells/m
    settings = Settings().with_assignments(["space_size=1000", "resolution=2"])  # 4000: the largest
    assert round(2 * settings.space_size * settings.resolution) == MAX_SIDE
    with pytest.raises(ValidationError):
        settings.resolution = 2.5  # checked on assignment too (a PARAM_SET)


def test_the_defaults_and_every_preset_sweep_fit_the_map_stream():
    assert round(2 * Settings().space_size * Settings().resolution) <= MAX_SIDE
    for preset in PRESETS.values():
        grid = preset["grid"]
        for space in grid.get("space_size", [Settings().space_size]):
            for resolution in grid.get("resolution", [Settings().resolution]):
                assert Settings(space_size=space, resolution=resolution)


def test_an_unknown_name_is_refused_and_the_known_ones_listed():
    with pytest.raises(SettingsError, match="unknown setting bogus") as error:
        Settings().with_assignments(["bogus=1"])
    assert "closeness" in str(error.value)


@pytest.mark.parametrize("assignment", ["speed", "=3", " =3", ""])
def test_an_assignment_without_name_and_equals_is_refused(assignment):
    with pytest.raises(SettingsError, match="name=value"):
        Settings().with_assignments([assignment])


def test_assigning_an_attribute_is_validated():
    s = Settings()
    with pytest.raises(ValidationError):
        s.speed = -1
    with pytest.raises(ValidationError):
        Settings(nonsense=1)


def test_settings_error_is_a_value_error():
    assert issubclass(SettingsError, ValueError)


# ---- TOML --------------------------------------------------------------------------------------
def test_toml_at_the_top_level(tmp_path):
    path = tmp_path / "flat.toml"
    path.write_text("altitude = 6\ncloseness = 1.5\n")
    s = Settings().with_config(path)
    assert s.altitude == 6 and s.closeness == 1.5 and s.speed == 2.5


def test_toml_under_a_settings_table(tmp_path):
    path = tmp_path / "table.toml"
    path.write_text('title = "ignored"\n\n[settings]\nspeed = 4.0\nresolution = 5\n')
    s = Settings().with_config(path)
    assert s.speed == 4 and s.resolution == 5


@pytest.mark.parametrize("text, message", [("speed = \n", "bad.toml"), ("bogus = 1\n", "bogus"),
                                           ("speed = -3\n", "speed")])
def test_bad_toml_is_refused_with_a_message(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SettingsError, match=message):
        Settings().with_config(path)


def test_a_missing_toml_file_is_a_settings_error(tmp_path):
    with pytest.raises(SettingsError, match="absent.toml"):
        Settings().with_config(tmp_path / "absent.toml")


# ---- precedence and scene hints ---------------------------------------------------------------
def test_scene_defaults_keep_only_settings():
    hints = {"altitude": "1.6", "waypoints": "1,2; 3,4", "author": "someone"}
    assert scene_defaults(hints) == {"altitude": "1.6"}


def test_load_settings_applies_defaults_hints_config_set_and_options_in_that_order(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text("padding = 1.0\nspeed = 3.0\n")
    hints = {"altitude": "1.6", "padding": "0.2", "closeness": "1.0", "waypoints": "0,1"}
    s = load_settings(config, ["speed=3.5", "closeness=1.2"], hints, altitude=None, time_limit=99.0)
    assert s.altitude == 1.6  # hint, nothing above it
    assert s.padding == 1.0  # config over hint
    assert s.speed == 3.5  # --set over config
    assert s.closeness == 1.2  # --set over hint
    assert s.time_limit == 99  # an explicit option over everything
    assert s.resolution == 10  # default


def test_set_wins_over_a_scene_hint():
    assert load_settings(assignments=["altitude=3"], scene_hints={"altitude": "1.6"}).altitude == 3


def test_a_bad_scene_hint_is_a_settings_error():
    with pytest.raises(SettingsError, match="altitude"):
        load_settings(scene_hints={"altitude": "high"})


def test_hints_from_a_worldinfo_reach_the_settings():
    scene = parse_scene('#VRML V2.0 utf8\nWorldInfo { info ["altitude=1.6" "padding=0.3" "title=house"] }\n'
                        "Shape { geometry Box { size 1 1 1 } }\n")
    s = load_settings(scene_hints=scene.hints)
    assert s.altitude == 1.6 and s.padding == 0.3


def test_load_settings_without_anything_gives_the_defaults():
    assert load_settings() == Settings()
