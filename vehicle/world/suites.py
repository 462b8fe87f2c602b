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
              "sees a drop or a steep slope before it drives onto it (a rover carries that sonar, and three looking "
              "30 degrees down, straight and to either side, that tell a slope it can drive down from an edge, in "
              "every suite)",
}
LOOKS_DOWN = -5.0  # degrees: a sensor pitched further down than this watches the ground, not for walls
LOOKS_NEAR = -20.0  # degrees: one pitched further down than this traces the ground right in front of the body
LOOKS_UP = 2.0  # degrees: a sensor pitched further up than this watches for overhangs, not for walls
DEFAULT_SUITE = "triple"


def sensor_suite(name: str, kind: str = "copter") -> list:
    """The sonars (``vehicle.world.sonar.Sonar``) of a named sensor suite (see SENSOR_SUITES) on a vehicle of
    ``kind``: a rover carries the ground sonars in every suite (with the level sonars alone, 6 of 12 rover runs in
    a castle drove down a bank they could not see; a robot's cliff sensor is no option): one that sees the
    ground 1.6 m ahead, and three 0.6 m ahead, straight and 30 degrees to either side, that tell a slope it can
    drive down from an edge across the body's width (with the middle one alone, rovers crept into the tapered ends
    of the castle's moat, narrow grooves its line crossed where they were shallow). A copter carries the
    overhead sonar, pitched 8 degrees up with a 6 degree half-angle: it meets the skirt of a tree's crown 0.25 m
    above the body's centre from 1 m to 7 m ahead, where the level cones (7.5 degrees) pass under it until it
    is 1.9 m away and see it only when one points at it (flying under pines, 2 team runs in 68 crashed into a
    crown). A flat ceiling meets its rays at 76 degrees or more, beyond its critical angle, so indoors it stays
    silent; foliage met less obliquely echoes."""
    from vehicle.protocol.rangefinder import Servo
    from vehicle.world.sonar import Sonar

    # narrow and echoing off ground met at a grazing angle (rough ground scatters)
    down = Sonar("down", mount_pitch=-10.0, max_range=6.0, beam_angle=2.0, rings=1, critical_angle=85.0)
    # a rover's next three: steeper than any slope it drives (``max_slope``, 20 degrees), they meet a slope down
    # that starts ahead, which the first passes over as over a bank, and tell the two apart
    near = [Sonar(name, mount_pitch=-30.0, mount_yaw=yaw, max_range=3.0, beam_angle=2.0, rings=1, critical_angle=85.0)
            for name, yaw in (("near", 0.0), ("near left", -30.0), ("near right", 30.0))]
    up = Sonar("up", mount_pitch=8.0, max_range=12.0, beam_angle=6.0, rings=2, critical_angle=75.0)
    if name == "single":
        level = [Sonar("front")]
    elif name in ("triple", "ground"):
        level = [Sonar("front"), Sonar("left", mount_yaw=-45.0), Sonar("right", mount_yaw=45.0)]
    elif name == "servo":
        level = [Sonar("sweep", servo=Servo())]
    else:
        raise ValueError(f"unknown sensor suite {name!r}; suites: {', '.join(SENSOR_SUITES)}")
    rover = str(getattr(kind, "value", kind)) == "rover"
    return [*level, *([down, *near] if rover else [down] if name == "ground" else []), *([] if rover else [up])]
