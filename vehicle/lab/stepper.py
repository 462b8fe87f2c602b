"""The one stepper: a simulation and its onboard agent advanced together, on simulated time.

Each step moves the simulation one fixed step and hands the readings it took
to the agent's flight controller (in-process, ``SimController``); every
``monitor_period`` the agent steps. A wreck is never steered: after a
collision the agent is not stepped again. Headless experiments, the live
``vehicle sim`` and the tests all step through here, and ``simulate`` wires
a scene, a vehicle and its agent the one way they are wired.
"""

from __future__ import annotations

from collections.abc import Callable

from vehicle.agent.agent import Agent
from vehicle.agent.settings import Settings
from vehicle.protocol.rangefinder import Reading
from vehicle.sim.onboard import SimController
from vehicle.sim.simulation import Simulation
from vehicle.world.scene import Scene


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
    return Stepper(simulation, mission, settings, waypoints, autostart)
