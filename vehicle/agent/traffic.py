"""Giving way: the other vehicles of a team are moving obstacles, kept ``separation`` metres away.

Every period the agent looks ``HORIZON`` seconds ahead: where it is going (the
heading and reach its autopilot navigates by, at the cruise speed) against
where each team-mate is going (its velocity). When two moving vehicles would
come closer than the separation plus both bodies' radii, the one with the
higher system id gives way (a deterministic rule both ends agree on without
talking): it stops the mission where it is, or, when it stands in the other's
track, steps aside out of it. A team-mate that stands still (scanning,
holding, landed, a wreck) is gone round instead, whatever its id: to the point
beside it, the margin and a metre off, after which the mission plans on. As a
last resort a vehicle waits rather than move closer to a team-mate already
within the margin. Each says what it does, and carries on once the way has
been clear for a second: the mission is never given up for a team-mate, and
its echoes are no walls in the map (``vehicle.agent.monitor``).

It gives way in every phase it flies level (a GUIDED mission, an AUTO one, the way
home): giving way from AUTO switches to GUIDED to hold or step aside, and the
agent switches back to AUTO, which flies on to the waypoint it was flying to.
The margin is a sphere round each body: two vehicles whose tracks cross more
than the margin apart in height (a copter at 4 m over a rover, or over a copter
at 1 m) pass each other, neither gives way. A vehicle that climbs or descends
in place (taking off, landing) keeps out of the column it moves through: it
does not take off under a team-mate, nor land onto one, within the margin
across and in height (``column``), but waits where it is; team-mates flying
level meanwhile go round it as one that stands.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from vehicle.agent.missions.base import Context
from vehicle.protocol.traffic import Traffic

HORIZON = 8.0  # s looked ahead for a conflict
SAMPLES = 33  # times looked at over the horizon (every quarter second)
CLEAR_FOR = 1.0  # s without a conflict before carrying on
ASIDE = 1.0  # m beyond the margin that stepping aside leaves
MOVING = 0.3  # m/s: a team-mate slower than this stands: it has no track to keep out of, it is gone round
DETOUR_REACHED = 0.7  # m from the point beside a team-mate at which going round it is done
DETOUR_FOR = 20.0  # s at most spent going round one
GUARD_EXTRA = 0.5  # s looked ahead by the guard beyond the time to stop
COLUMN_AHEAD = 3.0  # s looked ahead for a team-mate coming into the column a vehicle climbs or descends through
_TIMES = np.linspace(0.0, HORIZON, SAMPLES)
CLOSE_AHEAD = "going round vehicle {}, which stands close ahead"


class GiveWay:
    def __init__(self, ctx: Context, carry_on: Callable[[], None]):
        """``carry_on``: called when the way is clear again, to send again what the mission was doing."""
        self.ctx = ctx
        self.carry_on = carry_on
        self.giving_way_to: int | None = None  # the team-mate given way to now
        self.times = 0  # how often it gave way
        self._wanted = (0.0, 0.0)  # the velocity it wanted when it stopped for a team-mate
        self._clear_since: float | None = None
        self._sent: tuple[float, float] | None = None
        self._said: tuple[int, str] | None = None
        self._detour: tuple[list[tuple[float, float]], float] | None = None  # the legs round a team-mate, till when
        self._others: list[Traffic] = []  # the team-mates known at this step

    def step(self) -> bool:
        """True while the vehicle gives way, goes round a team-mate or waits: the mission is then not stepped."""
        ctx = self.ctx
        fc = ctx.fc
        others = self._others = team_mates(fc)
        busy = self.giving_way_to is not None
        if not others and not busy:
            return False
        if (busy and self._sent is not None and ctx.observation.too_close
                and ctx.distance_to(self._sent) > DETOUR_REACHED):  # held back on its way somewhere
            self._held_back()
        wanted = self._wanted if busy else self._intent()
        me = getattr(fc, "system_id", 1)
        conflicts = [o for o in others if self._conflict(wanted, o)]
        standing = [o for o in conflicts if _stands(o)]
        moving_lower = [o for o in conflicts if o.vehicle < me and o not in standing]
        # the guard, before any rule or detour, judges what the vehicle flies now (towards what was sent
        # while it gives way, else the mission's way): never fly into a team-mate's margin
        close = self._closing_in(self._flying() if busy else wanted, others)
        if close is not None:
            self._detour = None
            if _stands(close):  # whatever its id: one that stands moves for no one, so it is gone round
                self._go_round(close, wanted, CLOSE_AHEAD)
            elif close.vehicle < me:
                self._begin(close, wanted, "giving way to vehicle {} (lower system id), which is close")
                self._keep_out_of(close)
            else:
                self._begin(close, wanted, "waiting: vehicle {} is too close ahead")
                self._hold()
            return True
        if moving_lower:  # the rule: the higher system id gives way to the lower
            other = min(moving_lower, key=lambda o: o.vehicle)
            self._begin(other, wanted, "giving way to vehicle {} (lower system id)")
            self._keep_out_of(other)
            return True
        if self._detour is not None and self._detouring():
            return True
        if standing:  # a team-mate that stands in the way (scanning, holding, landed): go round it
            other = min(standing, key=lambda o: math.hypot(o.x - fc.pose.x, o.y - fc.pose.y))
            said_close = self._said == (other.vehicle, CLOSE_AHEAD)
            self._go_round(other, wanted, None if said_close else "going round vehicle {}, which stands in the way")
            return True
        other = self._too_close_ahead(wanted, others)
        if other is not None:
            self._begin(other, wanted, "waiting: vehicle {} is too close ahead")
            self._hold()
            return True
        if not busy:
            return False
        now = ctx.time
        self._clear_since = now if self._clear_since is None else self._clear_since
        if now - self._clear_since < CLEAR_FOR:
            return True
        ctx.say(f"Traffic: clear of vehicle {self.giving_way_to}; carrying on")
        self.giving_way_to, self._sent, self._clear_since, self._detour, self._said = None, None, None, None, None
        self.carry_on()
        return False

    def _begin(self, other: Traffic, wanted: tuple[float, float], what: str) -> None:
        """Say once what it does for which team-mate; the velocity it wanted is kept till the way is clear."""
        self._clear_since = None
        if self.giving_way_to is None:
            self._wanted = wanted
            self.times += 1
        key = (other.vehicle, what)
        if key != self._said:
            x, y = self.ctx.position
            self.ctx.say(f"Traffic: {what.format(other.vehicle)} at ({x:.1f}, {y:.1f})")
            self._said = key
        self.giving_way_to = other.vehicle

    def _held_back(self) -> None:
        """On its way aside or round, something too close ahead (the autopilot's avoidance holds it back, or
        the sonar sees it) that the map does not block: a pine crown's rim just above the sonars' plane, whose
        echo the autopilot then forgot, once let a copter fly on into it. The obstacle goes into the map where
        it was met, so no way aside or round goes through it again, and the vehicle holds for now."""
        ctx = self.ctx
        x, y = ctx.position
        dx, dy = self._sent[0] - x, self._sent[1] - y
        distance = math.hypot(dx, dy)
        pose = ctx.fc.pose
        near = any(math.dist((pose.x, pose.y, pose.z), (o.x, o.y, o.z)) < self._margin(o) for o in self._others)
        if not near:  # a team-mate within the margin may be what holds it back: no wall
            ahead = ctx.observation.nearest_ahead
            reach = ahead if ahead is not None else ctx.radius + 1.0 / ctx.map.resolution
            ctx.map.add_reading(np.array([x, y, pose.z]), np.array([dx / distance, dy / distance, 0.0]),
                                reach, reach + 1.0, free=False)
            ctx.say(f"Traffic: held back on the way at ({x:.1f}, {y:.1f}): an obstacle {reach:.1f} m ahead; "
                    "holding")
        self._detour = None
        self._sent = None  # hold here, even within half a metre of where it was sent
        self._hold()

    def _hold(self) -> None:
        self._send(self.ctx.position)

    def _send(self, target: tuple[float, float]) -> None:
        if self.ctx.fc.mode != "GUIDED":  # an AUTO mission: the agent steers while it gives way
            self.ctx.fc.set_mode("GUIDED")
            self._sent = None
        if self._sent is None or math.dist(target, self._sent) > 0.5:
            self.ctx.goto(target)
            self._sent = target

    def _go_round(self, other: Traffic, wanted: tuple[float, float], what: str | None) -> None:
        """Step sideways off the way it wants to go, to the margin and a metre from the team-mate's line, on
        the side it is already on, then fly level with the team-mate: two legs that never come closer to it
        (one straight leg to beside it cuts into its margin when it is near). The mission plans on from there.
        Two vehicles going round each other head on both turn to their right, away from each other. Says ``what``
        it does (None: said already), or that it waits when neither side is clear."""
        ctx = self.ctx
        x, y = ctx.position
        speed = math.hypot(*wanted)
        ux, uy = (wanted[0] / speed, wanted[1] / speed) if speed > 0 else (0.0, 1.0)
        rx, ry = x - other.x, y - other.y
        along = rx * ux + ry * uy
        nx, ny = rx - along * ux, ry - along * uy
        off = math.hypot(nx, ny)
        nx, ny = (nx / off, ny / off) if off > 0.1 else (uy, -ux)  # right on its line: round its right
        reach = self._margin(other) + ASIDE
        for side in (1.0, -1.0):  # this side, else the other
            beside = (other.x + side * nx * reach, other.y + side * ny * reach)
            aside = (beside[0] + along * ux, beside[1] + along * uy)  # level with here
            legs = [aside, beside] if along < 0 else [aside]  # once level with it or past, stepping aside does
            if self._safe(legs):
                if what is not None:
                    self._begin(other, wanted, what)
                self._detour = (legs, ctx.time + DETOUR_FOR)
                self._send(legs[0])
                return
        self._begin(other, wanted, "waiting: no way round vehicle {}, which stands in the way")
        self._hold()

    def _detouring(self) -> bool:
        """Still on the way round (not at its last point yet, and not for too long)."""
        legs, until = self._detour
        if self.ctx.time < until:
            while legs and self.ctx.distance_to(legs[0]) <= DETOUR_REACHED:
                legs.pop(0)
            if legs:
                self._send(legs[0])
                return True
        self._detour = None
        return False

    def _flying(self) -> tuple[float, float]:
        """The velocity it flies while giving way: towards what it sent, at the cruise speed (none when
        there)."""
        if self._sent is None:
            return 0.0, 0.0
        x, y = self.ctx.position
        dx, dy = self._sent[0] - x, self._sent[1] - y
        distance = math.hypot(dx, dy)
        if distance < DETOUR_REACHED:
            return 0.0, 0.0
        speed = self.ctx.speed
        return speed * dx / distance, speed * dy / distance

    def _margin(self, other: Traffic) -> float:
        return self.ctx.settings.separation + self.ctx.radius + other.radius

    def _intent(self) -> tuple[float, float]:
        """The velocity the vehicle is about to fly: towards its autopilot's target at the cruise speed."""
        navigation = self.ctx.fc.navigation
        if navigation.heading is None:
            return 0.0, 0.0
        speed = self.ctx.speed
        return speed * math.sin(navigation.heading), speed * math.cos(navigation.heading)

    def _conflict(self, wanted: tuple[float, float], other: Traffic) -> bool:
        """Whether the two would come within the margin over the horizon, each keeping its velocity (this
        vehicle's until its target, ``reach`` away)."""
        pose = self.ctx.fc.pose
        speed = math.hypot(*wanted)
        margin = self._margin(other)
        if math.dist((pose.x, pose.y, pose.z), (other.x, other.y, other.z)) > (
                margin + (speed + math.hypot(other.vx, other.vy)) * HORIZON):
            return False  # too far apart to meet within the horizon: no array work
        reach = self.ctx.fc.navigation.reach
        until = reach / speed if speed > 0 and math.isfinite(reach) else math.inf
        return _meet(pose.x, pose.y, wanted[0], wanted[1], until, other.x, other.y, other.vx, other.vy,
                     pose.z - other.z, margin * margin)

    def _closing_in(self, wanted: tuple[float, float], others: list[Traffic]) -> Traffic | None:
        """The nearest team-mate this vehicle would come within the margin of before it could stop, flying
        ``wanted`` (the other keeping its velocity): a monitor period of flight plus the braking distance."""
        pose = self.ctx.fc.pose
        speed = max(math.hypot(*wanted), self.ctx.fc.speed)
        soon = self.ctx.settings.monitor_period + speed / max(self.ctx.fc.brake, 0.1) + GUARD_EXTRA
        closest, found = math.inf, None
        for other in others:
            margin = self._margin(other)
            gx, gy, gz = other.x - pose.x, other.y - pose.y, other.z - pose.z
            if math.sqrt(gx * gx + gy * gy + gz * gz) > margin + (speed + math.hypot(other.vx, other.vy)) * soon:
                continue
            cx, cy = wanted[0] - other.vx, wanted[1] - other.vy  # closing velocity
            closing2 = cx * cx + cy * cy
            when = min(soon, max(0.0, (gx * cx + gy * cy) / closing2)) if closing2 > 1e-9 else 0.0
            if when <= 0.0:
                continue  # not closing in: moving away is always allowed
            ax, ay = gx - cx * when, gy - cy * when
            nearest = math.sqrt(ax * ax + ay * ay + gz * gz)
            if nearest < margin and nearest < closest:
                closest, found = nearest, other
        return found

    def _too_close_ahead(self, wanted: tuple[float, float], others: list[Traffic]) -> Traffic | None:
        """A team-mate already within the margin that this vehicle would move closer to."""
        pose = self.ctx.fc.pose
        for other in others:
            dx, dy = other.x - pose.x, other.y - pose.y
            if (math.dist((pose.x, pose.y, pose.z), (other.x, other.y, other.z)) < self._margin(other)
                    and dx * (wanted[0] - other.vx) + dy * (wanted[1] - other.vy) > 0):
                return other
        return None

    def _keep_out_of(self, other: Traffic) -> None:
        """Hold here, or step aside when the team-mate's track (a team-mate standing still: the team-mate
        itself) is within the margin and a metre."""
        ctx = self.ctx
        x, y = ctx.position
        ox, oy = x - other.x, y - other.y  # from the team-mate to here
        speed = math.hypot(other.vx, other.vy)
        if speed > MOVING:  # off its track, level with here
            ux, uy = other.vx / speed, other.vy / speed
            along = ox * ux + oy * uy
            ox, oy = ox - along * ux, oy - along * uy
        off = math.hypot(ox, oy)
        if off < 0.1:  # right on it: to the right of its way (east of a team-mate standing still), as both agree
            ox, oy, off = (uy, -ux, 1.0) if speed > MOVING else (1.0, 0.0, 1.0)
        need = self._margin(other) + ASIDE - off
        target = (x, y)
        if need > 0:
            aside = (x + ox / off * need, y + oy / off * need)
            if self._safe([aside]):
                target = aside
        self._send(target)

    def _safe(self, points: list[tuple[float, float]]) -> bool:
        """Whether flying straight from here through ``points`` stays clear of the scene's known obstacles and
        out of every team-mate's margin (one already within it: never closer than now). Checked against all of
        them: stepping out of one's way must not cut into another's."""
        ctx = self.ctx
        if not all(ctx.inside(p) and ctx.is_clear(p) for p in points) or not ctx.path_clear(points):
            return False
        pose = ctx.fc.pose
        legs = list(zip([(pose.x, pose.y), *points[:-1]], points, strict=True))
        for other in self._others:
            dz2 = (pose.z - other.z) ** 2
            now = math.sqrt((pose.x - other.x) ** 2 + (pose.y - other.y) ** 2 + dz2)
            keep = min(self._margin(other), now) - 1e-6
            if any(math.sqrt(_to_segment((other.x, other.y), a, b) ** 2 + dz2) < keep for a, b in legs):
                return False
        return True


