"""What makes a team cheap must not change what it senses: the traffic picture made once a step, and the
compiled ray-sphere test of the bodies in a sonar's cone."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate_team
from vehicle.protocol.frames import Pose, body_to_world
from vehicle.protocol.traffic import Traffic
from vehicle.sim.simulation import Simulation
from vehicle.world.sonar import Bodies, Sonar


def test_each_agent_sees_its_team_mates_as_they_are_at_every_step(flat_scene):
    """Asked any number of times in a step, the traffic is every other vehicle's state at that step, never an
    earlier step's (the picture is made once a step and must be made again at the next)."""
    stepper = simulate_team(flat_scene, "search", 3, settings=Settings().updated({"time_limit": 60}))
    team = stepper.team
    moved = 0
    for _ in range(300):  # 15 s: taking off and setting out
        stepper.step()
        for controller, own in zip(stepper.controllers, team.simulations, strict=True):
            expected = [Traffic(vehicle, *sim.body.pose.xyz(), sim.body.vx, sim.body.vy, sim.limits.radius,
                                sim.time) for vehicle, sim in zip(team.ids, team.simulations, strict=True)
                        if sim is not own]
            assert controller.traffic() == expected
            assert controller.traffic() == expected  # asked again in the same step
        moved += any(math.hypot(s.body.vx, s.body.vy, s.body.vz) > 0.1 for s in team.simulations)
    assert moved > 100  # the team flew, so a stale picture would have shown


def test_the_nearest_body_in_a_cone_echoes_and_is_named_and_a_grazed_one_does_not(flat_scene):
    sim = Simulation(flat_scene, "copter", (0.0, 0.0), sensors=[Sonar("front", rings=3)])
    pose = Pose(0.0, 0.0, 4.0, yaw=0.0)  # the front sonar looks north
    near, far = (0.0, 5.0, 4.0), (0.0, 9.0, 4.0)
    behind = (0.0, -2.0, 4.0)
    bodies = Bodies(np.array([4, 5, 6]), np.array([far, near, behind]), np.array([0.5, 0.3, 0.5]))
    [reading] = sim.sonars.read(pose, 0.0, bodies)
    assert reading.vehicle == 5 and reading.distance == pytest.approx(5.0 - 0.3, abs=1e-9)
    # a sphere one edge ray of the cone just grazes (outside the cone, 0.99 of its radius off that ray): the
    # ray meets its surface far beyond the critical angle, so there is no echo
    rays, axes = sim.sonars._body_rays()
    edge_ray = rays[-1] @ body_to_world(pose).T
    axis = axes[0] @ body_to_world(pose).T
    outward = axis - edge_ray * float(edge_ray @ axis)
    centre = np.array(pose.xyz()) + 5.0 * edge_ray - 0.99 * 0.3 * outward / np.linalg.norm(outward)
    [reading] = sim.sonars.read(pose, 0.0, Bodies(np.array([8]), np.array([centre]), np.array([0.3])))
    assert reading.vehicle is None and reading.distance is None
