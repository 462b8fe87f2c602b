"""The flight-controller interface: all the agent knows of its vehicle, and all it can ask of it.

In the spirit of MAVSDK's ``telemetry`` and ``action``: observations are the
latest values the flight controller reported, actions are requests answered
with a MAVLink result code (MAV_RESULT_*, ``ACCEPTED`` is 0). The agent never
reaches past this interface, so the same missions fly any implementation:

- ``vehicle.sim.onboard.SimController``: our simulator in the same process
  (experiments and sweeps, at full speed);
- ``vehicle.agent.mavlink_controller.MavlinkController``: MAVLink to an
  ArduPilot-like autopilot (our simulator as a plain autopilot, or ArduPilot).

Positions are scene metres (x east, y north, z up), headings compass radians;
``home`` is the start: its x, y and the height of the ground there.
"""

from __future__ import annotations

from typing import Protocol

from vehicle.protocol.frames import Navigation, Pose
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import MissionItem, MissionProgress
from vehicle.protocol.modes import Kind
from vehicle.protocol.rangefinder import Reading, Servo
from vehicle.protocol.traffic import Traffic


class FlightController(Protocol):
    kind: Kind
    datum: Datum
    home: tuple[float, float, float]
    radius: float  # m, the vehicle's body (the agent plans clear of it)
    brake: float  # m/s^2 the vehicle decelerates at (the monitor's stopping distance)
    avoid_margin: float  # m that the autopilot's own obstacle avoidance keeps from echoes (0: none)
    servo: Servo | None  # a servo that turns the sonar, if the vehicle has one
    system_id: int  # the vehicle's MAVLink system id (in a team, the lower id has the right of way)

    # ---- observe ----------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Seconds on the flight controller's clock (its time since boot), never the agent's wall clock."""

    @property
    def pose(self) -> Pose: ...

    @property
    def speed(self) -> float:
        """Horizontal ground speed, m/s."""

    @property
    def mode(self) -> str: ...

    @property
    def armed(self) -> bool: ...

    @property
    def flying(self) -> bool:
        """A copter in the air (a rover never flies)."""

    @property
    def taking_off(self) -> bool:
        """A GUIDED take-off is still climbing."""

    @property
    def navigation(self) -> Navigation: ...

    @property
    def blocked(self) -> bool:
        """The autopilot's obstacle avoidance holds the vehicle back."""

    @property
    def mission(self) -> MissionProgress: ...

    def readings(self) -> list[Reading]:
        """Distance readings taken since the last call."""

    def traffic(self) -> list[Traffic]:
        """The other vehicles of the team, as last known (none for a vehicle alone)."""

    def took_over(self) -> str | None:
        """Why the agent must stop commanding, in words, if something happened since the last call: someone
        else took over (a mode change the agent did not make, another ground station's target), or the flight
        controller refused a command or did not answer. None if nothing. (A gap in a MAVLink autopilot's
        heartbeat, which ends by itself, is the process's to handle: ``vehicle.agent.process``.)"""

    # ---- act (each returns a MAV_RESULT) ------------------------------------------------------------
    def arm(self, report: bool = True) -> int:
        """Arm. A refusal is news (``took_over``) unless ``report`` is False: the caller deals with it."""

    def takeoff(self, altitude: float, report: bool = True) -> int:
        """Climb to ``altitude`` m above home (GUIDED, armed copter); ``report`` as for ``arm``."""

    def set_mode(self, name: str) -> int: ...

    def goto(self, x: float, y: float, altitude: float | None = None) -> int:
        """Fly to a scene position in GUIDED, at ``altitude`` m above home (None keeps the current height)."""

    def set_yaw(self, heading: float, relative: bool = False) -> int:
        """Turn to a compass heading (radians); with ``relative``, by that angle (clockwise positive)."""

    def set_speed(self, speed: float) -> int: ...

    def set_servo(self, channel: int, pwm: int) -> int: ...

    def hold(self) -> int:
        """Stop and hold the current position (and drop any target or velocity still running)."""

    def return_home(self) -> int: ...

    def land(self) -> int: ...

    def upload_mission(self, items: list[MissionItem]) -> int:
        """Replace the autopilot's AUTO mission (item 0 is home)."""

    def download_mission(self) -> list[MissionItem]: ...

    def start_mission(self) -> int:
        """Run the AUTO mission (MAV_CMD_MISSION_START)."""
