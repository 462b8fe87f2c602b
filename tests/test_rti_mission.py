"""--mission rti: a team stops at paired spots round the region and waits for each other; a late partner is
waited for, a lost one is said and the mission ends with that reason, never a silent stop."""

from __future__ import annotations

import math

from vehicle.agent.missions.rti import Phase
from vehicle.agent.settings import Settings
from vehicle.lab.stepper import TeamStepper, simulate_team

REGION = {"rti_x0": 4.0, "rti_y0": 4.0, "rti_x1": 10.0, "rti_y1": 10.0}


def team(scene, count=2, **settings) -> TeamStepper:
    values = {"time_limit": 400, "rti_dwell": 2.0, "rti_rounds": 3, **REGION, **settings}
    return simulate_team(scene, "rti", count, settings=Settings().updated(values))


def fly(stepper: TeamStepper, until: float, asleep: dict[int, float] | None = None, watch=None) -> None:
    """Step the team to ``until`` s (or every agent done); vehicle k's agent is not stepped before
    ``asleep[k]`` s (a partner that is late: its autopilot waits on the ground). ``watch()`` after every step."""
    asleep = asleep or {}
    for index, agent in enumerate(stepper.agents):
        wake = asleep.get(index)
        if wake is not None:
            awake = agent.step
            agent.step = lambda awake=awake, wake=wake: awake() if stepper.team.time >= wake else None
    while stepper.team.time < until and not all(a.done for a in stepper.agents):
        stepper.step()
        if watch is not None:
            watch()


def said(agent, words: str) -> list[str]:
    return [m for m in agent.messages if words in m]


def test_a_pair_flies_its_rounds_at_the_same_spots_and_measures_together(flat_scene):
    stepper = team(flat_scene)
    dwelling = []  # (each one's position, each one's plan of the round) while both dwell

    def watch():
        missions = [a.mission for a in stepper.agents]
        if all(a.phase == "mission" and getattr(a.mission, "phase", None) is Phase.DWELL for a in stepper.agents):
            dwelling.append(([(s.pose.x, s.pose.y) for s in stepper.team.simulations], [m.spots for m in missions]))

    fly(stepper, 400, watch=watch)
    first, second = stepper.agents
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"], [a.reason for a in stepper.agents]
    assert first.reason == second.reason == "3 rounds measured, 3 links"
    assert dwelling, "the two never dwelt at the same time"
    rounds = set()
    for positions, (plan_1, plan_2) in dwelling:
        assert plan_1 == plan_2  # the same plan on both, exchanging nothing
        assert math.dist(positions[0], plan_1[1]) < 0.5 and math.dist(positions[1], plan_1[2]) < 0.5
        rounds.add(tuple(plan_1.items()))
    assert len(rounds) == 3  # three rounds, each at its own pair of spots
    assert stepper.team.closest_gap >= Settings().separation


def test_a_late_partner_is_waited_for(flat_scene):
    stepper = team(flat_scene, rti_rounds=1, rti_wait=120)
    first, second = stepper.agents
    held = []

    def watch():
        mission = getattr(first, "mission", None)
        if getattr(mission, "phase", None) is Phase.WAIT:
            held.append((stepper.team.time, first.fc.pose.x, first.fc.pose.y, mission.rounds))

    fly(stepper, 300, asleep={1: 60.0}, watch=watch)
    assert held and held[0][0] < 40  # vehicle 1 was at its spot long before its partner woke
    assert held[-1][0] > 60  # and held there, waiting, till after it
    spot = first.mission.spot
    assert all(math.dist((x, y), spot) < 0.8 and rounds == 0 for _, x, y, rounds in held)
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"]
    assert not said(first, "lost")


def test_a_lost_partner_is_said_and_ends_the_mission_with_that_reason(flat_scene):
    stepper = team(flat_scene, rti_wait=15)
    first, second = stepper.agents
    fly(stepper, 200, asleep={1: 1e9})  # vehicle 2 never leaves the ground
    assert first.outcome == "stopped"
    assert first.reason == "partner vehicle 2 lost in round 1: no link left to measure"
    assert said(first, "Rti: partner vehicle 2 did not reach its spot")
    assert said(first, "in 15 s (last seen at (-4.0, -4.0)): lost")
    assert first.done  # it went home and landed: no silent stop mid-air


