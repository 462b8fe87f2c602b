"""Rti: fly round a region in pairs of spots, holding at each pair while the radios measure the links between them.

Every vehicle of the team holds the same plan (``vehicle.tomography.planning``: the next spots depend only on the
spots measured before, never on what the radios read), so no one sends anyone a plan. A round: each vehicle
flies to its spot of the round, then holds there and WAITS until every partner is at its own (it sees them as
team traffic: ``FlightController.traffic``), then all dwell ``rti_dwell`` seconds while the radios measure, then
the next round. A partner that is not at its spot ``rti_wait`` seconds after this vehicle reached its own (late,
wrecked, or no longer heard) is lost: the mission says so and goes on with the rest of the team (or alone with
fixed radio nodes), or, left without any link to measure, ends with that reason. A team of two or more, or one
vehicle with fixed radio nodes (``radio_nodes`` of its flight controller).

A spot the vehicle finds it cannot reach (its memory map holds an obstacle there, or no way to it) is moved to
the nearest point within ``SHIFT`` that it can reach, and said: the radios measure wherever they stand (every
record carries its positions), so a link half a metre off the plan is still a link, where giving up lost the
partner too. Its partners take it as there when it has settled within ``SHIFT`` + ``THERE`` of its spot after
moving in this round; the plan itself goes on from the planned spots, so every vehicle still holds the same one.
"""

from __future__ import annotations

import math
from enum import StrEnum

import numpy as np

from vehicle.agent.missions.base import Mission, Status
from vehicle.agent.missions.routines import Travel
from vehicle.agent.traffic import team_mates
from vehicle.tomography.planning import PLANNERS, Planner, nearest_object, ring
from vehicle.world.collision import Collider

ARRIVED = 0.4  # m from its spot at which a vehicle counts as there (itself: the autopilot then settles on it)
THERE = 0.5  # m: a vehicle this close to its spot (a partner: as its traffic tells), and settled, is there
SPACING = 1.0  # m between two candidate spots on the ring round the region
CLEAR_EXTRA = 1.0  # m kept between two spots of a round beyond the team's separation margin
SETTLED = 0.3  # m/s: slower than this at its spot, a vehicle is there
SHIFT = 1.0  # m: how far from an unreachable spot a vehicle looks for one it can reach (the ring's spacing)
SHIFT_STEPS = (0.25, 0.5, 0.75, 1.0)  # m: the distances tried, nearest first, ...
SHIFT_BEARINGS = 12  # ... each in this many directions


class Phase(StrEnum):
    TRAVEL = "travel"
    WAIT = "wait"
    DWELL = "dwell"


def clear_spots(spots: np.ndarray, scene, radius: float, altitude: float, padding: float) -> np.ndarray:
    """The spots where a body of ``radius`` at ``altitude`` above the ground keeps ``padding`` from the scene."""
    collider = Collider(scene, radius, search=radius + padding + 1.0)
    keep = [collider.clearance(np.array([x, y, altitude])) > radius + padding for x, y in spots]
    return spots[np.array(keep, bool)] if len(spots) else spots


def region(settings, scene, home: tuple[float, float]) -> tuple[float, float, float, float]:
    """The region's bounds: the settings', or the scene's object nearest home."""
    edges = (settings.rti_x0, settings.rti_y0, settings.rti_x1, settings.rti_y1)
    if any(edges):
        return edges
    if scene is None:
        raise ValueError("no region given (rti_x0, rti_y0, rti_x1, rti_y1) and no scene to find an object in")
    return nearest_object(scene, home, margin=2.0)


def radio_nodes(fc) -> list[tuple[float, float]]:
    """The fixed radio nodes the flight controller knows of (none by default)."""
    return [tuple(p[:2]) for p in getattr(fc, "radio_nodes", None) or ()]


