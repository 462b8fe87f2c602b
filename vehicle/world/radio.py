"""Simulated radios in the VRML scene: the signal strength of every packet between radios, for radio tomography.

The model (every number a field of ``RadioModel``; ``--radio NAME=VALUE`` on the command line):

* log-distance path loss: ``rss = power_dbm - 10 * path_loss_exponent * log10(d / 1 m)`` over the 3-D distance d
  (no closer than 0.1 m);
* ``wall_loss_db`` for every wall the straight line A-B crosses in the scene's mesh, found by casting rays from A
  towards B as the sonar does (``vehicle.world.raycast``): the surfaces hit along the way are grouped, hits closer
  than ``wall_thickness_m`` to the previous one being the two faces of one wall, so a slab wall costs one loss and
  a line through a closed building two (in and out). Typical values at 2.4 GHz are 4 to 15 dB; ns-3's building
  model uses 5 dB for an inner wall;
* targets (people) are vertical cylinders of ``target_radius_m`` standing on the ground plane: a link whose line,
  seen from above, passes within the radius loses ``target_loss_db``; beyond it the loss fades as a Gaussian of the
  distance past the radius with ``target_fringe_m`` as its standard deviation (a person shadows links near him,
  not only those through him). Heights are not modelled: a copter's link over a person's head is shadowed too;
* a static shadowing offset per link (pair of radios), normal with ``shadowing_sigma_db``, drawn from
  ``shadowing_seed``: a property of the place, so two channels with different seeds (a run and its empty-area
  twin) share it;
* per-packet noise, normal with ``noise_sigma_db`` (0.7 dB: measured on static links of ZigBee-class radios);
* the RSS quantised to ``rss_step_db`` (radios report whole dBm); a packet below ``sensitivity_dbm`` is lost, and
  so is a ``packet_loss`` share of the rest, at random;
* radios transmit in turn: a round has ``slots_per_round`` slots, ``rounds_per_second`` rounds a second; the k-th
  radio (by increasing id) transmits in slot k of each round, every other radio receives.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from vehicle.protocol.radiostream import LinkRecord
from vehicle.world.raycast import RayCaster

MAX_HITS = 64  # surfaces counted along one line at most (a line through a dense mesh stops counting there)
CACHE = 100_000  # lines whose wall count is kept (radios that hold a spot ask the same line again)
NODE_IDS = 200  # fixed radio node k has the id NODE_IDS + k (vehicles keep their system ids)


class RadioModel(BaseModel):
    """The radio model's settings (see the module's docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    power_dbm: float = Field(-40.0, ge=-150, le=30, description="dBm received at 1 m in the open")
    path_loss_exponent: float = Field(2.0, ge=1, le=6, description="log-distance path-loss exponent")
    wall_loss_db: float = Field(5.0, ge=0, le=60, description="dB lost per wall the line A-B crosses")
    wall_thickness_m: float = Field(1.0, gt=0, le=10, description="m: surfaces closer than this along the line "
                                    "are one wall")
    target_radius_m: float = Field(0.3, ge=0, le=5, description="m: a target's (person's) radius")
    target_loss_db: float = Field(4.0, ge=0, le=40, description="dB lost by a link passing within the radius")
    target_fringe_m: float = Field(0.2, ge=0, le=5, description="m: the loss fades past the radius as a Gaussian "
                                   "of this standard deviation")
    shadowing_sigma_db: float = Field(2.0, ge=0, le=20, description="dB: static shadowing per link (std)")
    shadowing_seed: int = Field(0, ge=0, description="seed of the static shadowing (the place, not the run)")
    noise_sigma_db: float = Field(0.7, ge=0, le=20, description="dB: per-packet noise (std)")
    rss_step_db: float = Field(1.0, ge=0, le=10, description="dB: RSS quantisation (0: none)")
    sensitivity_dbm: float = Field(-95.0, ge=-150, le=0, description="dBm: weaker packets are lost")
    packet_loss: float = Field(0.06, ge=0, lt=1, description="share of packets lost at random")
    slots_per_round: int = Field(16, ge=1, le=256, description="transmit slots in a round (radios at most)")
    rounds_per_second: float = Field(5.0, gt=0, le=1000, description="rounds a second")
    channel: int = Field(11, ge=0, le=255, description="the channel the records name (0: unknown)")

    @classmethod
    def from_options(cls, assignments: Iterable[str] | None = None) -> RadioModel:
        """A model from ``NAME=VALUE`` strings (``--radio``); ValueError naming the bad one."""
        values: dict[str, str] = {}
        for text in assignments or ():
            name, sep, value = text.partition("=")
            if not sep or not name.strip():
                raise ValueError(f"--radio wants NAME=VALUE, not {text!r}")
            values[name.strip()] = value.strip()
        unknown = sorted(set(values) - set(cls.model_fields))
        if unknown:
            raise ValueError(f"unknown radio setting {', '.join(unknown)}; known: {', '.join(cls.model_fields)}")
        try:
            return cls.model_validate(values)
        except ValidationError as error:
            raise ValueError("; ".join(f"radio {'.'.join(map(str, e['loc']))}: {e['msg']} (got {e.get('input')!r})"
                                       for e in error.errors())) from None


