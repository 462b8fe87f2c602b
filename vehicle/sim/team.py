"""A team: several simulated vehicles in one scene, on one simulated clock, each a body to the others.

Why it is split this way: each vehicle stays a whole ``Simulation`` (its body,
autopilot, sensors, battery, its own collider against the scene), exactly as
when it flies alone, and the team only adds what lies between vehicles. A team
step is two halves over every vehicle: all bodies move (``Simulation.move``,
checked against the scene), then every pair is checked over that same step,
then all sonars read (``Simulation.sense``) with the other bodies as spheres
to echo off. So one vehicle costs what it costs alone, plus a pair check per
step in plain floats and, per read, a compiled pick of the bodies within sonar
range and inside a cone: a read with none costs what a lone one does, and
only the bodies picked meet the rays (a compiled ray-sphere loop). What the
agents ask of their team-mates (``traffic``) is made once a step. The same
vehicles given the same seeds fly the same way, whatever the machine.

Two bodies collide when their centres, each moving in a straight line over the
step, come closer than the sum of their radii (the closest approach of two
linearly moving points); the contact names both vehicles and both become
wrecks where they first touched. The team also keeps the closest approach
between any two bodies, and between each body and the scene's walls.
"""

from __future__ import annotations

import math

import numpy as np

from vehicle.protocol.traffic import Traffic
from vehicle.sim.simulation import PlacementError, Simulation
from vehicle.world.collision import WALKABLE_NORMAL_Z, Collider, Contact, TriangleGrid
from vehicle.world.sonar import Bodies

SCENE_GAP_REACH = 5.0  # m: the scene's walls further than this from a body's centre are not measured


