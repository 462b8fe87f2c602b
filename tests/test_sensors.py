"""Simulated sonars (vehicle.sensors): range, beam, critical angle, noise, mounts, servos, attitude."""

import math

import numpy as np
import pytest

from vehicle.protocol.frames import Pose, body_to_world
from vehicle.protocol.modes import Kind
from vehicle.protocol.rangefinder import Servo
from vehicle.sim.simulation import Simulation
from vehicle.world.raycast import RayCaster
from vehicle.world.sonar import Sonar, SonarArray, cone_rays
from vehicle.world.suites import SENSOR_SUITES, sensor_suite

NORTH = 10.0  # distance from the origin to the north wall's south face
EAST = 6.0  # distance from the origin to the east wall's west face
HEIGHT = 2.0  # sensor height: level with the middle of the walls


@pytest.fixture
def walls(make_scene, box):
    """A wall facing south at y = 10 and one facing west at x = 6, both 40 m long and 10 m high."""
    return make_scene(box(0, NORTH + 0.1, 2, 40, 0.2, 10), box(EAST + 0.1, 0, 2, 0.2, 40, 10))


def read(scene, sensors, pose=None, seed=0, backend="auto"):
    array = SonarArray(sensors, RayCaster(scene.mesh, backend), seed)
    return array.read(pose or Pose(0.0, 0.0, HEIGHT), 1.0)


def test_a_wall_at_a_known_distance_reads_that_distance(walls):
    (reading,) = read(walls, [Sonar()])
    assert reading.distance == pytest.approx(NORTH, abs=1e-3)  # a perpendicular wall: the centre ray is nearest
    assert reading.hit == pytest.approx([0.0, NORTH, HEIGHT], abs=1e-3)
    assert reading.time == 1.0 and reading.sensor == 0 and reading.max_range == 40.0


def test_an_oblique_wall_reads_within_the_beam_of_the_axis_distance(walls):
    """At 45 degrees the nearest ray of the cone is closer than the axis: at most the beam's half-angle closer."""
    sonar = Sonar(mount_yaw=45.0)
    (reading,) = read(walls, [sonar], pose=Pose(0.0, 0.0, HEIGHT, yaw=math.radians(-45)))  # axis due north
    (oblique,) = read(walls, [Sonar()], pose=Pose(0.0, 4.0, HEIGHT, yaw=math.radians(45)))  # NE at 45 deg
    assert reading.distance == pytest.approx(NORTH, abs=1e-3)
    axis = 6.0 * math.sqrt(2)  # to the north wall from (0, 4) along NE
    beam = math.radians(sonar.beam_angle)
    assert axis * math.cos(math.pi / 4) / math.cos(math.pi / 4 - beam) - 1e-3 <= oblique.distance <= axis + 1e-3


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_both_backends_read_the_same(backend, walls):
    from vehicle.world.raycast import embree_available

    if backend == "embree" and not embree_available():
        pytest.skip("needs embreex")
    sensors = sensor_suite("triple") + [Sonar("side", mount_yaw=90.0, rings=3)]
    reference = [r.distance for r in read(walls, sensors, backend="numpy")]
    assert [r.distance for r in read(walls, sensors, backend=backend)] == pytest.approx(reference, abs=1e-3)


def test_a_wall_beyond_max_range_reads_none(walls):
    short, long_ = read(walls, [Sonar(max_range=NORTH - 0.5), Sonar(max_range=NORTH + 0.5)])
    assert short.distance is None and short.hit is None
    assert long_.distance == pytest.approx(NORTH, abs=1e-3)


def test_nothing_in_front_reads_none(walls):
    (reading,) = read(walls, [Sonar(mount_yaw=180.0)])  # south: open
    assert reading.distance is None


def test_a_surface_closer_than_min_range_is_not_read(walls):
    (reading,) = read(walls, [Sonar(min_range=0.5)], pose=Pose(0.0, NORTH - 0.3, HEIGHT))
    assert reading.distance is None


