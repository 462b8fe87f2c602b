"""The monitor: every period, vet the sensor readings, keep the memory map, and raise the alarm.

It drops readings past ``farness`` (a glitching sonar reports nonsense far
away), takes an echo off a team-mate for free space up to it (not a wall: the
agent keeps apart from team-mates through ``vehicle.agent.traffic``), projects
the rest into the memory map, and reports an obstacle closer
than ``closeness`` in the direction the vehicle is moving, so the agent can
stop before it gets any closer. It also keeps the mission's progress figures.

A sensor pitched down (``vehicle.world.suites.LOOKS_DOWN``) watches the ground
ahead instead: on flat ground it echoes where the ground plane under the vehicle
meets its beam, so no echo there (or one from deeper than ``drop_depth``) is an
edge, and one from ground rising more steeply than ``max_slope`` is a slope the
vehicle cannot drive. Either is an obstacle: marked in the map and reported
ahead like a wall. Its echoes off the ground itself are never walls.

Where level ground starts down a slope, a beam pitched less steeply than the
slope passes over it as over a bank: any ground below its line gives the same
echo. A vehicle that also carries sensors pitched further down
(``LOOKS_NEAR``: a rover's three, 30 degrees, steeper than any slope it drives)
traces the ground right in front of it, point by point in the scene's frame,
and only those decide: ground that falls below a traced point by more than
``drop_depth``, and more steeply than ``max_slope`` from it, is an edge; ground
that falls as a slope it can drive is driven onto. An edge the far sensor sees
stops the vehicle the first time (it may be coming too fast to stop within the
near sensor's sight), and then only slows it to the speed that stops it within
that sight, till the near sensor has looked. Without a recent word from the near
sensor the far one's edges are edges, as for a vehicle without one.

A sensor pitched up (``vehicle.world.suites.LOOKS_UP``) watches for overhangs: its
echo is an obstacle like a wall's while the beam's centre meets it within the
map's band above the sensor (the sensor's last 1 m, up to 7 m ahead for the
copter's), and room overhead further out; its beam never marks free space, since
it rises over what the level sensors see.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from vehicle.agent.settings import Settings
from vehicle.mapping.memory_map import MemoryMap
from vehicle.protocol.geodesy import heading_of
from vehicle.protocol.rangefinder import Reading
from vehicle.world.suites import LOOKS_DOWN, LOOKS_NEAR, LOOKS_UP

RIDE_HEIGHT = 0.05  # m: a rover's body above the ground (the simulator's ground clearance)
MIN_RUN = 0.05  # m between two echoes off risen ground to measure a slope between them
RISE_NOISE = 0.05  # m: ground this little above the vehicle's is flat (the cone's edge echoes a little short)
EDGE_SPREAD, EDGE_STEP = 20, 5  # degrees either side of a ground sensor's beam an edge it sees is marked, and apart
PROFILE_REACH = 2.0  # m around the vehicle the ground traced by the sensor looking down nearest is kept
NEAR_FRESH = 1.0  # s: that sensor vouches for the ground only while it has reported this recently
SUSPECT_FOR = 1.0  # s after the last word of a possible edge ahead the vehicle still creeps
EDGE_WIDTH = 0.6  # m either side along the rim an edge the near sensor finds is marked (the far one's 20 degrees)
EDGES_KEPT = 50  # edges the near sensor found, the latest, that make the far one's edges near them known ones
TRACED_MAX = 200  # ground points kept: two seconds of the near sensor's readings at its 10 Hz, a dozen times over


@dataclass
class Observation:
    """What the monitor saw in one period."""

    time: float
    readings: list[Reading] = field(default_factory=list)  # readings kept this period (not the overhead ones)
    nearest_ahead: float | None = None  # closest echo in the direction of travel, metres
    too_close: bool = False
    outside: bool = False  # the vehicle left the allowed space around home
    ground: str | None = None  # what the ground ahead forbids ("ground drops away ..."), None when drivable


class Monitor:
    def __init__(self, settings: Settings, memory_map: MemoryMap, home: tuple[float, float], radius: float,
                 brake: float = 2.5, height: float | None = None, say=None):
        """``height``: of the sensors above the ground under the vehicle (a rover's; None: unknown, as for a
        copter, and then sensors looking down are ignored). ``say`` tells the operator of ground it refuses."""
        self.settings = settings
        self.map = memory_map
        self.home = home
        self.radius = radius
        self.brake = brake  # m/s^2 the vehicle can decelerate at
        self.readings_dropped = 0
        self.readings_used = 0
        self.distance_travelled = 0.0
        self._last_xy: tuple[float, float] | None = None
        self._speed_before: float | None = None  # the speed at the last period, to tell it is speeding up
        self._pending: list[Reading] = []
        self.height = height
        self.say = say
        self._ground_said: str | None = None
        self._risen: dict[int, tuple[float, float, float]] = {}  # each ground sensor's last echo off risen ground
        self.ground_sight: float | None = None  # m ahead at which the sensors looking down first see an edge
        self.near_sight: float | None = None  # the same for the sensor looking down nearest (``LOOKS_NEAR``)
        self._near_at = -math.inf  # when that one last reported
        self._suspect_at = -math.inf  # when the far sensors last saw what may be an edge or a slope down
        self._traced: deque[tuple[float, float, float]] = deque()  # ground points the near sensor met that the
        # vehicle can drive, in the scene's frame
        self._edges: deque[tuple[float, float]] = deque(maxlen=EDGES_KEPT)  # edges the near sensor found
        self._time = 0.0

    @property
    def speed_limit(self) -> float:
        """The fastest the vehicle may go and still stop short of an edge its sensors looking down see only
        ``ground_sight`` ahead (inf while none has reported), to 0.1 m/s below: the body's front must stop
        before the edge, after up to two monitor periods (the reading's and the monitor's) at that speed and
        the braking distance. While it creeps, within ``near_sight``."""
        return self._stops_within(self.near_sight if self.creeping else self.ground_sight)

    @property
    def cruise_limit(self) -> float:
        """The speed limit away from what may be an edge (within ``ground_sight``): a way home is timed at it,
        not at a creep towards a rim (timed so, a rover's Search in the castle ended a third early)."""
        return self._stops_within(self.ground_sight)

    def _stops_within(self, sight: float | None) -> float:
        if sight is None:
            return math.inf
        period, room = self.settings.monitor_period, max(sight - self.radius, 0.0)
        return math.floor(10 * self.brake * (-2 * period + math.sqrt(4 * period * period + 2 * room / self.brake))) / 10

    @property
    def creeping(self) -> bool:
        """Whether the far sensor looking down saw what may be an edge ahead within ``SUSPECT_FOR``, and the near
        one vouches for the ground: the vehicle goes no faster than stops it within the near one's sight."""
        return self._vouched and self._time - self._suspect_at <= SUSPECT_FOR

    @property
    def _vouched(self) -> bool:
        return self.near_sight is not None and self._time - self._near_at <= NEAR_FRESH

    def stopping(self, speed: float, before: float | None = None) -> float:
        """How far the vehicle goes before it stands, stopped at the next period: speeding up (from ``before``,
        the speed a period ago), it goes on doing so until then, to the speed it is flown at, and then brakes.
        Reckoned at the speed it had, one speeding up towards a wall it met obliquely was told too late, and
        struck it (in the apartment, 1.6 m ahead at 2.5 m/s, up from 1.9 m/s a period before)."""
        period = self.settings.monitor_period
        cruise = min(self.settings.speed, self.speed_limit)  # as ``Context.speed``
        gain = 0.0 if before is None else min(max(speed - before, 0.0), self.brake * period)
        then = min(speed + gain, max(speed, cruise))
        return then * period + then * then / (2 * self.brake)

    def _nearest_ahead(self, x: float, y: float, travel: float, readings: list[Reading],
                       reach: float, clearance: float = math.inf,
                       path: list[tuple[float, float]] | None = None) -> float | None:
        """Distance ahead of the nearest echo inside the corridor the body sweeps along ``travel``,
        as far as ``reach`` metres (a new obstacle: as far as ``path`` runs on straight ahead, when that is
        further).

        An echo comes from somewhere on its cone's arc at that range. Where the map already holds obstacles on
        the arc (a door frame at the cone's edge), they explain it, as the map itself takes them to
        (``MemoryMap.add_readings``): the echo is ahead only if one of them lies in the corridor, as far as
        ``reach`` (beyond it, the path on was planned round them). Else it counts where the beam's centre
        meets it, as far as ``path`` runs on (unless it lies a cell off what the map knows: a wall the path on
        was planned round, whose cells the arc misses by one). Call before the period's readings go into the
        map."""
        ux, uy = math.sin(travel), math.cos(travel)
        corridor = self.radius + min(self.settings.padding, clearance)
        run = straight_run(x, y, travel, path, corridor) if path else 0.0

        def in_corridor(px: float, py: float, limit: float = reach) -> float | None:
            dx, dy = px - x, py - y
            ahead = dx * ux + dy * uy
            return ahead if 0 < ahead < limit + corridor and abs(dx * uy - dy * ux) < corridor else None

        nearest = None
        for reading in readings:  # a handful per period: plain floats beat a dozen numpy calls
            if reading.distance is None:
                continue
            ox, oy, oz = reading.origin.tolist()
            rx, ry, rz = reading.direction.tolist()
            hx, hy, hz = ox + rx * reading.distance, oy + ry * reading.distance, oz + rz * reading.distance
            if abs(hz - oz) > self.map.band:
                continue  # ground or ceiling
            ahead = in_corridor(hx, hy, max(reach, run))
            if ahead is None:
                continue
            beam = math.radians(reading.beam_angle)
            known = self._known_on_arc(ox, oy, rx, ry, reading.distance, beam)
            if known:  # the known obstacles explain it: ahead only where one of them is
                ahead = min((a for a in (in_corridor(*point) for point in known) if a is not None), default=None)
            elif in_corridor(hx, hy) is None and self._known_beside_arc(ox, oy, rx, ry, reading.distance, beam):
                continue  # beyond the target, a cell off what the map knows: the path on was planned round it
            if ahead is not None:
                nearest = ahead if nearest is None else min(nearest, ahead)
        return nearest

    def _arc_cells(self, ox: float, oy: float, rx: float, ry: float, distance: float,
                   beam: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows and columns of the map cells on a cone's arc at ``distance``, sampled every half cell as the
        map's tracing samples it (those on the map only)."""
        m = self.map
        level = math.hypot(rx, ry)
        if level < 1e-9:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        arc = distance * level
        samples = 1 + 2 * int(2.0 * beam * arc * m.resolution + 0.5)
        angles = math.atan2(ry, rx) + (np.linspace(-beam, beam, samples) if samples > 1 else np.zeros(1))
        cols = np.floor((ox + arc * np.cos(angles) - m.origin[0]) * m.resolution).astype(np.int64)
        rows = np.floor((oy + arc * np.sin(angles) - m.origin[1]) * m.resolution).astype(np.int64)
        inside = (rows >= 0) & (rows < m.size) & (cols >= 0) & (cols < m.size)
        return rows[inside], cols[inside]

    def _known_on_arc(self, ox: float, oy: float, rx: float, ry: float, distance: float,
                      beam: float) -> list[tuple[float, float]]:
        """The centres of the occupied map cells on a cone's arc at ``distance``."""
        rows, cols = self._arc_cells(ox, oy, rx, ry, distance, beam)
        known = self.map.grid[rows, cols] >= self.map.OCCUPIED_AT
        cells = dict.fromkeys(zip(rows[known].tolist(), cols[known].tolist(), strict=True))
        return [self.map.center_of(row, col) for row, col in cells]

    def _known_beside_arc(self, ox: float, oy: float, rx: float, ry: float, distance: float, beam: float) -> bool:
        """Whether the map holds an obstacle within a cell of a cone's arc at ``distance`` (an arc that misses a
        known wall by a cell still meets that wall)."""
        rows, cols = self._arc_cells(ox, oy, rx, ry, distance, beam)
        last = self.map.size - 1
        return any(bool((self.map.grid[np.clip(rows + dr, 0, last), np.clip(cols + dc, 0, last)]
                         >= self.map.OCCUPIED_AT).any()) for dr in (-1, 0, 1) for dc in (-1, 0, 1))

    def _ground_ahead(self, x: float, y: float, travel: float | None, speed: float, reach_to: float,
                      readings: list[Reading]) -> tuple[float | None, str | None]:
        """Edges and steep slopes seen by the sensors looking down: mark each in the map, and return the
        distance ahead of the nearest in the corridor along ``travel`` and what it is."""
        nearest, what = None, None
        corridor = self.radius + self.settings.padding
        max_slope = math.radians(self.settings.max_slope)
        for reading in readings:  # first how far each sees (the far one's edge needs the near one's word)
            sight = self.height / math.tan(math.radians(reading.beam_angle - reading.pitch))  # on level ground
            if reading.pitch <= LOOKS_NEAR:
                self.near_sight = sight if self.near_sight is None else min(self.near_sight, sight)
                self._near_at = self._time
            else:
                self.ground_sight = sight if self.ground_sight is None else min(self.ground_sight, sight)
        for reading in readings:
            near = reading.pitch <= LOOKS_NEAR
            ox, oy, oz = reading.origin.tolist()
            dx, dy, dz = reading.direction.tolist()
            level = math.hypot(dx, dy)
            down = math.radians(-reading.pitch)  # the beam's centre below the ground the vehicle stands on
            if down <= 0 or level < 1e-6:
                continue  # it looks level or up: it sees no ground
            # depths are below the plane of the ground under the vehicle (its wheels lie on it): on a slope it
            # can drive, the ground ahead goes on in that plane. Ground that bends away from the plane but
            # lies no deeper than the level (a climb's top) is no drop either: the beam cannot tell it from
            # a bank beyond the top, and the drop is only the depth below the level (as on level ground)
            beam = math.radians(reading.beam_angle)
            flat = self.height / math.sin(down)  # range of the beam's centre to that plane
            # the cone's lower edge meets that plane first: the edge lies no further than there
            edge = self.height / math.tan(down + beam)
            if reading.distance is None:
                self._risen.pop(reading.sensor, None)
                deepest = reading.max_range * min(math.sin(down), -dz) - self.height  # below the plane, the level
                if flat > reading.max_range or deepest <= self.settings.drop_depth:
                    continue  # it could not have seen the ground, or not deep enough to tell
                reach, kind = edge, "drops away"
            else:
                # below that plane, and below the level, along the cone's lower edge (the first to meet the ground)
                depth = reading.distance * math.sin(down + beam) - self.height
                below_level = reading.distance * math.sin(math.asin(max(-1.0, min(1.0, -dz))) + beam) - self.height
                run = reading.distance * level
                deep = depth > self.settings.drop_depth and below_level > self.settings.drop_depth
                hit = _lower_edge_hit(reading) if near else None
                falls = self._falls(hit, max_slope, x, y) if near else None
                if falls or (falls is None and deep):  # near: nothing traced yet, and deep below the plane
                    reach, kind = edge, "drops away"
                elif -depth <= RISE_NOISE or not self._too_steep(reading, -depth, max_slope):
                    if -depth <= RISE_NOISE:
                        self._risen.pop(reading.sensor, None)  # the plane goes on, a step down, or a climb's top
                    if near:
                        self._trace(hit)  # ground it can drive
                    continue
                else:
                    reach, kind = run, "rises too steeply"
            ux, uy = dx / level, dy / level
            ahead = None  # how far ahead along ``travel`` it lies, if in the corridor the body sweeps
            if travel is not None:
                ex, ey = ox + ux * reach - x, oy + uy * reach - y
                tx, ty = math.sin(travel), math.cos(travel)
                along = ex * tx + ey * ty
                ahead = along if 0 < along and abs(ex * ty - ey * tx) < corridor else None
            known = not near and kind == "drops away" and self._on_known_edge(ox + ux * reach, oy + uy * reach)
            beyond = ahead is not None and ahead > reach_to + self.radius  # past where it stops or turns
            if not near and kind == "drops away" and self._vouched and not known and not beyond and (
                    ahead is not None or travel is None):
                # on the way: maybe a slope down that starts ahead, and the near sensor decides. Coming faster
                # than stops the vehicle within its sight, it stops first (as at an edge); then it creeps on.
                # Beside the way it is marked, as without the near sensor: creeping along every rim the far
                # one sees aslant, rovers searched the castle at half the pace
                first = not self.creeping
                self._suspect_at = self._time
                if not first or speed <= self.speed_limit or ahead is None:
                    continue
            else:
                # an edge is a line the narrow beam meets at one point: mark it either side too, as far as
                # EDGE_SPREAD, so a way planned along it keeps off (a rover ran along a bank's rim it had seen
                # only ahead, and its body touched the slope as it turned); a slope up is only climbed, not fallen
                # (the near sensor's: as wide along the rim as the far one's, and the far one's edges near it
                # are known edges, not looked at again)
                if near and kind == "drops away":
                    self._edges.append((ox + ux * reach, oy + uy * reach))
                    sides = np.linspace(-EDGE_WIDTH, EDGE_WIDTH, 2 * round(EDGE_WIDTH / 0.1) + 1)
                    ends = np.column_stack([ux * reach - uy * sides, uy * reach + ux * sides])
                    lengths = np.hypot(ends[:, 0], ends[:, 1])
                    directions = np.column_stack([ends / lengths[:, None], np.zeros(len(sides))])
                    ranges = lengths
                else:
                    spread = EDGE_SPREAD if kind == "drops away" else 0
                    turns = np.radians(np.arange(-spread, spread + 1, EDGE_STEP))
                    directions = np.column_stack([ux * np.cos(turns) + uy * np.sin(turns),
                                                  uy * np.cos(turns) - ux * np.sin(turns), np.zeros(len(turns))])
                    ranges = np.full(len(turns), reach)
                self.map.add_readings(np.tile([ox, oy, oz], (len(ranges), 1)), directions, ranges, ranges + 1.0)
            if ahead is not None and (nearest is None or ahead < nearest):
                nearest, what = ahead, f"ground {kind} {ahead:.1f} m ahead"
        return nearest, what

    def _on_known_edge(self, x: float, y: float) -> bool:
        """Whether the near sensor found one of its latest edges within ``EDGE_WIDTH`` of (x, y)."""
        return any(math.hypot(ex - x, ey - y) <= EDGE_WIDTH for ex, ey in self._edges)

    def _falls(self, point: tuple[float, float, float], max_slope: float, x: float, y: float) -> bool | None:
        """Whether ground at ``point`` lies more than ``drop_depth`` below ground the near sensor traced before,
        and more steeply than ``max_slope`` below it: an edge, or a slope down steeper than the vehicle drives
        (a slope it drives falls less steeply than that from every point before it; a step down shallower than
        ``drop_depth`` is driven over). None when nothing is traced within ``PROFILE_REACH`` of the vehicle
        (just started, or turned onto ground it has not traced): then only the plane under it can tell."""
        traced = self._traced
        while traced and math.hypot(traced[0][0] - x, traced[0][1] - y) > PROFILE_REACH:
            traced.popleft()
        if not traced:
            return None
        px, py, pz = point
        drop_depth, steep = self.settings.drop_depth, math.tan(max_slope)
        return any(qz - pz > drop_depth and qz - pz > steep * math.hypot(qx - px, qy - py)
                   for qx, qy, qz in traced)

    def _trace(self, point: tuple[float, float, float]) -> None:
        """Ground the near sensor met that the vehicle can drive (the oldest go first when it stands turning)."""
        self._traced.append(point)
        if len(self._traced) > TRACED_MAX:
            self._traced.popleft()

    def _too_steep(self, reading: Reading, rise: float, max_slope: float) -> bool:
        """Ground ``rise`` above the vehicle's: a step up higher than ``drop_depth``, or a slope steeper than
        ``max_slope`` between this echo and the sensor's last one off risen ground (one echo cannot tell a
        steep slope near from a gentle one further away; two points on it can)."""
        if rise > self.settings.drop_depth:
            return True
        hit = _lower_edge_hit(reading)
        last, self._risen[reading.sensor] = self._risen.get(reading.sensor), hit
        if last is None:
            return False
        run = math.hypot(hit[0] - last[0], hit[1] - last[1])
        return run > MIN_RUN and math.atan2(abs(hit[2] - last[2]), run) > max_slope

    def collect(self, readings: list[Reading]) -> None:
        """Buffer readings taken between two monitor periods."""
        self._pending.extend(readings)

    def observe(self, time: float, x: float, y: float, travel: float | None, speed: float = 0.0,
                reach: float = math.inf, clearance: float = math.inf,
                path: list[tuple[float, float]] | None = None) -> Observation:
        """Run one monitor period on the readings collected since the last one.

        ``travel`` is the compass heading (rad) the vehicle wants to move in, None when it
        wants to stay put. An echo is "ahead" when its point lies in the corridor the
        body sweeps along that heading (body radius plus padding either side). It is
        too close when the vehicle, moving at ``speed``, could not stop within
        ``closeness`` of it: one more period of travel plus the braking distance.
        Echoes beyond ``reach`` (where the vehicle will stop or turn) are not in the way; ``path``, the rest
        of the path being flown (from here), carries the reach on for new obstacles as far as it runs on
        straight ahead (``straight_run``): a path walked target by target half a metre ahead runs on past each
        of them (known obstacles beyond the target: the path on was planned round them).
        ``clearance``: what the path being flown keeps beyond the body where it passes closest, when that is
        less than the padding (through a doorway): the corridor is that narrow, or the frame it was planned
        past would stop it.
        """
        observation = Observation(time)
        if self._last_xy is not None:
            self.distance_travelled += math.hypot(x - self._last_xy[0], y - self._last_xy[1])
        self._last_xy = (x, y)
        self.map.mark_body(x, y, self.radius)
        farness = self.settings.farness
        pending = self._pending
        readings = [r if r.distance is None or r.distance <= farness else replace(r, distance=None)
                    for r in pending]  # past farness: a glitch, or too far to trust
        count = len(readings)
        self.readings_used += count
        self.readings_dropped += sum(r is not kept for r, kept in zip(pending, readings, strict=True))
        # an echo off a team-mate is no wall: free space up to it, nothing known beyond (it moves on)
        readings = [r if r.vehicle is None or r.distance is None else replace(r, distance=None, max_range=r.distance)
                    for r in readings]
        # what a mission sweeps for open directions: not the overhead sensor's (its silence says nothing of walls)
        observation.readings = [r for r in readings if r.pitch < LOOKS_UP]
        if any(r.pitch <= LOOKS_DOWN for r in readings):  # the ground's sensors: never walls
            ground = [r for r in readings if r.pitch <= LOOKS_DOWN]
            readings = [r for r in readings if r.pitch > LOOKS_DOWN]
            count = len(readings)
            if self.height is not None:
                self._time = time
                ahead, observation.ground = self._ground_ahead(x, y, travel, speed, reach, ground)
                observation.nearest_ahead = ahead
        if readings:
            # one pass into arrays (np.array of a list of small arrays is slow)
            origins, directions = np.empty((count, 3)), np.empty((count, 3))
            distances, max_ranges, beams = np.empty(count), np.empty(count), np.empty(count)
            latest = {}
            for i, r in enumerate(readings):
                origins[i] = r.origin
                directions[i] = r.direction
                distances[i] = np.nan if r.distance is None else r.distance
                max_ranges[i] = min(r.max_range, farness)
                beams[i] = math.radians(r.beam_angle)
                latest[r.sensor] = i
            # free space from each level sensor's latest reading of the period: the earlier ones only repeat it
            free = np.zeros(count, dtype=bool)
            free[[i for i in latest.values() if readings[i].pitch < LOOKS_UP]] = True
            level = None if travel is None else self._nearest_ahead(x, y, travel, readings, reach, clearance, path)
            if level is not None and (observation.nearest_ahead is None or level < observation.nearest_ahead):
                observation.nearest_ahead = level
            self.map.add_readings(origins, directions, distances, max_ranges, beams, free)
        self._pending = []
        observation.too_close = (observation.nearest_ahead is not None and observation.nearest_ahead
                                 < self.settings.closeness + self.stopping(speed, self._speed_before))
        self._speed_before = speed
        if observation.ground != self._ground_said:
            self._ground_said = observation.ground
            if observation.ground is not None and observation.too_close and self.say is not None:
                self.say(f"Stopping: {observation.ground}")
        half = self.settings.space_size
        observation.outside = abs(x - self.home[0]) > half or abs(y - self.home[1]) > half
        return observation


def _lower_edge_hit(reading: Reading) -> tuple[float, float, float]:
    """Where a ground sensor's echo came from: on its cone's lower edge, which meets the ground first."""
    ox, oy, oz = reading.origin.tolist()
    dx, dy, dz = reading.direction.tolist()
    level = math.hypot(dx, dy)
    lower = math.asin(max(-1.0, min(1.0, -dz))) + math.radians(reading.beam_angle)
    run = reading.distance * math.cos(lower) / level
    return ox + dx * run, oy + dy * run, oz - reading.distance * math.sin(lower)


def straight_run(x: float, y: float, travel: float, path: list[tuple[float, float]], corridor: float) -> float:
    """How far ahead along ``travel`` (compass radians) from (x, y) the polyline ``path`` goes before it
    turns out of the corridor ``corridor`` m either side (the first point outside counts, so a turn's corner
    does), or ends."""
    ux, uy = math.sin(travel), math.cos(travel)
    run = 0.0
    for px, py in path:
        dx, dy = px - x, py - y
        run = max(run, dx * ux + dy * uy)
        if abs(dx * uy - dy * ux) > corridor:
            break
    return run


def sweep_profile(readings: list[Reading]) -> tuple[np.ndarray, np.ndarray]:
    """Headings (rad) and distances (inf for no echo) of a set of readings, sorted by heading."""
    if not readings:
        return np.zeros(0), np.zeros(0)
    headings = np.array([heading_of(r.direction[0], r.direction[1]) for r in readings])
    distances = np.array([np.inf if r.distance is None else r.distance for r in readings])
    order = np.argsort(headings)
    return headings[order], distances[order]
