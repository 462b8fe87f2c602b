"""Team-mates give way in every phase: on AUTO missions (the square), taking off and landing, and the margin is a
sphere: vehicles far enough apart in height pass each other."""

from __future__ import annotations

import math

from vehicle.agent.agent import Agent, Phase
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import TeamStepper, simulate_team
from vehicle.sim.simulation import Simulation
from vehicle.sim.team import Team


def fly(stepper: TeamStepper, limit: float = 300.0, until=None) -> None:
    """Step the team until every agent is done (or ``until()``, or the limit)."""
    while stepper.team.time < limit and not all(a.done for a in stepper.agents):
        stepper.step()
        if until is not None and stepper.monitor_due and until():
            return


def fly_across(stepper: TeamStepper) -> float:
    """Fly a team of two till both are done; the closest they came across (horizontally), m between centres."""
    closest = math.inf
    while stepper.team.time < 200 and not all(a.done for a in stepper.agents):
        stepper.step()
        a, b = (s.pose for s in stepper.team.simulations)
        closest = min(closest, math.hypot(a.x - b.x, a.y - b.y))
    return closest


def said(agent, words: str) -> list[str]:
    return [m for m in agent.messages if words in m]


def test_two_auto_squares_that_cross_keep_their_separation(flat_scene):
    """One flies its square clockwise, the other the same square the other way round from 6 m east: they meet
    head on along its north side and again on the south one. Before, AUTO missions never gave way: they
    collided at (-2.7, 7.7)."""
    corners = [(-8.0, 8.0), (8.0, 8.0), (8.0, -8.0), (-8.0, -8.0)]
    stepper = simulate_team(flat_scene, "square", 2, settings=Settings().updated({"time_limit": 300}),
                            starts=[(0.0, 0.0), (6.0, 0.0)], waypoints=[corners, [corners[i] for i in (1, 0, 3, 2)]])
    fly(stepper)
    assert all(s.collision is None for s in stepper.team.simulations)
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"]
    assert stepper.team.closest_gap >= 2.0
    assert all(said(a, "Traffic: back to AUTO") for a in stepper.agents if said(a, "Traffic: giving way"))
    assert said(stepper.agents[1], "giving way to vehicle 1 (lower system id)")


def copter_and_rover(flat_scene, rover_start, copter_start, settings) -> TeamStepper:
    """A rover (vehicle 1) browsing at its start and a copter (vehicle 2) flying Pathfind, in one world."""
    team = Team([Simulation(flat_scene, "rover", rover_start, cruise_speed=settings.speed),
                 Simulation(flat_scene, "copter", copter_start, cruise_speed=settings.speed, seed=1)])
    return TeamStepper(team, "browse", settings)


def test_a_copter_never_lands_onto_a_team_mate_below_it(flat_scene):
    """The copter flies 10 m north and home again; meanwhile the rover is sent to stand on the copter's home. The
    copter holds its landing above it, and lands once the rover has gone. Before, it landed onto the rover."""
    settings = Settings().updated({"time_limit": 300})
    # the rover 6 m from the copter's home: at 1.6 m/s (what its ground sonar's sight allows) it is there while
    # the copter is still high
    stepper = copter_and_rover(flat_scene, (0.0, 0.0), (6.0, 0.0), settings)
    rover, copter = stepper.agents
    stepper.agents[1] = copter = Agent(stepper.controllers[1], "pathfind", settings, [(6.0, 10.0)])
    fly(stepper, until=lambda: copter.phase is Phase.HOMING)
    assert rover.go_to((6.0, 0.0)) is None
    fly(stepper, until=lambda: bool(said(copter, "holding the landing")))
    assert said(copter, "Traffic: holding the landing: vehicle 1 is below")
    hold = stepper.team.time + 20.0
    fly(stepper, limit=hold)
    assert copter.phase is Phase.LANDING and not copter.done  # still held above the rover
    assert rover.go_to((-6.0, 0.0)) is None  # the rover leaves: the copter lands
    fly(stepper, until=lambda: copter.done)
    assert copter.done and said(copter, "Traffic: clear below; landing")
    assert all(s.collision is None for s in stepper.team.simulations)
    assert stepper.team.closest_gap >= 1.0  # held a margin above it (the gap between the bodies)


def test_a_copter_does_not_take_off_under_a_team_mate(flat_scene):
    """Vehicle 1 is sent to hover over vehicle 2, on the ground waiting for its start: started then, vehicle 2
    waits to take off till vehicle 1 has gone. Before, it climbed into it."""
    settings = Settings().updated({"time_limit": 300})
    stepper = simulate_team(flat_scene, "browse", 2, settings=settings, starts=[(0.0, 0.0), (6.0, 0.0)])
    above = stepper.agents[0]
    below = stepper.agents[1] = Agent(stepper.controllers[1], "browse", settings, autostart=False)
    fly(stepper, until=lambda: above.phase is Phase.MISSION)
    assert above.go_to((6.0, 0.0)) is None
    fly(stepper, until=lambda: above.paused and above.ctx.distance_to((6.0, 0.0)) < 0.3
        and above.fc.speed < 0.1)
    assert below.start()
    fly(stepper, limit=stepper.team.time + 15.0)
    assert said(below, "Traffic: waiting to take off: vehicle 1 is above") and not below.fc.flying
    above.resume()  # it browses on at its home: the one below takes off
    fly(stepper)
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"]
    assert all(s.collision is None for s in stepper.team.simulations)
    assert stepper.team.closest_gap >= 1.0


def test_copters_apart_in_height_cross_without_giving_way(flat_scene):
    """The margin is a sphere: a copter at 9 m crosses one at 4 m (5 m apart in height, beyond the 2.6 m margin
    between their centres); neither gives way. At one height they do (test_team_agents)."""
    settings = Settings().updated({"time_limit": 200})
    stepper = simulate_team(flat_scene, "pathfind", 2, settings=settings, starts=[(-18.0, 0.0), (0.0, -12.0)],
                            waypoints=[[(12.0, 0.0)], [(0.0, 12.0)]])
    stepper.agents[1] = Agent(stepper.controllers[1], "pathfind", settings.updated({"altitude": 9.0}), [(0.0, 12.0)])
    assert fly_across(stepper) < 1.0  # one passed over the other
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"]
    assert not any(said(a, "Traffic") for a in stepper.agents)
    assert stepper.team.closest_gap > 2.0


def test_a_copter_crosses_a_rover_below_without_either_giving_way(flat_scene):
    """The rule for a copter at 4 m and a rover on the ground: over 2.6 m apart in height, they are no conflict."""
    settings = Settings().updated({"time_limit": 200})
    # the rover at 1.6 m/s (what its ground sonar's sight allows) meets the copter's track as the copter passes
    stepper = copter_and_rover(flat_scene, (-11.5, 0.0), (0.0, -12.0), settings)
    for k, goal in enumerate([(12.0, 0.0), (0.0, 12.0)]):
        stepper.agents[k] = Agent(stepper.controllers[k], "pathfind", settings, [goal])
    assert fly_across(stepper) < 1.0  # the copter passed over the rover
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"]
    assert not any(said(a, "Traffic") for a in stepper.agents)
    assert stepper.team.closest_gap > 2.0