@pytest.fixture
def slanted_wall(make_scene, box):
    """A wall 8 m north turned 70 degrees about z: a beam looking north meets it 70 degrees off its normal."""
    return make_scene(box(0, 8, 2, 40, 0.2, 10, rotation=f"0 0 1 {math.radians(70)}"))


def test_grazing_incidence_beyond_the_critical_angle_gives_no_echo(slanted_wall):
    (reading,) = read(slanted_wall, [Sonar(critical_angle=60.0)])
    assert reading.distance is None


def test_the_same_surface_echoes_when_the_critical_angle_allows_it(slanted_wall):
    axis, cone = read(slanted_wall, [Sonar(critical_angle=85.0, rings=0), Sonar(critical_angle=85.0)])
    assert axis.distance == pytest.approx(8.0 - 0.1 / math.cos(math.radians(70)), abs=1e-3)  # the centre ray alone
    assert 0.0 < cone.distance < axis.distance  # a cone meets a slanted wall sooner on its near side


def noisy_distances(scene, seed, n=20):
    array = SonarArray([Sonar(noise=0.05), Sonar("east", mount_yaw=90.0, noise=0.05)], RayCaster(scene.mesh), seed)
    return [tuple(r.distance for r in array.read(Pose(0.0, 0.0, HEIGHT), t)) for t in range(n)]


def test_noise_with_the_same_seed_gives_the_same_readings(walls):
    assert noisy_distances(walls, seed=3) == noisy_distances(walls, seed=3)


def test_noise_with_different_seeds_differs(walls):
    first, second = noisy_distances(walls, seed=3), noisy_distances(walls, seed=4)
    assert first != second
    values = np.array(first)
    assert np.std(values[:, 0]) == pytest.approx(0.05, rel=0.6)
    assert np.mean(values[:, 0]) == pytest.approx(NORTH, abs=0.05)


def test_noiseless_readings_repeat_exactly(walls):
    array = SonarArray([Sonar()], RayCaster(walls.mesh), seed=1)
    assert array.read(Pose(0, 0, HEIGHT), 0)[0].distance == array.read(Pose(0, 0, HEIGHT), 1)[0].distance


def test_noise_never_pushes_a_reading_past_max_range(walls):
    array = SonarArray([Sonar(noise=2.0, max_range=NORTH + 0.01)], RayCaster(walls.mesh), seed=0)
    distances = [array.read(Pose(0, 0, HEIGHT), t)[0].distance for t in range(50)]
    assert all(d is not None and d <= NORTH + 0.01 for d in distances)


# ---- servo --------------------------------------------------------------------------------------

def test_servo_centre_and_ends():
    servo = Servo()
    assert servo.angle() == 0.0
    assert servo.pwm_for(-90.0) == 1000 and servo.pwm_for(90.0) == 2000 and servo.pwm_for(45.0) == 1750


@pytest.mark.parametrize("angle", [-90.0, -63.3, -10.0, 0.0, 17.5, 89.9, 90.0])
def test_servo_pwm_angle_round_trip(angle):
    servo = Servo()
    servo.set_angle(angle)
    assert servo.angle() == pytest.approx(angle, abs=180 / 1000 / 2 + 1e-9)  # within half a microsecond step
    assert servo.pwm_for(servo.angle()) == servo.pwm


def test_servo_clamps_angles_beyond_its_travel():
    servo = Servo(pwm_min=1100, pwm_max=1900, angle_min=-60.0, angle_max=60.0)
    assert servo.pwm_for(200.0) == 1900 and servo.pwm_for(-200.0) == 1100
    servo.set_angle(75.0)
    assert servo.angle() == 60.0


