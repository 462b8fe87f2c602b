"""What every mission sees and does: the context, the status, and the Mission interface.

A mission is a small class that is stepped by the agent once per monitor period
and steers the vehicle through its flight controller (``vehicle.agent.controller``),
the same requests a companion computer sends over MAVLink. It sees the pose, the
monitor's observation and the memory map, and plans on the map with ``MapPlanner``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, ClassVar

from vehicle.agent.controller import FlightController
from vehicle.agent.monitor import Monitor, Observation
from vehicle.agent.settings import Settings
from vehicle.mapping.memory_map import MemoryMap

if TYPE_CHECKING:
    from vehicle.world.scene import Scene
from vehicle.mapping.planner import MapPlanner
from vehicle.protocol.modes import Kind
from vehicle.protocol.rangefinder import Servo


class Status(StrEnum):
    RUNNING = "running"
    DONE = "done"  # the mission's plan is complete
    STOPPED = "stopped"  # the mission gave up safely (reason in Mission.reason)


@dataclass
class Context:
    fc: FlightController
    map: MemoryMap
    monitor: Monitor
    settings: Settings
    waypoints: list[tuple[float, float]] | None = None  # given by the operator, scene metres
    time: float = 0.0
    started: float = 0.0  # when the mission was started (flight-controller time)
    observation: Observation | None = None
    say: Callable[[str], None] = print
    planned_path: list[tuple[float, float]] = field(default_factory=list)  # for display
    path_clearance: float = math.inf  # m beyond the body ``planned_path`` keeps where it passes closest
    scene: Scene | None = None  # the world the agent was given (--scene), for missions that plan round its objects
    planner: MapPlanner = field(init=False)

    def __post_init__(self):
        self.planner = MapPlanner(self.map, self.fc.radius, self.fc.avoid_margin)
        self.home = (self.fc.home[0], self.fc.home[1])

    @property
    def kind(self) -> Kind:
        return self.fc.kind

    @property
    def speed(self) -> float:
        """What the vehicle travels at, m/s: the ``speed`` setting, or less where its sensors looking down see the
        ground too little ahead to stop short of an edge at that (``Monitor.speed_limit``)."""
        return min(self.settings.speed, self.monitor.speed_limit)

    @property
    def radius(self) -> float:
        """Of the vehicle body, m."""
        return self.fc.radius

    @property
    def servo(self) -> Servo | None:
        """A servo turning the sonar, if the vehicle has one."""
        return self.fc.servo

    @property
    def position(self) -> tuple[float, float]:
        pose = self.fc.pose
        return pose.x, pose.y

    @property
    def yaw(self) -> float:
        return self.fc.pose.yaw

    def hold_here(self) -> None:
        """Hold the current position in GUIDED, at the operating altitude (a copter) or on the ground."""
        x, y = self.position
        self.fc.goto(x, y, self.settings.altitude if self.kind is Kind.COPTER else None)

    def goto(self, point: tuple[float, float]) -> None:
        """Fly to a point in GUIDED, at the operating altitude (a copter) or on the ground."""
        self.fc.goto(point[0], point[1], self.settings.altitude if self.kind is Kind.COPTER else None)

    def distance_to(self, point: tuple[float, float]) -> float:
        x, y = self.position
        return math.hypot(point[0] - x, point[1] - y)

    def inside(self, point: tuple[float, float], margin: float = 1.0) -> bool:
        """Whether the point lies in the allowed space around home (with a margin)."""
        half = self.settings.space_size - margin
        return abs(point[0] - self.home[0]) <= half and abs(point[1] - self.home[1]) <= half

    @property
    def time_left(self) -> float:
        return self.settings.time_limit - (self.time - self.started)

    # ---- planning on the memory map (see ``MapPlanner``) -------------------------------------------
    def plan(self, goal: tuple[float, float], relax: bool = False,
             level: int = 0) -> tuple[list[tuple[float, float]] | None, int]:
        """A path from here to ``goal`` around known obstacles, and the relaxation level that found it."""
        return self.planner.plan(self.position, goal, self.settings.padding, relax, level)

    def path_clear(self, points: list[tuple[float, float]], horizon: float = 15.0, padding: float = 0.0) -> bool:
        """Whether the polyline from here through ``points`` keeps clear of known obstacles (first ``horizon`` m)."""
        return self.planner.path_clear(self.position, points, horizon, padding)

    def is_clear(self, point: tuple[float, float], padding: float | None = None) -> bool:
        """Whether the body (plus padding, by default the setting) would fit at ``point``."""
        return self.planner.is_clear(point, self.settings.padding if padding is None else padding)

    def nearest_clear(self, point: tuple[float, float], distances, bearings, padding: float | None = None,
                      reachable: bool = False) -> tuple[tuple[float, float], float] | None:
        """The first spot, ``distances`` (m) nearest first and at each the ``bearings`` (radians from east) in
        order, where the body fits (``is_clear``) inside the allowed space, and (``reachable``) a path reaches
        it; with its distance from ``point``. None if there is none: a spot a vehicle cannot take as given (an
        rti spot, the operator's Go here) is taken as near it as the map allows."""
        for distance in distances:
            for angle in bearings:
                spot = (point[0] + distance * math.cos(angle), point[1] + distance * math.sin(angle))
                if (self.is_clear(spot, padding) and self.inside(spot, margin=0.5)
                        and (not reachable or self.plan(spot)[0] is not None)):
                    return spot, distance
        return None


class Mission:
    """Base class: subclasses set ``name`` (their module's, listed in ``MISSIONS``) and implement ``step``.

    ``mode`` is the flight mode the mission flies in: GUIDED missions get the
    vehicle airborne (or armed) from the agent before ``begin``; AUTO missions
    upload their items in ``begin`` and are started by the agent.
    """

    name: ClassVar[str]
    mode: ClassVar[str] = "GUIDED"

    def __init__(self, ctx: Context):
        self.ctx = ctx
        self.reason = ""

    def begin(self) -> None:
        """Called once when the vehicle is ready (armed, airborne for a copter)."""

    def progress(self) -> tuple[int, int] | None:
        """Waypoints done and in all, for the operator (None: the mission has no waypoints of its own)."""
        return None

    def step(self) -> Status:
        raise NotImplementedError

    def too_close(self) -> Status:
        """The monitor stopped the vehicle: an obstacle is closer than ``closeness`` ahead.

        The default gives up safely; missions that can find another way override it.
        """
        self.reason = "obstacle closer than the safety distance"
        return Status.STOPPED

    def out_of_time(self) -> Status:
        """Time to head home to make it within the limit: DONE if the plan is complete enough."""
        self.reason = "time budget spent before the plan was complete"
        return Status.STOPPED

    def resume(self) -> None:
        """The operator handed control back: send again whatever the mission was doing."""
        for routine in (getattr(self, "scan", None), getattr(self, "travel", None)):
            if routine is not None:
                routine.resume()

    def stop(self) -> None:
        """Halt in place (GUIDED: hold the current position)."""
        self.ctx.hold_here()
