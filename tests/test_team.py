"""A team in one world: each vehicle a body the others' sonars echo off and the collision check sweeps."""

from __future__ import annotations

import pytest

from vehicle.sim.simulation import PlacementError, Simulation
from vehicle.sim.team import Team
from vehicle.world.suites import sensor_suite


def hovering_team(scene, starts, sensors="single", ids=None) -> Team:
    """Copters at ``starts`` (all facing north), in the air at 4 m."""
    team = Team([Simulation(scene, "copter", start, heading=0.0, sensors=sensor_suite(sensors) if sensors else [])
                 for start in starts], ids)
    for sim in team.simulations:
        sim.autopilot.set_mode("GUIDED")
        assert sim.autopilot.arm() == 0
        assert sim.autopilot.takeoff(4.0) == 0
    for _ in range(200):  # 10 s
        team.step()
    return team


def front_readings(readings_by_vehicle, index):
    return [r for r in readings_by_vehicle[index] if r.sensor == 0]


def test_a_sonar_aimed_at_a_hovering_team_mate_reads_its_distance_and_names_it(flat_scene):
    team = hovering_team(flat_scene, [(0.0, 0.0), (0.0, 6.0)], ids=[3, 7])
    readings = []
    for _ in range(4):
        readings.append(team.step())
    seen = [r for step in readings for r in front_readings(step, 0)]
    assert seen, "no reading was due in 4 steps"
    for reading in seen:
        assert reading.distance == pytest.approx(6.0 - 0.3, abs=0.05)  # to the near side of its body
        assert reading.vehicle == 7
    # the one behind: its front sonar looks away, into nothing
    assert all(r.distance is None and r.vehicle is None for step in readings for r in front_readings(step, 1))


def test_alone_the_same_sonar_hears_nothing(flat_scene):
    team = hovering_team(flat_scene, [(0.0, 0.0)])
    readings = [r for _ in range(4) for r in front_readings(team.step(), 0)]
    assert readings and all(r.distance is None for r in readings)


def test_the_scene_nearer_than_a_team_mate_wins(make_scene, box):
    from tests.conftest import GROUND

    scene = make_scene(GROUND, box(0, 3.5, 2, 4, 0.2, 4))  # a wall between the two
    team = hovering_team(scene, [(0.0, 0.0), (0.0, 6.0)])
    readings = [r for _ in range(4) for r in front_readings(team.step(), 0)]
    assert readings
    for reading in readings:
        assert reading.distance == pytest.approx(3.4, abs=0.05) and reading.vehicle is None


def test_two_bodies_driven_into_each_other_collide_and_the_contact_names_both(flat_scene):
    team = hovering_team(flat_scene, [(0.0, 0.0), (0.0, 8.0)], sensors=None, ids=[4, 2])  # no sonar: no avoidance
    a, b = team.simulations
    a.autopilot.goto(0.0, 8.0, 4.0)
    b.autopilot.goto(0.0, 0.0, 4.0)
    for _ in range(400):
        team.step()
        if a.collision is not None:
            break
    assert a.collision is not None and b.collision is not None
    assert a.collision.vehicles == b.collision.vehicles == (4, 2)
    assert "vehicles 4 and 2" in a.collision.describe()
    gap = abs(a.pose.y - b.pose.y)  # they stop where they first touched: one body's width apart
    assert gap == pytest.approx(0.6, abs=0.02)
    assert team.closest_gap < 0 and team.closest_pair == (4, 2)
    assert not a.autopilot.armed and not b.autopilot.armed


def test_bodies_that_pass_apart_do_not_collide_and_their_closest_approach_is_kept(flat_scene):
    team = hovering_team(flat_scene, [(-10.0, 0.0), (10.0, 1.5)], sensors=None)
    a, b = team.simulations
    a.autopilot.goto(10.0, 0.0, 4.0)
    b.autopilot.goto(-10.0, 1.5, 4.0)
    for _ in range(300):
        team.step()
    assert a.collision is None and b.collision is None
    assert team.closest_gap == pytest.approx(1.5 - 0.6, abs=0.05)


def test_the_same_command_gives_the_same_flight_twice(flat_scene):
    def fly():
        team = hovering_team(flat_scene, [(0.0, 0.0), (0.0, 6.0), (5.0, 3.0)], sensors="triple")
        team.simulations[0].autopilot.goto(5.0, 8.0, 4.0)
        team.simulations[2].autopilot.goto(-5.0, 3.0, 4.0)
        echoes = []
        for _ in range(300):
            echoes += [(r.time, r.sensor, r.distance, r.vehicle) for rs in team.step() for r in rs]
        return echoes, [s.pose.xyz() for s in team.simulations], team.closest_gap

    first, second = fly(), fly()
    assert first == second
    assert any(vehicle is not None for *_, vehicle in first[0])


def test_the_closest_approach_to_the_scene_leaves_the_ground_out(make_scene, box):
    from tests.conftest import GROUND

    scene = make_scene(GROUND, box(3, 0, 2, 0.2, 4, 4))  # a wall 2.9 m east
    team = hovering_team(scene, [(0.0, 0.0), (-20.0, 0.0)], sensors=None)
    near, far = team.scene_gaps
    assert near.gap == pytest.approx(2.9 - 0.3, abs=0.01)  # not the ground it took off from
    assert far.gap is None