def test_a_servo_turns_the_sensor(walls):
    servo = Servo()
    sonar = Sonar(servo=servo)
    array = SonarArray([sonar], RayCaster(walls.mesh))
    assert array.read(Pose(0, 0, HEIGHT), 0)[0].distance == pytest.approx(NORTH, abs=1e-3)
    servo.set_angle(90.0)  # clockwise: to the right, east while the vehicle faces north
    reading = array.read(Pose(0, 0, HEIGHT), 1)[0]
    assert reading.yaw_offset == 90.0
    assert reading.distance == pytest.approx(EAST, abs=1e-3)
    assert reading.direction == pytest.approx([1.0, 0.0, 0.0], abs=1e-9)


# ---- mounts and attitude ------------------------------------------------------------------------

def test_a_sensor_mounted_at_yaw_90_sees_the_east_wall_while_facing_north(walls):
    front, right = read(walls, [Sonar(), Sonar("right", mount_yaw=90.0)])
    assert right.distance == pytest.approx(EAST, abs=1e-3)
    assert right.direction == pytest.approx([1.0, 0.0, 0.0], abs=1e-9)
    assert right.yaw_offset == 90.0
    assert front.distance == pytest.approx(NORTH, abs=1e-3)


def test_the_vehicle_yaw_turns_every_sensor(walls):
    (front,) = read(walls, [Sonar()], pose=Pose(0.0, 0.0, HEIGHT, yaw=math.radians(90)))
    assert front.direction == pytest.approx([1.0, 0.0, 0.0], abs=1e-9)
    assert front.distance == pytest.approx(EAST, abs=1e-3)


def test_the_triple_suite_has_three_sensors_forward_and_45_degrees_each_side():
    suite = sensor_suite("triple", "rover")[:3]  # a rover's also looks down, a copter's also up (test_overhang)
    level = [s for s in sensor_suite("triple") if s.mount_pitch == 0]
    assert len(level) == 3 and [s.name for s in suite] == [s.name for s in level]
    assert sorted(s.mount_yaw for s in level) == [-45.0, 0.0, 45.0]
    assert len([s for s in sensor_suite("single") if s.mount_pitch == 0]) == 1
    assert set(SENSOR_SUITES) == {"single", "triple", "servo", "ground"}
    with pytest.raises(ValueError, match="unknown sensor suite"):
        sensor_suite("octo")


def test_the_world_reads_the_triple_suite_by_default(walls):
    world = Simulation(walls, Kind.COPTER, start=(0.0, 0.0))
    readings = []
    while not readings:
        readings = world.step()
    assert [r.sensor for r in readings] == [0, 1, 2, 3]  # the three level sonars and the overhead one
    assert [r.pitch for r in readings] == [0.0, 0.0, 0.0, 8.0]
    assert readings[0].distance == pytest.approx(NORTH, abs=1e-3)
    assert readings[0].origin == pytest.approx(world.pose.xyz())


def test_pitching_the_body_up_tilts_the_beam_up(walls):
    pose = Pose(0.0, 0.0, HEIGHT, pitch=math.radians(20))
    (reading,) = read(walls, [Sonar(rings=0)], pose=pose)  # the centre ray only: exact geometry
    assert reading.direction == pytest.approx([0.0, math.cos(math.radians(20)), math.sin(math.radians(20))], abs=1e-9)
    assert reading.distance == pytest.approx(NORTH / math.cos(math.radians(20)), abs=1e-3)
    assert reading.hit[2] == pytest.approx(HEIGHT + NORTH * math.tan(math.radians(20)), abs=1e-3)


def test_rolling_right_side_down_tips_a_right_looking_beam_down(walls):
    roll = math.radians(15)
    right, left = read(walls, [Sonar("right", mount_yaw=90.0), Sonar("left", mount_yaw=-90.0)],
                       pose=Pose(0.0, 0.0, HEIGHT, roll=roll))
    assert right.direction == pytest.approx([math.cos(roll), 0.0, -math.sin(roll)], abs=1e-9)
    assert left.direction == pytest.approx([-math.cos(roll), 0.0, math.sin(roll)], abs=1e-9)