def test_a_team_of_three_goes_on_without_a_lost_partner(flat_scene):
    stepper = team(flat_scene, count=3, rti_wait=15, rti_rounds=2)
    first, second, third = stepper.agents
    fly(stepper, 300, asleep={2: 1e9})
    for agent in (first, second):
        assert agent.outcome == "finished", agent.reason
        assert said(agent, "Rti: going on with vehicles 1, 2")
        assert said(agent, "partner vehicle 3 did not reach its spot")


def test_one_vehicle_alone_without_radio_nodes_says_why_it_cannot(flat_scene):
    stepper = team(flat_scene, count=1)
    fly(stepper, 100)
    (agent,) = stepper.agents
    assert agent.outcome == "stopped"
    assert agent.reason == "rti needs a team of two or more, or fixed radio nodes"


def test_one_vehicle_with_fixed_radio_nodes_measures_its_links_to_them(flat_scene):
    stepper = team(flat_scene, count=1, rti_rounds=3)
    (agent,) = stepper.agents
    stepper.controllers[0].radio_nodes = [(2.0, 7.0), (12.0, 7.0)]  # west and east of the region
    fly(stepper, 300)
    assert agent.outcome == "finished", agent.reason
    assert agent.reason == "3 rounds measured, 6 links"
    assert said(agent, "with vehicles 1 and 2 fixed radio nodes")


def test_a_spot_its_map_blocks_is_moved_to_the_nearest_reachable_point_and_the_pair_measures_there(flat_scene):
    """The demo's team ended its mission at round 20 when one copter's map held an obstacle within 0.35 m of its
    spot ("no known path"), and its partner then lost it. Now it stops as near as it can, and both go on."""
    stepper = team(flat_scene)
    first, second = stepper.agents
    spots, dwelt = [], []

    def watch():
        mission = getattr(first, "mission", None)
        if getattr(mission, "rounds", None) == 0 and getattr(mission, "spots", None):
            spots.append(mission.spot)
            cell = first.map.cell_of(*mission.spot)  # an echo its map insists on, right at its first spot
            first.map.grid[cell[0] - 1:cell[0] + 2, cell[1] - 1:cell[1] + 2] = first.map.LIMIT
            first.map.occupied_version += 1
            if all(getattr(a.mission, "phase", None) is Phase.DWELL for a in stepper.agents):
                dwelt.append((first.fc.pose.x, first.fc.pose.y))

    fly(stepper, 400, watch=watch)
    assert [a.outcome for a in stepper.agents] == ["finished", "finished"], [a.reason for a in stepper.agents]
    assert first.reason == second.reason == "3 rounds measured, 3 links"
    (shifted,) = said(first, "cannot be reached")
    spot = spots[0]
    assert shifted.startswith(f"Rti: its spot ({spot[0]:.1f}, {spot[1]:.1f}) of round 1 cannot be reached (no known "
                              "path to") and shifted.endswith(" m off")
    point = tuple(float(v) for v in shifted.split("measuring from (")[1].split(")")[0].split(","))
    assert 0.2 < math.dist(point, spot) <= 1.0 + 0.05
    assert dwelt, "the pair never measured round 1"
    assert max(math.dist(p, point) for p in dwelt) < 0.5  # it measured from the point it said
    assert not said(second, "lost")


def test_a_partner_that_has_not_moved_this_round_is_not_taken_as_at_a_spot_a_metre_away(flat_scene):
    """Settled within 1.5 m of its spot counts only after moving this round: the spots of one round are often a
    metre from the last (neighbours on the ring), and a partner still there has not come."""
    from types import SimpleNamespace

    stepper = team(flat_scene)
    first = stepper.agents[0]
    while getattr(first.mission, "spots", None) is None:
        stepper.step()
    mission = first.mission
    other = next(k for k in mission.spots if k != mission.me)
    x, y = mission.spots[other]
    standing = SimpleNamespace(x=x + 1.0, y=y, vx=0.0, vy=0.0)
    mission.moved.discard(other)
    assert not mission._there(other, standing)
    mission.moved.add(other)
    assert mission._there(other, standing)
    assert not mission._there(other, SimpleNamespace(x=x + 1.6, y=y, vx=0.0, vy=0.0))  # beyond SHIFT + THERE
    assert not mission._there(other, SimpleNamespace(x=x, y=y, vx=0.5, vy=0.0))  # not settled
    mission.moved.discard(other)
    assert mission._there(other, SimpleNamespace(x=x + 0.4, y=y, vx=0.0, vy=0.0))  # at its spot: no need to move
