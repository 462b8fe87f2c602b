"""The card shows how far the agent's mission is: the agent sends its waypoints done and in all and the time
left of its time budget (TUNNEL AGENT_PROGRESS beside its AGENT_STATUS), and the station shows them under the
agent in /api/vehicles; a malformed payload is dropped, the last good one kept."""

from __future__ import annotations

import math

from groundstation.state import Fleet
from vehicle.agent.companion import Companion
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import simulate
from vehicle.protocol import agent_status
from vehicle.protocol.mav import mavlink


def test_the_agent_s_waypoints_done_and_time_left_reach_the_card(flat_scene):
    settings = Settings(space_size=20, time_limit=300)
    stepper = simulate(flat_scene, "pathfind", "copter", settings, waypoints=[(0.0, 4.0), (4.0, 4.0)])
    agent, world = stepper.agent, stepper.simulation
    while world.time < 120 and not (agent.phase.value == "mission" and agent.mission.index == 1):
        stepper.step()
    assert agent.mission.index == 1, "never reached the first waypoint"
    companion = Companion(agent, 1)
    fleet = Fleet()
    heartbeat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                  mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4, 3)
    heartbeat.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    fleet.apply(heartbeat, 10.0)
    packer = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    for message in companion.tick(world.time):
        message.pack(packer)
        fleet.apply(message, 10.0)
    progress = fleet.describe(fleet.vehicles[1], 10.0)["agent"]["progress"]
    assert progress["done"] == 1 and progress["total"] == 2
    assert math.isclose(progress["time_left"], settings.time_limit - (world.time - agent.ctx.started), abs_tol=1.5)

    broken = mavlink.MAVLink_tunnel_message(0, 0, agent_status.AGENT_PROGRESS, 4, [9, 0, 1, 0] + [0] * 124)
    broken.pack(packer)
    fleet.apply(broken, 11.0)  # 9 done of 1: dropped
    assert fleet.describe(fleet.vehicles[1], 11.0)["agent"]["progress"] == progress