class Rti(Mission):
    name = "rti"

    def begin(self) -> None:
        ctx, settings = self.ctx, self.ctx.settings
        fc = ctx.fc
        self.me = getattr(fc, "system_id", 1)
        mates = {o.vehicle: o for o in team_mates(fc)}
        self.team = sorted([self.me, *mates])  # the team's system ids, the plan's order
        self.lost: list[int] = []
        self.rounds = 0
        self.phase = Phase.TRAVEL
        self.fixed = radio_nodes(fc)
        self.planner = None
        self.travel = None
        if len(self.team) < 2 and not self.fixed:
            self.reason = "rti needs a team of two or more, or fixed radio nodes"
            return
        # the scene the agent was given, or, in-process, the simulated world's
        scene = ctx.scene if ctx.scene is not None else getattr(getattr(fc, "simulation", None), "scene", None)
        try:
            bounds = region(settings, scene, ctx.home)
        except ValueError as error:
            self.reason = str(error)
            return
        spots = ring(bounds, settings.rti_offset, SPACING)
        if scene is not None:
            spots = clear_spots(spots, scene, ctx.radius, fc.home[2] + settings.altitude, settings.padding)
        kind = PLANNERS[round(settings.rti_planner)]
        apart = settings.separation + 2 * ctx.radius + CLEAR_EXTRA
        try:
            self.planner = Planner(bounds, spots, kind, self.fixed, apart, settings.rti_dwell, settings.speed,
                                   round(settings.rti_rounds))
        except ValueError as error:
            self.reason = str(error)
            return
        self.bounds = bounds
        seen = {self.me: ctx.position, **{k: (o.x, o.y) for k, o in mates.items()}}
        self.previous = [seen[k] for k in self.team]
        ctx.say(f"Rti: {kind} plan round ({bounds[0]:.1f}, {bounds[1]:.1f})-({bounds[2]:.1f}, {bounds[3]:.1f}) "
                f"with vehicles {', '.join(map(str, self.team))}"
                + (f" and {len(self.fixed)} fixed radio nodes" if self.fixed else ""))
        self._next_round()

    def _next_round(self) -> None:
        first = self.planner.steps == 0  # from where each is seen now: see Planner.next_spots
        self.spots = dict(zip(self.team, self.planner.next_spots(self.previous, known=not first), strict=True))
        self.previous = [self.spots[k] for k in self.team]
        self.phase = Phase.TRAVEL
        self.goal = self.spots[self.me]  # where it stops: its spot, or the nearest reachable point to it
        self.travel = Travel(self.ctx, self.goal, ARRIVED)
        self.since = self.ctx.time
        self.moved: set[int] = set()  # partners seen moving since the round began (see ``_there``)

    @property
    def spot(self) -> tuple[float, float]:
        return self.spots[self.me]

    def _shift(self) -> bool:
        """Travel to the nearest point within SHIFT of the spot that the body fits at and a path reaches
        instead, saying so; False when there is none."""
        ctx = self.ctx
        bearings = [2 * math.pi * k / SHIFT_BEARINGS for k in range(SHIFT_BEARINGS)]
        found = ctx.nearest_clear(self.spot, SHIFT_STEPS, bearings, reachable=True)
        if found is None:
            return False
        point, distance = found
        ctx.say(f"Rti: its spot {_at(self.spot)} of round {self.rounds + 1} cannot be reached "
                f"({self.travel.reason}); measuring from {_at(point)}, {distance:g} m off")
        self.goal = point
        self.travel = Travel(ctx, point, ARRIVED)
        return True

    def step(self) -> Status:
        if self.planner is None:
            return Status.STOPPED
        ctx = self.ctx
        self.moved.update(o.vehicle for o in team_mates(ctx.fc) if math.hypot(o.vx, o.vy) >= SETTLED)
        if self.phase is Phase.TRAVEL:
            status = self.travel.step()
            if status is Status.STOPPED and self.goal == self.spot and self._shift():
                return Status.RUNNING
            if status is Status.STOPPED:
                self.reason = (f"could not reach its spot {_at(self.spot)} of round {self.rounds + 1}"
                               + (f" nor any point within {SHIFT:g} m of it" if self.goal != self.spot else "")
                               + f": {self.travel.reason}")
                return status
            if status is Status.DONE:
                self.phase, self.since = Phase.WAIT, ctx.time
                ctx.goto(self.goal)
            return Status.RUNNING
        if self.phase is Phase.WAIT:
            return self._wait()
        if ctx.time - self.since < ctx.settings.rti_dwell:
            return Status.RUNNING
        self.rounds += 1
        if self.rounds >= ctx.settings.rti_rounds:
            self.reason = f"{self.rounds} rounds measured, {self.planner.links} links"
            return Status.DONE
        self._next_round()
        return Status.RUNNING

    def _wait(self) -> Status:
        """Hold at the spot until every partner is at its own; one late beyond ``rti_wait`` is lost."""
        ctx = self.ctx
        heard = {o.vehicle: o for o in team_mates(ctx.fc)}
        late = [k for k in self.team if k != self.me and not self._there(k, heard.get(k))]
        if not late:
            if ctx.distance_to(self.goal) <= THERE and ctx.fc.speed < SETTLED:  # itself settled there too
                self.phase, self.since = Phase.DWELL, ctx.time
            return Status.RUNNING
        if ctx.time - self.since < ctx.settings.rti_wait:
            return Status.RUNNING
        for k in late:
            seen = heard.get(k)
            where = f"last seen at {_at((seen.x, seen.y))}" if seen is not None else "no longer heard"
            ctx.say(f"Rti: partner vehicle {k} did not reach its spot {_at(self.spots[k])} in "
                    f"{ctx.settings.rti_wait:g} s ({where}): lost")
            self.lost.append(k)
            self.team.remove(k)
        if len(self.team) < 2 and not self.fixed:
            self.reason = (f"partner vehicle{'s' if len(late) > 1 else ''} {', '.join(map(str, late))} lost in "
                           f"round {self.rounds + 1}: no link left to measure")
            return Status.STOPPED
        ctx.say(f"Rti: going on with vehicles {', '.join(map(str, self.team))}"
                + (f" and {len(self.fixed)} fixed radio nodes" if self.fixed else ""))
        self.previous = [self.spots[k] for k in self.team]
        self.phase, self.since = Phase.DWELL, ctx.time  # the rest are at their spots: measure this round
        return Status.RUNNING

    def _there(self, vehicle: int, seen) -> bool:
        """Settled at its spot, or settled near it after moving this round (where it may have had to move the
        spot: see ``SHIFT``; a partner still at its last spot, often a metre from this one, has not come)."""
        if seen is None or math.hypot(seen.vx, seen.vy) >= SETTLED:
            return False
        off = math.dist((seen.x, seen.y), self.spots[vehicle])
        return off <= THERE or (off <= SHIFT + THERE and vehicle in self.moved)

    def resume(self) -> None:
        if self.travel is not None and self.phase is Phase.TRAVEL:
            self.travel.resume()
        elif self.planner is not None:
            self.ctx.goto(self.goal)

    def too_close(self) -> Status:
        if self.phase is Phase.TRAVEL:
            status = self.travel.too_close()
            if status is Status.STOPPED:
                self.reason = f"could not reach its spot {_at(self.goal)}: {self.travel.reason}"
            return status
        return Status.RUNNING  # holding at its spot: what came close is the partner or passing traffic

    def out_of_time(self) -> Status:
        links = self.planner.links if self.planner else 0
        self.reason = f"time budget spent after {self.rounds} rounds ({links} links)"
        return Status.STOPPED


def _at(point: tuple[float, float]) -> str:
    return f"({point[0]:.1f}, {point[1]:.1f})"