def parse_targets(text: str) -> list[tuple[float, float]]:
    """``X,Y[;X,Y...]`` (metres east and north of home) as points; ValueError saying which part is wrong."""
    return _parse_points(text, "target")


def parse_nodes(text: str) -> list[tuple[float, float, float]]:
    """Fixed radio nodes ``X,Y[,Z][;X,Y[,Z]...]`` (Z defaults to 1 m above the ground plane), or ``@FILE`` with one
    node a line (``X,Y[,Z]``, ``#`` comments, blank lines skipped)."""
    if text.strip().startswith("@"):
        path = text.strip()[1:]
        try:
            with open(path, encoding="utf-8") as file:
                lines = [line.split("#", 1)[0].strip() for line in file]
        except (OSError, UnicodeDecodeError) as error:
            raise ValueError(f"radio nodes file {path}: {getattr(error, 'strerror', None) or error}") from None
        text = ";".join(line for line in lines if line)
        if not text:
            raise ValueError(f"radio nodes file {path} names no node")
    points = _parse_points(text, "radio node", dims=(2, 3))
    return [(p[0], p[1], p[2] if len(p) > 2 else 1.0) for p in points]


def _parse_points(text: str, what: str, dims: tuple[int, ...] = (2,)) -> list[tuple[float, ...]]:
    shape = " or ".join(",".join("XYZ"[:n]) for n in dims)
    points = []
    for part in text.split(";"):
        if not part.strip():
            continue
        try:
            point = tuple(float(v) for v in part.split(","))
        except ValueError:
            point = ()
        if len(point) not in dims or not all(math.isfinite(v) for v in point):
            raise ValueError(f"{what} {part.strip()!r} is not {shape} (finite metres east and north of home)")
        if any(abs(v) > 100_000 for v in point):
            raise ValueError(f"{what} {part.strip()!r} lies over 100 km from home")
        points.append(point)
    if not points:
        raise ValueError(f"no {what} in {text!r} (expected {shape}[;{shape}...])")
    return points