def column(ctx: Context, top: float, bottom: float) -> Traffic | None:
    """The team-mate that is, or within ``COLUMN_AHEAD`` s will be, within the margin of the column this vehicle
    climbs or descends through, between the heights ``bottom`` and ``top`` (scene z): the nearest across."""
    pose = ctx.fc.pose
    found, nearest = None, math.inf
    for other in team_mates(ctx.fc):
        margin = ctx.settings.separation + ctx.radius + other.radius
        if not bottom - margin < other.z < top + margin:
            continue
        ahead = _TIMES[_TIMES <= COLUMN_AHEAD]
        across = np.hypot(other.x + other.vx * ahead - pose.x, other.y + other.vy * ahead - pose.y).min()
        if across < margin and across < nearest:
            found, nearest = other, across
    return found


def _to_segment(point: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance from ``point`` to the segment a-b."""
    ax, ay = b[0] - a[0], b[1] - a[1]
    length2 = ax * ax + ay * ay
    t = 0.0 if length2 < 1e-12 else max(0.0, min(1.0, ((point[0] - a[0]) * ax + (point[1] - a[1]) * ay) / length2))
    return math.hypot(point[0] - a[0] - t * ax, point[1] - a[1] - t * ay)


def _stands(other: Traffic) -> bool:
    return math.hypot(other.vx, other.vy) <= MOVING


@numba.njit(cache=True)
def _meet(x, y, vx, vy, until, other_x, other_y, other_vx, other_vy, gz, reach2):
    """Whether this vehicle (at x, y, flying vx, vy for ``until`` s, then still) and a team-mate (at other_x,
    other_y, flying other_vx, other_vy) come closer than sqrt(reach2) at any of the ``_TIMES`` looked at (gz:
    their height apart). A compiled loop: every agent asks it of every team-mate near enough at every step."""
    for t in _TIMES:
        mine = min(t, until)
        dx = (x + vx * mine) - (other_x + other_vx * t)
        dy = (y + vy * mine) - (other_y + other_vy * t)
        if dx * dx + dy * dy + gz * gz < reach2:
            return True
    return False


def team_mates(fc) -> list[Traffic]:
    """The other vehicles of the flight controller's team (a MAVLink flight controller tells of none yet)."""
    report = getattr(fc, "traffic", None)
    return report() if report is not None else []


def someone_elses(ctx: Context, point: tuple[float, float]) -> bool:
    """Whether a team-mate stands nearer to ``point`` than this vehicle does: its share of the area to search
    (the team splits the area by who is nearest, a Voronoi split on where each is now)."""
    others = team_mates(ctx.fc)
    if not others:
        return False
    mine = ctx.distance_to(point)
    return any(math.hypot(point[0] - o.x, point[1] - o.y) < mine for o in others)