@pytest.mark.parametrize("starts, ids, words", [
    ([], None, "at least one vehicle"),
    ([(0.0, 0.0), (0.4, 0.0)], None, "start inside each other"),
    ([(0.0, 0.0), (4.0, 0.0)], [2, 2], "system id 2"),
])
def test_a_team_that_cannot_be_is_refused_before_it_starts(flat_scene, starts, ids, words):
    with pytest.raises(PlacementError, match=words):
        Team([Simulation(flat_scene, "copter", start) for start in starts], ids)


def test_the_cone_precheck_skips_only_bodies_no_ray_can_meet(flat_scene):
    """Bodies all around, near and far, at every angle off the beams: a read that tests only the bodies the
    scalar pre-check lets through echoes exactly as one that tests every body, and most reads test none."""
    import numpy as np

    from vehicle.protocol.frames import Pose
    from vehicle.world.sonar import Bodies, SonarArray

    sim = Simulation(flat_scene, "copter", (0.0, 0.0), sensors=sensor_suite("triple"))
    sonars: SonarArray = sim.sonars
    everyone = sonars._in_cones
    rng = np.random.default_rng(4)
    skipped = hits = 0
    for trial in range(400):
        pose = Pose(0.0, 0.0, 4.0, yaw=float(rng.uniform(0, 2 * np.pi)))
        count = int(rng.integers(1, 6))
        centres = np.column_stack([rng.uniform(-12, 12, count), rng.uniform(-12, 12, count),
                                   rng.uniform(2.5, 5.5, count)])
        bodies = Bodies(np.arange(10, 10 + count), centres, rng.uniform(0.2, 1.0, count))
        picked = sonars.read(pose, trial, bodies)
        sonars._in_cones = lambda xyz, axes, b: list(range(len(b.ids)))
        brute = sonars.read(pose, trial, bodies)
        sonars._in_cones = everyone
        assert [r.vehicle for r in picked] == [r.vehicle for r in brute]
        assert [r.distance for r in picked] == pytest.approx([r.distance for r in brute], abs=1e-9)
        skipped += not everyone((0.0, 0.0, 4.0), (sonars._body_rays()[1] @ _to_world(pose)).tolist(), bodies)
        hits += any(r.vehicle is not None for r in brute)
    assert hits > 40 and skipped > 100  # both kinds of read were tried


def _to_world(pose):
    from vehicle.protocol.frames import body_to_world

    return body_to_world(pose).T


@pytest.mark.parametrize("start, words", [
    ((0.0, 0.0), None),  # 2.7 m from the wall: clear
    ((2.5, 0.0), "would climb and land within 0.20 m of the scene"),  # beside a wall below the flight height
    ((3.75, 0.0), "would climb and land within 0.15 m of the scene"),  # on its far side
])
def test_a_copter_start_whose_column_passes_a_wall_top_is_refused(make_scene, box, start, words):
    """A copter climbs straight up from its start and lands back down the same column, as precisely as a
    position hold (giving way moves it about): in a team run one landed 0.4 m off its spot onto the top of a
    3 m wall its start was 0.03 m from. A start whose column passes within the padding of the scene above
    the ground's reach is refused before anything flies."""
    from tests.conftest import GROUND
    from vehicle.agent.settings import Settings
    from vehicle.lab.stepper import simulate_team

    scene = make_scene(GROUND, box(3.15, 0, 1.5, 0.3, 4, 3))  # a wall 3 m high, its faces at x = 3.0 and 3.3
    settings = Settings(altitude=4.0, padding=0.5)
    if words is None:
        assert simulate_team(scene, "search", 1, settings=settings, starts=[start]) is not None
    else:
        with pytest.raises(PlacementError, match=words):
            simulate_team(scene, "search", 1, settings=settings, starts=[start])


def test_a_team_of_one_reads_and_flies_as_a_lone_vehicle_and_keeps_its_gap_to_the_scene(make_scene, box):
    """A team of one takes its own short way through a step (no pair, no other body): the same readings and
    flight as the vehicle alone, and the team's scene-gap figure still measured."""
    from tests.conftest import GROUND

    scene = make_scene(GROUND, box(3, 0, 2, 0.2, 4, 4))  # a wall 2.9 m east

    def fly(step_of):
        sim = Simulation(scene, "copter", (0.0, 0.0), heading=90.0, sensors=sensor_suite("triple"))
        step = step_of(sim)
        sim.autopilot.set_mode("GUIDED")
        assert sim.autopilot.arm() == 0 and sim.autopilot.takeoff(4.0) == 0
        echoes = []
        for k in range(400):
            if k == 200:
                sim.autopilot.goto(1.5, 0.0, 4.0)
            echoes += [(r.time, r.sensor, r.distance) for r in step()]
        return echoes, sim.pose.xyz()

    alone = fly(lambda sim: sim.step)
    teams = []
    together = fly(lambda sim: teams.append(Team([sim])) or (lambda: teams[0].step()[0]))
    assert together == alone and any(distance is not None for _, _, distance in alone[0])
    assert teams[0].scene_gaps[0].gap == pytest.approx(2.9 - 0.3 - 1.5, abs=0.05)