class RadioChannel:
    """The packets radios exchange in a scene: ``measure`` answers what was received in a span of time."""

    def __init__(self, scene, model: RadioModel | None = None, seed: int = 0):
        self.model = model or RadioModel()
        self.caster = None if scene is None else scene.prepared(("caster", "auto"), lambda: RayCaster(scene))
        self.rng = np.random.default_rng(seed)
        self._walls: dict[tuple, int] = {}
        self._shadowing: dict[tuple[int, int], float] = {}

    @property
    def slot(self) -> float:
        """Seconds per slot."""
        return 1.0 / (self.model.rounds_per_second * self.model.slots_per_round)

    def measure(self, t0: float, t1: float, radios: dict[int, tuple[float, float, float]],
                targets: list[tuple[float, float]]) -> list[LinkRecord]:
        """The packets received in the slots that start in [t0, t1): radio k (k-th smallest id) transmits in slot
        k of each round, every other radio receives it; lost packets are absent. Positions are held through the
        span (a step of the simulation)."""
        ids = sorted(radios)
        if len(ids) > self.model.slots_per_round:
            raise ValueError(f"{len(ids)} radios, but a round has {self.model.slots_per_round} slots "
                             "(--radio slots_per_round=N)")
        if len(ids) < 2 or t1 <= t0:
            return []
        slot, count = self.slot, self.model.slots_per_round
        first, last = math.ceil(t0 / slot - 1e-9), math.ceil(t1 / slot - 1e-9)  # slot numbers starting in [t0, t1)
        records: list[LinkRecord] = []
        for number in range(first, last):
            k = number % count
            if k >= len(ids):
                continue
            tx = ids[k]
            receivers = [rx for rx in ids if rx != tx]
            rssi = self.rss(radios[tx], [radios[rx] for rx in receivers], tx, receivers, targets)
            t = number * slot
            for rx, value in zip(receivers, rssi, strict=True):
                if value is not None:
                    a, b = radios[tx], radios[rx]
                    records.append(LinkRecord(t, tx, rx, float(a[0]), float(a[1]), float(b[0]), float(b[1]), value,
                                              self.model.channel))
        return records

    def rss(self, a, bs: list, tx: int, rxs: list[int], targets) -> list[float | None]:
        """One packet from ``a`` heard at each of ``bs``: its RSS in dBm, None where it is lost."""
        m = self.model
        mean = self.mean_rss(a, bs, targets) + np.array([self.shadowing(tx, rx) for rx in rxs])
        value = mean + self.rng.normal(0.0, m.noise_sigma_db, len(bs)) if m.noise_sigma_db else mean
        if m.rss_step_db:
            value = np.round(value / m.rss_step_db) * m.rss_step_db
        lost = (self.rng.random(len(bs)) < m.packet_loss) | (value < m.sensitivity_dbm)
        return [None if gone else float(v) for v, gone in zip(value, lost, strict=True)]

    def mean_rss(self, a, bs: list, targets) -> np.ndarray:
        """The noiseless RSS (dBm, before shadowing) from ``a`` to each of ``bs``."""
        m = self.model
        a = np.asarray(a, float)
        bs = np.asarray(bs, float).reshape(-1, 3)
        distance = np.maximum(np.linalg.norm(bs - a, axis=1), 0.1)
        value = m.power_dbm - 10.0 * m.path_loss_exponent * np.log10(distance)
        value -= m.wall_loss_db * np.array([self.walls(a, b) for b in bs])
        for target in targets:
            value -= self.target_loss(a[:2], bs[:, :2], target)
        return value

    def target_loss(self, a: np.ndarray, bs: np.ndarray, target) -> np.ndarray:
        """dB a target costs each line a-b (seen from above)."""
        m = self.model
        d = _segment_distance(np.asarray(target, float)[:2], a, bs) - m.target_radius_m
        if m.target_fringe_m <= 0:
            return np.where(d <= 0, m.target_loss_db, 0.0)
        return m.target_loss_db * np.exp(-0.5 * (np.maximum(d, 0.0) / m.target_fringe_m) ** 2)

    def walls(self, a, b) -> int:
        """Walls the straight line a-b crosses in the scene (see the module's docstring)."""
        if self.caster is None:
            return 0
        key = (*np.round(a, 2).tolist(), *np.round(b, 2).tolist())
        count = self._walls.get(key)
        if count is None:
            if len(self._walls) >= CACHE:
                self._walls.clear()
            count = self._walls[key] = self._walls[key[3:] + key[:3]] = self._count_walls(np.asarray(a, float),
                                                                                           np.asarray(b, float))
        return count

    def _count_walls(self, a: np.ndarray, b: np.ndarray) -> int:
        length = float(np.linalg.norm(b - a))
        if length < 1e-6:
            return 0
        direction = (b - a) / length
        hits, travelled = [], 0.0
        while len(hits) < MAX_HITS:
            distance, _ = self.caster.cast(a + direction * travelled, direction)
            step = float(distance[0])
            if not math.isfinite(step) or travelled + step >= length:
                break
            travelled += step
            hits.append(travelled)
            travelled += 1e-4  # past the surface
        walls, previous = 0, -math.inf
        for at in hits:
            if at - previous > self.model.wall_thickness_m:
                walls += 1
            previous = at
        return walls

    def shadowing(self, tx: int, rx: int) -> float:
        """The static shadowing offset (dB) of the link between radios tx and rx (the same both ways)."""
        key = (min(tx, rx), max(tx, rx))
        value = self._shadowing.get(key)
        if value is None:
            sigma = self.model.shadowing_sigma_db
            rng = np.random.default_rng([self.model.shadowing_seed, *key])
            value = self._shadowing[key] = float(rng.normal(0.0, sigma)) if sigma else 0.0
        return value


def _segment_distance(p: np.ndarray, a: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """Distance from point p to each segment a-b (2-D)."""
    ab = bs - a
    length2 = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(np.divide((p - a) @ ab.T, length2, out=np.zeros(len(bs)), where=length2 > 0), 0.0, 1.0)
    closest = a + t[:, None] * ab
    return np.linalg.norm(closest - p, axis=1)
