"""The one stepper: a simulation and its onboard agent advanced together, on simulated time.

Each step moves the simulation one fixed step and hands the readings it took
to the agent's flight controller (in-process, ``SimController``); every
``monitor_period`` the agent steps. A wreck is never steered: after a
collision the agent is not stepped again. Headless experiments, the live
``vehicle sim`` and the tests all step through here, and ``simulate`` wires
a scene, a vehicle and its agent the one way they are wired.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from vehicle.agent.agent import Agent
from vehicle.agent.missions.square import square_corners
from vehicle.agent.settings import Settings
from vehicle.mapping.sharing import Changes, apply
from vehicle.protocol.rangefinder import Reading
from vehicle.sim.onboard import SimController
from vehicle.sim.simulation import PlacementError, Simulation
from vehicle.sim.team import Team
from vehicle.world.scene import Scene
from vehicle.world.solids import solid_at
from vehicle.world.suites import DEFAULT_SUITE, sensor_suite


class Stepper:
    def __init__(self, simulation: Simulation, mission: str | None = None, settings: Settings | None = None,
                 waypoints: list[tuple[float, float]] | None = None, autostart: bool = True):
        """``mission`` None: the simulation alone, a plain autopilot with no agent on board."""
        self.simulation = simulation
        self.settings = settings or Settings()
        self.controller = SimController(simulation)
        self.agent = Agent(self.controller, mission, self.settings, waypoints, autostart) if mission else None
        self.period = max(1, round(self.settings.monitor_period / simulation.dt))

    @property
    def monitor_due(self) -> bool:
        """The agent stepped in the last step."""
        return self.simulation.steps % self.period == 0

    def step(self) -> list[Reading]:
        """One simulation step (and the agent's, when due); returns the readings taken."""
        simulation = self.simulation
        readings = simulation.step()
        if self.agent is not None and simulation.collision is None:
            self.controller.collect(readings)
            if simulation.steps % self.period == 0:
                self.agent.step()
        return readings

    def run(self, seconds: float, until: Callable[[], object] | None = None) -> bool:
        """Step for up to ``seconds`` of simulated time, stopping at a collision; True as soon as ``until()``
        holds after a step of the agent."""
        simulation = self.simulation
        end = simulation.time + seconds
        while simulation.time < end - 1e-9 and simulation.collision is None:
            self.step()
            if until is not None and self.monitor_due and until():
                return True
        return False


def simulate(scene: Scene, mission: str | None = None, kind: str = "copter", settings: Settings | None = None,
             start: tuple[float, ...] | None = None, heading: float | None = None,
             waypoints: list[tuple[float, float]] | None = None, autostart: bool = True, **options) -> Stepper:
    """A simulated vehicle in ``scene`` flying ``mission`` (None: no agent), its autopilot set up from the
    mission parameters (cruise speed, waypoint radius). ``options`` go to ``Simulation`` (seed, sensors,
    datum, limits, ...)."""
    settings = settings or Settings()
    simulation = Simulation(scene, kind, start, heading, cruise_speed=settings.speed, wp_radius=settings.closeness,
                            **options)
    if waypoints is None and mission in CORNER_MISSIONS:
        waypoints = corners_clear_of(scene, simulation.home, settings)
    return Stepper(simulation, mission, settings, waypoints, autostart)


CORNER_MISSIONS = ("pathfind", "square")  # missions that fly to the corners of a square round home by default
CORNER_CLEARANCE = 2.0  # m round a default corner that must be free of every solid
PULL_STEP = 0.02  # share of the way home a corner inside a solid is pulled in at a time


def corners_clear_of(scene: Scene, home: tuple[float, float, float], settings: Settings,
                     margin: float = CORNER_CLEARANCE) -> list[tuple[float, float]] | None:
    """Square's and Pathfind's default corners with each one inside a solid of the scene at the flight altitude
    (or within ``margin`` of one) pulled towards home until it is clear; None when all are clear, and the
    mission's own default stands. The agent knows no scene: in the demo scene its south-west corner lay inside
    the Office, and Pathfind always ended "waypoints 4 unreachable"."""
    corners = square_corners(home[:2], settings.space_size)
    moved = [_pulled_in(scene, home, corner, settings.altitude, margin) for corner in corners]
    return moved if moved != corners else None


def _pulled_in(scene: Scene, home, corner: tuple[float, float], altitude: float, margin: float):
    z = home[2] + altitude
    ring = [(margin * math.cos(a), margin * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 12, endpoint=False)]
    for share in np.arange(1.0, 0.0, -PULL_STEP):
        x, y = home[0] + share * (corner[0] - home[0]), home[1] + share * (corner[1] - home[1])
        if all(solid_at(scene, x + dx, y + dy, z) is None for dx, dy in [(0.0, 0.0), *ring]):
            return corner if share == 1.0 else (round(float(x), 1), round(float(y), 1))
    return corner


SHARE_PERIOD = 1.0  # s between two shares of a team's map changes


class TeamStepper:
    """A team's simulations (``Team``) and their agents, stepped together on the one clock.

    Each step moves the whole world one step and hands every vehicle's readings to its own controller;
    every ``monitor_period`` each agent still flying steps, and (``share_maps``) once a second each map takes
    in the cells the others' maps changed since, as the map stream would carry them (batched: each share costs
    a few array calls per vehicle, whatever it carries). A wreck's agent steps no more; the
    others fly on.
    """

    def __init__(self, team: Team, mission: str, settings: Settings | None = None,
                 waypoints: list[list[tuple[float, float]] | None] | None = None, autostart: bool = True):
        """``waypoints``: per vehicle (None: the mission's default)."""
        self.team = team
        self.settings = settings or Settings()
        self.controllers = [SimController(simulation, team) for simulation in team.simulations]
        waypoints = waypoints or [None] * len(team)
        self.agents = [Agent(controller, mission, self.settings, points, autostart)
                       for controller, points in zip(self.controllers, waypoints, strict=True)]
        self.period = max(1, round(self.settings.monitor_period / team.simulations[0].dt))
        self.share_every = self.period * max(1, round(SHARE_PERIOD / self.settings.monitor_period))
        self.share_maps = self.settings.share_maps >= 0.5
        self.cells_shared = 0  # changes made to a map by a team-mate's (a cell two of them changed counts twice)

    @property
    def monitor_due(self) -> bool:
        return self.team.simulations[0].steps % self.period == 0

    def step(self) -> list[list[Reading]]:
        readings = self.team.step()
        steps = self.team.simulations[0].steps
        due = steps % self.period == 0
        for simulation, controller, agent, taken in zip(self.team.simulations, self.controllers, self.agents,
                                                        readings, strict=True):
            if simulation.collision is None:
                controller.collect(taken)
                if due:
                    agent.step()
        if due and self.share_maps and len(self.agents) > 1 and steps % self.share_every == 0:
            self._share()
        return readings

    def _share(self) -> None:
        maps = [agent.map for agent in self.agents]
        changes = [Changes.of(m, m.take_changes(in_order=False)) for m in maps]  # each source read once
        for target in maps:
            self.cells_shared += apply(target, changes)


def simulate_team(scene: Scene, mission: str, count: int, kind: str = "copter", settings: Settings | None = None,
                  starts: list[tuple[float, ...]] | None = None, ids: list[int] | None = None,
                  waypoints: list[list[tuple[float, float]] | None] | None = None, seed: int = 0,
                  suite: str = DEFAULT_SUITE, **options) -> TeamStepper:
    """``count`` vehicles in ``scene`` flying ``mission``, each with its agent; ``starts`` (default: the team's
    spots around the scene's start), ``ids`` (default 1 ... count); each carries the sensor ``suite``, and
    vehicle k's sensor noise has seed + k.
    Raises PlacementError for a team that cannot be (see ``Team``)."""
    settings = settings or Settings()
    if count < 1:
        raise PlacementError(f"a team needs at least one vehicle, not {count}")
    starts = starts or team_starts(scene, count)
    if len(starts) != count:
        raise PlacementError(f"{len(starts)} starts for {count} vehicles")
    simulations = [Simulation(scene, kind, start, cruise_speed=settings.speed, wp_radius=settings.closeness,
                              seed=seed + k, sensors=sensor_suite(suite, kind), **options)
                   for k, start in enumerate(starts)]
    for k, simulation in enumerate(simulations):
        _check_climb(simulation, settings, k + 1 if ids is None else ids[k])
    return TeamStepper(Team(simulations, ids), mission, settings, waypoints)


COLUMN_STEP = 0.25  # m between the heights at which a copter's climb column is checked


def _check_climb(simulation: Simulation, settings: Settings, vehicle: int) -> None:
    """A copter takes off straight up, its sonars looking sideways, and sets off at once: a start under a
    branch or a roof, or one whose flight altitude lies within ``padding`` of a tree's crown, would fly it
    into it before it could see it. It also lands back down that column, as precisely as a position hold
    (giving way moves it about): a column within ``padding`` of a wall's top (above the ground's reach)
    lands it on the wall. Such a start is refused before anything flies."""
    if simulation.kind.value != "copter":
        return
    x, y, z = simulation.pose.xyz()
    top = max(z, simulation.home[2] + settings.altitude)
    radius = simulation.limits.radius
    where = f"vehicle {vehicle} at x={x:.2f} y={y:.2f}"
    contact = simulation.collider.sweep((x, y, z), (x, y, top))
    if contact is not None:
        raise PlacementError(f"{where} cannot climb to {settings.altitude:g} m: something is overhead at "
                             f"z={contact.point[2]:.2f}")
    for height in np.arange(z + radius + settings.padding, top, COLUMN_STEP):
        clear = simulation.collider.clearance((x, y, height)) - radius
        if clear < settings.padding:
            raise PlacementError(f"{where} would climb and land within {clear:.2f} m of the scene at z={height:.2f}"
                                 f" (padding {settings.padding:g} m): start it further out")
    clear = simulation.collider.clearance((x, y, top)) - simulation.limits.radius
    if clear < settings.padding:
        raise PlacementError(f"{where} would fly within {clear:.2f} m of the scene at its altitude of "
                             f"{settings.altitude:g} m (padding {settings.padding:g} m): start it further out")


# where a team starts, around the scene's start: the spots of ``groundstation demo --vehicles N``, metres apart
TEAM_SPOTS = [(0.0, 0.0), (-4.0, -4.0), (4.0, -3.0), (-3.0, 4.0), (6.0, 6.0), (-7.0, 1.0), (1.0, -7.0), (8.0, -1.0)]


def team_starts(scene: Scene, count: int) -> list[tuple[float, float]]:
    if count > len(TEAM_SPOTS):
        raise PlacementError(f"at most {len(TEAM_SPOTS)} vehicles start on the team's spots; give --start for each "
                             f"of {count}")
    x, y = (scene.start or (0.0, 0.0))[:2]
    return [(x + dx, y + dy) for dx, dy in TEAM_SPOTS[:count]]
