"""Regression tests for bugs found while writing the mission and monitor tests (each failed before its fix).
"""

import math

import numpy as np

from vehicle.agent.missions.base import Context
from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, run_experiment
from vehicle.lab.stepper import simulate
from vehicle.mapping.memory_map import MemoryMap
from vehicle.sim.onboard import SimController
from vehicle.sim.simulation import Simulation
from vehicle.world.scene import parse_scene


def box(x, y, z, sx, sy, sz):
    return f"Transform {{ translation {x} {y} {z} children Shape {{ geometry Box {{ size {sx} {sy} {sz} }} }} }}\n"


def scene(*walls):
    return parse_scene("#VRML V2.0 utf8\n" + box(0, 0, -0.05, 80, 80, 0.1) + "".join(box(*w) for w in walls))


def context_near_wall(position):
    settings = Settings(space_size=20)
    world = Simulation(scene(), "copter")
    grid = MemoryMap((0.0, 0.0), 20, 10)
    (r0, c0), (r1, c1) = grid.cell_of(-5, 4.9), grid.cell_of(5, 5.1)
    grid.grid[:r0, :] = MemoryMap.FREE_AT  # the sonar saw the space south of the wall free
    grid.grid[r0:r1 + 1, c0:c1 + 1] = MemoryMap.LIMIT  # a known wall, y 4.9..5.1, x -5..5
    ctx = Context(SimController(world), grid, Monitor(settings, grid, (0, 0), 0.3), settings, say=lambda t: None)
    world.body.pose.x, world.body.pose.y = position
    return ctx


def crosses_wall(chain):
    for (ax, ay), (bx, by) in zip(chain[:-1], chain[1:], strict=False):
        for t in np.linspace(0, 1, 400):
            x, y = ax + (bx - ax) * t, ay + (by - ay) * t
            if abs(x) <= 5 + 0.3 and 4.9 - 0.3 <= y <= 5.1 + 0.3:
                return True
    return False


def test_bug1_path_clear_says_a_line_through_a_known_wall_is_clear_when_starting_within_the_margin():
    # vehicle 0.6 m in front of the wall (inside radius + padding = 0.8 m), goal straight behind it
    ctx = context_near_wall((0.0, 4.3))
    assert not ctx.path_clear([(0.0, 14.0)], horizon=math.inf, padding=0.5)


def test_bug1_plan_from_next_to_a_wall_goes_straight_through_it():
    ctx = context_near_wall((0.0, 4.4))
    path, _ = ctx.plan((-8.0, 8.0))
    assert path is not None
    assert not crosses_wall([ctx.position, *path]), path


def test_bug1_pathfind_livelocks_at_a_wall_end():
    # a 4 m wall between home and a waypoint 14 m north; closeness 1 m. Straightforward detour, yet
    # the copter stops/scans/replans at (2.2, 4.15) every ~9.5 s until its time budget runs out
    result = run_experiment(Experiment("x", "pathfind", settings=Settings(space_size=20, time_limit=300,
                                                                           closeness=1.0),
                                       waypoints=[(0.0, 14.0)]), scene=scene((0, 5, 2, 4, 0.2, 6)))
    assert result["outcome"] == "finished", result["reason"]
    assert result["sim_time_s"] < 120


def test_bug1_square_without_avoidance_collides_on_the_way_home():
    # the monitor stops the square in front of a wall across its east leg; homing then plans a
    # straight line home that grazes the wall end (path_clear skips the margin) and, with the
    # autopilot's avoidance off, creeps into it scan after scan
    def no_avoidance(stepper, readings):
        stepper.simulation.autopilot.avoidance = None

    result = run_experiment(Experiment("x", "square", settings=Settings(space_size=20, time_limit=200)),
                            scene=scene((5, 0, 2, 4, 0.2, 6)), on_step=no_avoidance)
    assert result["outcome"] != "collision", result["reason"]


class Flight:
    def __init__(self, mission, kind="copter", waypoints=None):
        self.stepper = simulate(scene((0, 6, 2, 8, 0.2, 6)), mission, kind, Settings(space_size=20, time_limit=200),
                                waypoints=waypoints)
        self.world, self.agent = self.stepper.simulation, self.stepper.agent

    def run(self, seconds, until=None):
        return self.stepper.run(seconds, until)


def _pause_and_resume(flight, stop_mode="BRAKE"):
    flight.run(30, until=lambda: flight.agent.phase.value == "mission")
    flight.run(3)
    flight.world.autopilot.set_mode(stop_mode, source="gcs")
    flight.run(5)
    assert flight.agent.paused
    assert flight.agent.resume()
    flight.run(120, until=lambda: flight.agent.done)


def test_bug2_resumed_pathfind_continues_to_its_waypoints():
    flight = Flight("pathfind", waypoints=[(0.0, 3.0), (5.0, 3.0)])
    _pause_and_resume(flight)
    assert flight.agent.done and flight.agent.outcome == "finished", (flight.agent.outcome, flight.agent.reason)


def test_bug2_resumed_browse_finishes_its_turn():
    flight = Flight("browse")
    _pause_and_resume(flight)
    assert flight.agent.done and flight.agent.outcome == "finished", (flight.agent.outcome, flight.agent.reason)


def test_bug3_the_monitor_lets_the_vehicle_get_well_inside_the_safety_distance():
    # The monitor must stop the vehicle before it gets closer than the safety distance. With closeness 2 m
    # and the autopilot's avoidance off, a copter on the square's east leg was flagged at 1.7 m and came
    # to rest 0.51 m (centre) from the wall face: the monitor only reacted once inside `closeness`,
    # ignoring the braking distance (v^2 / 2a = 1.25 m at 2.5 m/s) and the monitor period (0.25 s = 0.6 m).
    settings = Settings(space_size=20, time_limit=200)
    stepper = simulate(scene((5, 0, 2, 4, 0.2, 6)), "square", "copter", settings)
    world, agent = stepper.simulation, stepper.agent
    world.autopilot.avoidance = None
    closest = math.inf
    while world.time < 60 and agent.phase.value in ("preflight", "takeoff", "mission"):
        stepper.step()
        if 3 < world.pose.x < 7:
            closest = min(closest, abs(world.pose.y - 0.1))
    for _ in range(100):  # and while it brakes after the stop (not the trip home past the wall's end)
        if world.body.speed < 0.7:
            break
        stepper.step()
        if 3 < world.pose.x < 7:
            closest = min(closest, abs(world.pose.y - 0.1))
    assert agent.outcome == "stopped"
    assert closest >= settings.closeness - world.limits.radius, closest


def test_bug2_auto_and_mission_start_within_one_monitor_period_pause_the_agent_again():
    # The endpoint's AUTO (set_mode source "gcs") + MISSION_START (agent.resume()) arriving in the same
    # 0.25 s monitor period: resume() does not take the operator's AUTO as seen (_mode_changes), so the
    # next Agent.step() treats it as a new takeover and pauses again ("paused, operator switched to AUTO").
    # The square then flies on unmonitored and the agent never finishes.
    flight = Flight("square")
    flight.run(8)
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    flight.run(3)
    assert flight.agent.paused
    flight.world.autopilot.set_mode("AUTO", source="gcs")
    flight.world.autopilot.start_mission()
    assert flight.agent.resume()
    flight.run(1)
    assert not flight.agent.paused, flight.agent.messages[-2:]