class Team:
    def __init__(self, simulations: list[Simulation], ids: list[int] | None = None):
        """``ids``: the vehicles' MAVLink system ids (default 1, 2, ...). Raises PlacementError for an empty
        team, two vehicles with one id, or two that start inside each other."""
        if not simulations:
            raise PlacementError("a team needs at least one vehicle")
        ids = list(ids) if ids is not None else list(range(1, len(simulations) + 1))
        if len(ids) != len(simulations):
            raise PlacementError(f"{len(ids)} system ids for {len(simulations)} vehicles")
        repeated = sorted({i for i in ids if ids.count(i) > 1})
        if repeated:
            raise PlacementError(f"two vehicles have the system id {repeated[0]}: each needs its own")
        self.simulations = simulations
        self.ids = ids
        self.radii = np.array([s.limits.radius for s in simulations])
        centres = self._centres()
        for i, j in zip(*np.triu_indices(len(simulations), 1), strict=True):
            if np.linalg.norm(centres[i] - centres[j]) < self.radii[i] + self.radii[j]:
                raise PlacementError(f"vehicles {ids[i]} and {ids[j]} start inside each other (at "
                                     f"{_where(centres[i])} and {_where(centres[j])})")
        self.closest_gap = math.inf  # m between the surfaces of the two bodies that came closest
        self.closest_pair: tuple[int, int] | None = None
        self.scene_gaps = [_SceneGap(s) for s in simulations]
        self._pair_list = [(i, j, float(self.radii[i] + self.radii[j]))
                           for i in range(len(simulations)) for j in range(i + 1, len(simulations))]
        self._ids = np.array(ids)
        self._travelled = [0.0] * len(simulations)  # m each body has moved, as the pair check saw it
        self._last = [s.body.pose.xyz() for s in simulations]
        self._anchors: list[tuple[float, float, float] | None] = [None] * len(self._pair_list)
        self._radii = self.radii.tolist()
        self._traffic: list[Traffic] = []
        self._traffic_steps = -1

    def __len__(self) -> int:
        return len(self.simulations)

    @property
    def time(self) -> float:
        return self.simulations[0].time

    def _centres(self) -> np.ndarray:
        return np.array([s.body.pose.xyz() for s in self.simulations], dtype=np.float64)

    def step(self) -> list[list]:
        """One step of every vehicle: move all, collide pairs, then read every sonar. Returns each vehicle's
        readings, in the team's order."""
        sims = self.simulations
        if len(sims) == 1:  # a team of one: no pair to check, no other body to sense; as cheap as alone
            (simulation,) = sims
            simulation.move()
            if not simulation.reading_due:
                return [[]]
            self.scene_gaps[0].note(simulation.body.pose.xyz())
            return [simulation.sense(None)]
        moves = [s.move() for s in sims]
        self._collide(moves)
        readings = []
        centres = None  # every body's centre, taken once a step when some sonar reads (all moved by then)
        for index, (gap, simulation) in enumerate(zip(self.scene_gaps, sims, strict=True)):
            if not simulation.reading_due:  # ten times a second is enough for the scene-gap figure too
                readings.append([])
                continue
            if centres is None:
                centres = [s.body.pose.xyz() for s in sims]
                points, gaps = self._gaps(centres)
            gap.note(centres[index])
            readings.append(simulation.sense(self._near(index, simulation.sonars.reach, points, gaps)))
        return readings

    def _gaps(self, centres: list[tuple[float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
        """The centres as an array, and gaps[i, k]: metres from body i's centre to body k's surface (the
        diagonal: never near). Once a step for every read: in plain floats per read, a team of 8 spent a
        tenth of its world's time on it."""
        points = np.array(centres, dtype=np.float64)
        gaps = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)) - self.radii[None, :]
        np.fill_diagonal(gaps, math.inf)
        return points, gaps

    def _near(self, index: int, within: float, points: np.ndarray, gaps: np.ndarray) -> Bodies | None:
        """Every body but vehicle ``index``'s (wrecks too: they still stand in the way) whose surface is
        within ``within`` metres of its centre; None when there is none (then a read costs what it does alone)."""
        near = np.flatnonzero(gaps[index] <= within)
        if not len(near):
            return None
        return Bodies(self._ids[near], points[near], self.radii[near])

    def traffic(self) -> list[Traffic]:
        """Every vehicle as its team-mates know it now, in the team's order: made once a step, however many
        agents ask how many times (each agent asks for its team-mates several times a step)."""
        steps = self.simulations[0].steps
        if self._traffic_steps != steps:
            now = self.simulations[0].time
            self._traffic = [Traffic(vehicle, *sim.body.pose.xyz(), sim.body.vx, sim.body.vy, sim.limits.radius, now)
                             for vehicle, sim in zip(self.ids, self.simulations, strict=True)]
            self._traffic_steps = steps
        return self._traffic

    def _collide(self, moves: list) -> None:
        """Check every pair over the step just taken (a wreck stands where it lies); note the closest.
        In plain floats: a few pairs cost less so than numpy's calls on arrays of a few rows. A pair is checked
        exactly only when it could touch or come closer than the closest yet: its gap at its last exact check,
        less the way both bodies have gone since, bounds its gap now from below (most pairs of a team are far
        apart most of the time)."""
        sims, travelled, last = self.simulations, self._travelled, self._last
        paths = []
        for k, (sim, move) in enumerate(zip(sims, moves, strict=True)):
            if move is None:
                here = sim.body.pose.xyz()
                move = (here, here)
            travelled[k] += math.dist(last[k], move[0]) + math.dist(move[0], move[1])
            last[k] = move[1]
            paths.append(move)
        contacts = []
        for pair, (i, j, reach) in enumerate(self._pair_list):
            anchor = self._anchors[pair]
            if anchor is not None:
                bound = anchor[0] - (travelled[i] - anchor[1]) - (travelled[j] - anchor[2])
                if bound > 0.0 and bound >= self.closest_gap:
                    continue
            (ai, bi), (aj, bj) = paths[i], paths[j]
            gx, gy, gz = aj[0] - ai[0], aj[1] - ai[1], aj[2] - ai[2]  # j's centre seen from i's, at the start
            cx = (bj[0] - bi[0]) - gx  # and how that changes over the step
            cy = (bj[1] - bi[1]) - gy
            cz = (bj[2] - bi[2]) - gz
            speed2 = cx * cx + cy * cy + cz * cz
            when = min(1.0, max(0.0, -(gx * cx + gy * cy + gz * cz) / speed2)) if speed2 > 1e-18 else 0.0
            gap = math.sqrt((gx + when * cx) ** 2 + (gy + when * cy) ** 2 + (gz + when * cz) ** 2) - reach
            self._anchors[pair] = (math.sqrt((gx + cx) ** 2 + (gy + cy) ** 2 + (gz + cz) ** 2) - reach,
                                   travelled[i], travelled[j])  # the gap at the step's end
            if gap < self.closest_gap:
                self.closest_gap = gap
                self.closest_pair = (self.ids[i], self.ids[j])
            if gap < 0 and not (moves[i] is None and moves[j] is None):  # two wrecks lie still
                contacts.append((i, j, _first_touch((gx, gy, gz), (cx, cy, cz), reach)))
        for i, j, fraction in contacts:
            for index in (i, j):
                start, end = paths[index]
                point = np.array(start) + fraction * (np.array(end) - np.array(start))
                contact = Contact(point=point, fraction=fraction, face=-1, vehicles=(self.ids[i], self.ids[j]))
                if sims[index].collision is None:
                    sims[index].crash(contact)


class _SceneGap:
    """The closest a body came to the scene's walls (the ground a copter takes off from and lands on is no
    obstacle). Measured exactly only where it could be a new closest:
    the clearance at the last measured point, less the way gone since, bounds it from below."""

    def __init__(self, simulation: Simulation):
        scene = simulation.scene
        grid = scene.prepared("walls", lambda: TriangleGrid(_Walls(scene)))
        self.collider = Collider(grid, simulation.limits.radius, search=2 * SCENE_GAP_REACH)
        self.radius = simulation.limits.radius
        self.closest = math.inf  # m from the body's centre
        self._anchor: tuple[float, float, float] | None = None
        self._clear = 0.0

    def note(self, centre: tuple[float, float, float]) -> None:
        worth = min(self.closest, SCENE_GAP_REACH)
        if self._anchor is not None and self._clear - math.dist(centre, self._anchor) >= worth:
            return
        self._anchor, self._clear = centre, self.collider.clearance(np.array(centre))
        if self._clear < SCENE_GAP_REACH:
            self.closest = min(self.closest, self._clear)

    @property
    def gap(self) -> float | None:
        """Metres between the body's surface and the nearest wall it came to; None if never within reach."""
        return None if math.isinf(self.closest) else self.closest - self.radius


class _Walls:
    """The scene's faces steeper than 45 degrees, up or down (not the ground, a roof or a box's underside)."""

    def __init__(self, scene):
        steep = np.abs(np.asarray(scene.face_normals)[:, 2]) <= WALKABLE_NORMAL_Z
        self.triangles = np.asarray(scene.triangles, dtype=np.float64).reshape(-1, 3, 3)[steep]
        self.face_normals = np.asarray(scene.face_normals)[steep]


def _first_touch(gap0: tuple[float, float, float], change: tuple[float, float, float], reach: float) -> float:
    """The first fraction of the step at which |gap0 + t change| = reach (0 if already touching)."""
    a = sum(v * v for v in change)
    b = 2.0 * sum(g * v for g, v in zip(gap0, change, strict=True))
    c = sum(g * g for g in gap0) - reach * reach
    if c <= 0 or a <= 1e-18:
        return 0.0
    root = b * b - 4 * a * c
    return min(1.0, max(0.0, (-b - math.sqrt(max(root, 0.0))) / (2 * a)))


def _where(centre: np.ndarray) -> str:
    return f"x={centre[0]:.2f} y={centre[1]:.2f}"
