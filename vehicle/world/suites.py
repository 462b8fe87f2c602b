"""The named sensor suites a vehicle in a simulated scene can carry (``vehicle sim --sensors``, ``vehicle agent
--suite``).

Kept apart from the sensor model so that a command line can list them
without loading the ray casting and its compiled loops.
"""

from __future__ import annotations

SENSOR_SUITES = {
    "single": "one sonar looking forward (the thesis's vehicle)",
    "triple": "three sonars: forward and 45 degrees to each side (sees walls alongside the path)",
    "servo": "one sonar on a servo that sweeps it 90 degrees either side (the thesis's servo option)",
    "ground": "the triple suite and a fourth sonar looking ahead and 10 degrees down at the ground, so the agent "
              "sees a drop or a steep slope before it drives onto it (a rover carries that sonar in every suite)",
}
LOOKS_DOWN = -5.0  # degrees: a sensor pitched further down than this watches the ground, not for walls
DEFAULT_SUITE = "triple"


def sensor_suite(name: str, kind: str = "copter") -> list:
    """The sonars (``vehicle.world.sonar.Sonar``) of a named sensor suite (see SENSOR_SUITES) on a vehicle of
    ``kind``: a rover carries the ground sonar in every suite (with the level sonars alone, 6 of 12 rover runs in
    a castle drove down a bank they could not see; a robot's cliff sensor is no option)."""
    from vehicle.protocol.rangefinder import Servo
    from vehicle.world.sonar import Sonar

    # narrow and echoing off ground met at a grazing angle (rough ground scatters)
    down = Sonar("down", mount_pitch=-10.0, max_range=6.0, beam_angle=2.0, rings=1, critical_angle=85.0)
    if name == "single":
        level = [Sonar("front")]
    elif name in ("triple", "ground"):
        level = [Sonar("front"), Sonar("left", mount_yaw=-45.0), Sonar("right", mount_yaw=45.0)]
    elif name == "servo":
        level = [Sonar("sweep", servo=Servo())]
    else:
        raise ValueError(f"unknown sensor suite {name!r}; suites: {', '.join(SENSOR_SUITES)}")
    return [*level, down] if name == "ground" or str(getattr(kind, "value", kind)) == "rover" else level