def test_yaw_pitch_and_roll_compose_into_a_rotation(walls):
    pose = Pose(yaw=math.radians(30), pitch=math.radians(10), roll=math.radians(-25))
    rotation = body_to_world(pose)
    assert rotation @ rotation.T == pytest.approx(np.eye(3), abs=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    forward = rotation @ [1.0, 0.0, 0.0]  # roll does not move the nose
    assert forward == pytest.approx([math.sin(math.radians(30)) * math.cos(math.radians(10)),
                                     math.cos(math.radians(30)) * math.cos(math.radians(10)),
                                     math.sin(math.radians(10))], abs=1e-12)
    (reading,) = read(walls, [Sonar()], pose=pose)
    assert reading.direction == pytest.approx(forward, abs=1e-9)


def test_mount_pitch_tilts_the_beam(walls):
    (reading,) = read(walls, [Sonar(mount_pitch=-90.0)], pose=Pose(0.0, 0.0, HEIGHT))
    assert reading.direction == pytest.approx([0.0, 0.0, -1.0], abs=1e-9)
    assert reading.distance is None  # the walls have no ground under the sensor here


def test_cone_rays_are_unit_vectors_within_the_beam():
    rays = cone_rays(math.radians(7.5), rings=2)
    assert rays.shape == (1 + 6 + 12, 3)  # ring k holds 6 k rays: as far apart around as between rings
    assert np.linalg.norm(rays, axis=1) == pytest.approx(np.ones(len(rays)))
    angles = np.degrees(np.arccos(np.clip(rays[:, 0], -1, 1)))
    assert angles.max() == pytest.approx(7.5) and angles[0] == 0.0
    assert np.count_nonzero(np.isclose(angles, 3.75)) == 6


def test_a_small_face_off_the_beam_axis_still_echoes():
    """The end of a thin wall (0.13 x 0.3 m) 8 m away, 5 degrees off the axis (within the 7.5 degree cone):
    a real sonar hears it, and the default cone is dense enough to find it (a cone of 7 rays missed such a
    wall end, and a copter flew along the wall into it)."""
    import trimesh

    from vehicle.world.raycast import RayCaster
    from vehicle.world.sonar import SonarArray

    off_axis = math.radians(5.0)
    post = trimesh.creation.box(extents=(0.13, 0.13, 0.3))
    post.apply_translation((8.0 * math.sin(off_axis), 8.0 * math.cos(off_axis), 0.0))
    (reading,) = SonarArray([Sonar()], RayCaster(post)).read(Pose(0.0, 0.0, 0.0), 0.0)
    assert reading.distance == pytest.approx(8.0, abs=0.2)


def test_sonar_axis_matches_the_reading_direction(walls):
    pose = Pose(1.0, -2.0, HEIGHT, yaw=math.radians(200), pitch=math.radians(-5), roll=math.radians(12))
    sonar = Sonar("left", mount_yaw=-45.0, mount_pitch=10.0)
    (reading,) = read(walls, [sonar], pose=pose)
    assert reading.direction == pytest.approx(sonar.axis(pose), abs=1e-12)
    assert reading.origin == pytest.approx([1.0, -2.0, HEIGHT])


def test_the_servo_suite_turns_its_sonar_with_the_autopilot_output(walls):
    world = Simulation(walls, Kind.COPTER, start=(0.0, 0.0), sensors=sensor_suite("servo"))
    servo = world.servo
    assert servo is not None and servo.angle() == 0.0
    world.autopilot.set_servo(servo.channel, servo.pwm_for(90.0))
    readings = []
    while not readings:
        readings = world.step()
    assert readings[0].yaw_offset == pytest.approx(90.0)
    assert readings[0].direction[0] == pytest.approx(1.0, abs=1e-6)  # facing north, the beam looks east
