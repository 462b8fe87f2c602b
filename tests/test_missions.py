"""Missions and the agent that runs them (vehicle.missions, vehicle.agent), on small scenes and simulated time.

Scenes are a ground slab (top at z = 0) and a few 6 m tall boxes; the memory map is
20 m either side of home (``space_size=20``), so a run takes a fraction of a second.
The planning helpers of ``missions.base.Context`` are tested on hand-made maps.
"""

import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20.ardupilotmega import MAV_SEVERITY_WARNING

import vehicle.agent.missions as missions_package
from vehicle.agent.agent import Phase
from vehicle.agent.missions import MISSIONS, mission_class
from vehicle.agent.missions.base import Context, Mission, Status
from vehicle.agent.missions.square import square_corners
from vehicle.agent.monitor import Monitor
from vehicle.agent.settings import Settings
from vehicle.lab.experiment import Experiment, _fly, run_experiment
from vehicle.lab.stepper import simulate
from vehicle.mapping.memory_map import MemoryMap
from vehicle.mapping.planner import UNSEEN_EXTENT
from vehicle.protocol.mav import mavlink
from vehicle.protocol.modes import DISARMED
from vehicle.sim.onboard import SimController
from vehicle.sim.physics import Limits
from vehicle.sim.simulation import Simulation
from vehicle.world.scene import parse_scene

GROUND = (0, 0, -0.05, 80, 80, 0.1)
SMALL = {"space_size": 20, "time_limit": 200}


def wall(x, y, sx, sy):
    """A 6 m tall box of footprint sx x sy centred at (x, y)."""
    return (x, y, 2, sx, sy, 6)


def enclosure(cx, cy, side):
    """Four walls around (cx, cy), ``side`` metres apart, closed at the corners."""
    half = side / 2
    return [wall(cx, cy + half, side + 0.2, 0.2), wall(cx, cy - half, side + 0.2, 0.2),
            wall(cx + half, cy, 0.2, side), wall(cx - half, cy, 0.2, side)]


@pytest.fixture
def scene_of(make_scene, box):
    """A Scene of the ground and the given boxes (tuples for ``box``)."""
    return lambda *boxes: make_scene(*(box(*b) for b in (GROUND, *boxes)))


def box(x, y, z, sx, sy, sz):
    """The VRML text of a Box, as the ``box`` fixture gives it, for helpers that build a scene without fixtures."""
    return f"Transform {{ translation {x} {y} {z} children Shape {{ geometry Box {{ size {sx} {sy} {sz} }} }} }}\n"


def scene(*walls):
    """A Scene of the ground and the given boxes (tuples for ``box``), built without fixtures."""
    return parse_scene("#VRML V2.0 utf8\n" + box(0, 0, -0.05, 80, 80, 0.1) + "".join(box(*w) for w in walls))


class Track:
    """``on_step`` recorder: horizontal path length, farthest excursion, closest approach to points, yaw turned."""

    def __init__(self, points=()):
        self.points = list(points)
        self.closest = [math.inf] * len(self.points)
        self.horizontal = 0.0
        self.farthest = 0.0
        self.turned = 0.0
        self.world = self.agent = None
        self._last = None

    def __call__(self, stepper, readings):
        world = self.world = stepper.simulation
        self.agent = stepper.agent
        pose = world.pose
        if self._last is not None:
            self.horizontal += math.hypot(pose.x - self._last[0], pose.y - self._last[1])
            self.turned += abs((pose.yaw - self._last[2] + math.pi) % (2 * math.pi) - math.pi)
        self._last = (pose.x, pose.y, pose.yaw)
        self.farthest = max(self.farthest, math.hypot(pose.x - world.home[0], pose.y - world.home[1]))
        for i, (px, py) in enumerate(self.points):
            self.closest[i] = min(self.closest[i], math.hypot(pose.x - px, pose.y - py))


def fly(scene, mission, vehicle="copter", waypoints=None, track=None, **settings):
    """One mission in a hand-made scene, with the small test settings."""
    experiment = Experiment("test.wrl", mission, vehicle, settings=Settings(**{**SMALL, **settings}),
                            waypoints=waypoints)
    return run_experiment(experiment, scene=scene, on_step=track)


def home_distance(result):
    x, y, _ = result["final_position"]
    return math.hypot(x - result["start"][0], y - result["start"][1])


# ---- the registry -----------------------------------------------------------------------------
def test_registry_lists_every_mission_module_and_only_those():
    package = Path(missions_package.__file__).parent
    modules = {p.stem for p in package.glob("*.py")} - {"__init__", "base", "routines"}
    assert set(MISSIONS) == modules == {"square", "browse", "search", "pathfind", "rti"}
    assert list(MISSIONS) == sorted(MISSIONS)
    for name in MISSIONS:
        cls = mission_class(name.title())
        assert issubclass(cls, Mission) and cls.name == name
        assert cls.__module__ == f"vehicle.agent.missions.{name}"


def test_an_unknown_mission_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown mission 'hover'") as error:
        mission_class("hover")
    for name in ("square", "browse", "search", "pathfind"):
        assert name in str(error.value)


# ---- browse -----------------------------------------------------------------------------------
def test_browse_turns_a_full_circle_and_lands_disarmed_with_the_wall_detected(scene_of):
    track = Track()
    result = fly(scene_of(wall(0, 4, 8, 0.2)), "browse", track=track)
    assert result["outcome"] == "finished", result["reason"]
    assert track.turned >= 2 * math.pi - math.radians(5)
    assert track.farthest < 0.5  # it turned in place
    pilot = track.world.autopilot
    assert not pilot.armed and not pilot.flying and pilot.mode == "LAND"
    assert result["final_position"][2] < 0.5  # on the ground (body centre 0.35 m up)
    points = track.agent.map.occupied_points()
    assert result["detections"] == len(points) >= 10
    outside_x = np.maximum(np.abs(points[:, 0]) - 4.0, 0)
    outside_y = np.maximum(np.abs(points[:, 1] - 4.0) - 0.1, 0)
    assert np.hypot(outside_x, outside_y).max() < 0.75  # every detection is on (or just before) the wall


def test_browse_in_an_empty_scene_finishes_with_nothing_detected(scene_of):
    result = fly(scene_of(), "browse", vehicle="rover")
    assert result["outcome"] == "finished"
    assert result["detections"] == 0
    assert result["distance_m"] == 0


def test_browse_with_a_servo_sweeps_the_sonar_and_turns_the_vehicle_only_between_sweeps(scene_of):
    track = Track()
    experiment = Experiment("test.wrl", "browse", "copter", settings=Settings(**SMALL), sensors="servo")
    result = run_experiment(experiment, scene=scene_of(wall(0, 4, 8, 0.2)), on_step=track)
    assert result["outcome"] == "finished", result["reason"]
    assert result["detections"] >= 10
    assert math.radians(150) < track.turned < math.radians(200)  # two sweeps with about a half-turn between them
    assert track.world.servo.angle() == pytest.approx(0.0, abs=1.0)  # centred again


# ---- square -----------------------------------------------------------------------------------
@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_square_flies_its_corners_and_finishes_home(scene_of, vehicle):
    corners = square_corners((0.0, 0.0), SMALL["space_size"])
    track = Track(corners)
    result = fly(scene_of(), "square", vehicle=vehicle, track=track)
    assert result["outcome"] == "finished", result["reason"]
    assert max(track.closest) <= Settings().closeness  # every corner reached (waypoint radius = closeness)
    assert track.horizontal > 3 * 2 * abs(corners[0][0])  # at least three sides of the square
    assert home_distance(result) < 0.5
    if vehicle == "copter":
        assert not track.world.autopilot.armed


@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_square_with_a_wall_across_a_leg_stops_safely_and_gets_home(scene_of, vehicle):
    # corners at +-5 m: the east leg runs from (5, 5) to (5, -5); the wall crosses it at y = 0
    track = Track()
    result = fly(scene_of(wall(5, 0, 4, 0.2)), "square", vehicle=vehicle, track=track)
    assert result["outcome"] == "stopped", result["reason"]
    assert track.world.collision is None
    assert home_distance(result) < 0.5
    assert result["detections"] > 0


def test_bug1_square_without_avoidance_collides_on_the_way_home():
    # the monitor stops the square in front of a wall across its east leg; homing then plans a
    # straight line home that grazes the wall end (path_clear skips the margin) and, with the
    # autopilot's avoidance off, creeps into it scan after scan
    def no_avoidance(stepper, readings):
        stepper.simulation.autopilot.avoidance = None

    result = run_experiment(Experiment("x", "square", settings=Settings(space_size=20, time_limit=200)),
                            scene=scene((5, 0, 2, 4, 0.2, 6)), on_step=no_avoidance)
    assert result["outcome"] != "collision", result["reason"]


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


# ---- pathfind ---------------------------------------------------------------------------------
@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_pathfind_goes_around_a_wall_to_its_waypoint(scene_of, vehicle):
    goal = (0.0, 10.0)
    track = Track([goal])
    result = fly(scene_of(wall(0, 5, 10, 0.2)), "pathfind", vehicle=vehicle, waypoints=[goal], track=track)
    assert result["outcome"] == "finished", result["reason"]
    assert track.world.collision is None
    assert track.closest[0] <= Settings().closeness
    assert track.horizontal > 1.3 * 2 * math.dist((0, 0), goal)  # there and back, around the wall
    assert home_distance(result) < 0.5


def test_pathfind_skips_an_unreachable_waypoint_and_names_it(scene_of):
    waypoints = [(-5.0, 0.0), (8.0, 0.0)]  # the second lies inside a closed 4 m box
    track = Track(waypoints)
    result = fly(scene_of(*enclosure(8, 0, 4)), "pathfind", waypoints=waypoints, track=track)
    assert result["outcome"] == "stopped"
    assert "waypoints 2 unreachable" in result["reason"]
    assert track.closest[0] <= Settings().closeness
    assert track.world.collision is None
    assert home_distance(result) < 0.5
    assert any("skipping waypoint 2" in m for m in result["messages"])


def test_pathfind_flies_the_waypoints_it_is_given(scene_of):
    given = [(-4.0, 3.0), (4.0, 3.0)]
    default = square_corners((0.0, 0.0), SMALL["space_size"])
    track = Track([*given, *default])
    result = fly(scene_of(), "pathfind", vehicle="rover", waypoints=given, track=track)
    assert result["outcome"] == "finished", result["reason"]
    assert max(track.closest[:2]) <= Settings().closeness
    assert min(track.closest[2:]) > 1.0  # not the default square
    reached = [m for m in result["messages"] if "reached waypoint" in m]
    assert reached == ["Pathfind: reached waypoint 1", "Pathfind: reached waypoint 2"]


@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_a_waypoint_closer_than_the_autopilot_stops_is_reached_not_waited_for(scene_of, vehicle):
    """A waypoint 0.12 m from the start, ``closeness`` 0.1 m: the autopilot holds a target within 0.15 m as
    reached and does not move, and the vehicle at rest there has reached it. Before, it waited there until the
    time ran out (a thesis sweep's Search in the trees, ``closeness`` 0.1, hovered 121 s 0.12 m from its goal)."""
    result = fly(scene_of(), "pathfind", vehicle=vehicle, waypoints=[(0.12, 0.0), (3.0, 0.0)], closeness=0.1)
    assert result["outcome"] == "finished", result["reason"]
    assert [m for m in result["messages"] if "reached waypoint" in m] == [
        "Pathfind: reached waypoint 1", "Pathfind: reached waypoint 2"]
    assert result["sim_time_s"] < 60


def test_bug1_pathfind_livelocks_at_a_wall_end():
    # a 4 m wall between home and a waypoint 14 m north; closeness 1 m. Straightforward detour, yet
    # the copter stops/scans/replans at (2.2, 4.15) every ~9.5 s until its time budget runs out
    result = run_experiment(Experiment("x", "pathfind", settings=Settings(space_size=20, time_limit=300,
                                                                           closeness=1.0),
                                       waypoints=[(0.0, 14.0)]), scene=scene((0, 5, 2, 4, 0.2, 6)))
    assert result["outcome"] == "finished", result["reason"]
    assert result["sim_time_s"] < 120


# ---- search -----------------------------------------------------------------------------------
SEARCH_SCENE = [wall(0, 10, 6, 0.3), wall(10, 0, 0.3, 6), wall(-9, -6, 4, 4)]


def test_search_moves_away_detects_more_than_browse_and_gets_home(scene_of):
    scene = scene_of(*SEARCH_SCENE)
    browse = fly(scene, "browse", time_limit=150)
    track = Track()
    search = fly(scene, "search", track=track, time_limit=150)
    assert browse["outcome"] == "finished"
    assert search["outcome"] == "finished", search["reason"]
    assert track.farthest > 4.0
    assert search["detections"] > browse["detections"]
    assert track.world.collision is None
    assert home_distance(search) < 0.5


def test_a_rover_stopped_within_the_margin_of_an_echo_gets_home(castle_path):
    """In the castle (from (-40, 0), three sonars) Search ends with the rover stopped right beside something
    low, within the autopilot's avoidance margin of its echoes. Home lies the other way, yet avoidance held it
    back (an echo lay a hair ahead of its side) and the agent gave up "blocked", holding position."""
    result = run_experiment(Experiment(str(castle_path), "search", "rover", (-40.0, 0.0), None, Settings(),
                                       sensors="triple"))
    assert result["outcome"] == "finished", result["reason"]
    assert not [text for text in result["messages"] if text.startswith("Homing:")], result["messages"]
    assert math.dist(result["final_position"][:2], (-40.0, 0.0)) < 1.0, result["final_position"]


@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_a_vehicle_that_cannot_get_home_holds_where_it_is_and_warns(scene_of, vehicle):
    """When the way home gives up (blocked, no known path), the operator must bring the vehicle home: the agent
    holds it where it is and says so as a warning (it was mere information)."""
    flight = Flight(scene_of(), "pathfind", vehicle, waypoints=[(0.0, 8.0)])
    travel = None

    def on_the_way_home():
        nonlocal travel
        travel = flight.agent._travel if flight.agent.phase is Phase.HOMING else None
        return travel is not None and travel.path and flight.world.body.speed > 1.0

    assert flight.run(60.0, until=on_the_way_home)

    def give_up():
        travel.reason = "blocked at the test's say-so"
        return Status.STOPPED

    travel.step = give_up
    flight.run(1.0)
    stopped_at = flight.xy
    assert flight.agent.done and flight.agent.outcome == "stopped"
    assert "could not get home: blocked at the test's say-so" in flight.agent.reason
    flight.run(15.0)
    assert math.dist(flight.xy, stopped_at) < 1.0 and math.dist(flight.xy, (0.0, 0.0)) > 3.0, flight.xy
    assert flight.world.autopilot.mode == "GUIDED" and flight.world.autopilot.armed
    told = [(severity, text) for severity, text in flight.agent.outbox if text.startswith("Homing:")]
    assert told == [(MAV_SEVERITY_WARNING, "Homing: blocked at the test's say-so; holding position")]


def test_a_kill_in_flight_pauses_the_agent_once_saying_so(scene_of):
    """Disarmed in GUIDED by someone else (an operator's kill), the agent stops commanding and says why, once."""
    flight = Flight(scene_of(), "pathfind", waypoints=[(0.0, 8.0)])
    assert flight.run(30.0, until=lambda: flight.world.body.speed > 1.0)
    assert flight.world.autopilot.disarm(force=True) == 0
    flight.run(5.0)
    assert flight.agent.paused and flight.agent.pause_reason == DISARMED
    assert [text for text in flight.agent.messages if text.startswith("Agent: paused")] == [
        f"Agent: paused, {DISARMED}"]


def test_a_rover_disarmed_mid_mission_is_armed_again_by_resume_and_carries_on(scene_of):
    """Resumed after a disarm, the rover's agent sent its targets to a disarmed vehicle, was refused, and paused
    again at once. Resume now arms it (as it takes a landed copter up again) and the mission carries on where it
    was, not from its start."""
    flight = Flight(scene_of(), "pathfind", "rover", waypoints=[(0.0, 8.0), (8.0, 8.0)])
    assert flight.run(60.0, until=lambda: math.dist(flight.xy, (0.0, 8.0)) < 2.5)
    assert flight.world.autopilot.disarm() == 0
    flight.run(2.0)
    assert flight.agent.paused and flight.agent.pause_reason == DISARMED
    assert flight.agent.resume()
    assert flight.run(60.0, until=lambda: flight.agent.done), flight.agent.messages
    assert flight.agent.outcome == "finished", flight.agent.reason
    assert [text for text in flight.agent.messages if "pathfind: start" in text] == ["Mission pathfind: start"]
    assert [text for text in flight.agent.messages if text.startswith("Agent: paused")] == [
        f"Agent: paused, {DISARMED}"]


def test_an_auto_mission_landed_on_its_way_home_goes_home_when_resumed(scene_of):
    """Square (an AUTO mission) ended and its copter flew home in GUIDED; an operator landed it on the way. The
    resume took it up and flew the whole square again, as if the mission had just begun."""
    flight = Flight(scene_of(), "square")
    assert flight.run(200.0, until=lambda: flight.agent.phase is Phase.HOMING and flight.world.body.speed > 1.0)
    assert flight.world.autopilot.set_mode("LAND") == 0
    assert flight.run(30.0, until=lambda: not flight.world.autopilot.armed)
    assert flight.agent.paused and flight.agent.resume()
    assert flight.run(120.0, until=lambda: flight.agent.done), flight.agent.messages
    assert [text for text in flight.agent.messages if text.startswith("Mission square: finished")] == [
        "Mission square: finished (mission complete); going home"]
    assert flight.agent.outcome == "finished" and flight.world.autopilot.mode == "LAND"
    assert math.dist(flight.xy, flight.world.home[:2]) < 1.0, flight.xy


def test_a_pause_for_the_same_reason_is_said_once(scene_of):
    """Two targets the agent sent before it paused, both refused for one reason, paused it twice over MAVLink:
    the operator saw the same warning twice. A new reason is news."""
    agent = Flight(scene_of(), "browse").agent
    for reason in ("flight controller: do_reposition temporarily rejected",) * 2 + ("operator switched to RTL",):
        agent.pause(reason)
    assert [text for text in agent.messages if text.startswith("Agent: paused")] == [
        "Agent: paused, flight controller: do_reposition temporarily rejected",
        "Agent: paused, operator switched to RTL"]


def test_search_with_a_short_time_limit_heads_home_in_time(scene_of):
    result = fly(scene_of(*SEARCH_SCENE), "search", time_limit=80)
    assert result["outcome"] == "finished", result["reason"]
    assert "time" in result["reason"]
    assert result["sim_time_s"] < 80
    assert home_distance(result) < 0.5


# ---- operator takeover --------------------------------------------------------------------------
@pytest.mark.parametrize("vehicle", ["copter", "rover"])
def test_a_vehicle_that_leaves_its_space_flies_back_home(scene_of, vehicle):
    """Just past its space a vehicle stands off its own memory map, where it had "no known path" home: it held
    position out there for good. It now comes straight back onto the map and home."""
    result = fly(scene_of(), "square", vehicle, waypoints=[(30.0, 0.0)])
    assert (result["outcome"], result["reason"]) == ("stopped", "left the allowed space around home")
    assert home_distance(result) < 1.0


class Flight:
    """A simulated vehicle and its agent on the one stepper, for tests that intervene mid-flight."""

    def __init__(self, scene, mission, vehicle="copter", waypoints=None, **settings):
        self.stepper = simulate(scene, mission, vehicle, Settings(**{**SMALL, **settings}), waypoints=waypoints)
        self.world, self.agent = self.stepper.simulation, self.stepper.agent

    def run(self, seconds, until=None) -> bool:
        """Step up to ``seconds`` of simulated time; True as soon as ``until()`` holds after an agent step."""
        reached = self.stepper.run(seconds, until)
        assert self.world.collision is None, self.world.collision.describe()
        return reached

    @property
    def xy(self):
        return self.world.pose.x, self.world.pose.y


def test_a_mode_change_from_the_ground_station_pauses_the_agent(scene_of):
    flight = Flight(scene_of(), "pathfind", waypoints=[(0.0, 8.0), (8.0, 8.0)])
    assert flight.run(30, until=lambda: flight.xy[1] > 3.0)  # on its way north
    assert flight.world.autopilot.set_mode("BRAKE", source="gcs") == 0
    flight.run(3)  # brakes to a stop
    assert flight.agent.paused
    assert any("paused" in m for m in flight.agent.messages)
    stopped_at = flight.xy
    flight.run(20)
    assert math.dist(flight.xy, stopped_at) < 0.2  # the agent sends nothing while paused
    assert flight.world.autopilot.mode == "BRAKE"
    assert flight.agent.phase is Phase.MISSION and flight.agent.outcome is None


def test_a_new_go_here_drops_the_path_to_the_last_one_at_once(scene_of):
    """The page shows the agent's planned path: a second "Go here" must not show the way to the first one
    while the agent looks around before planning anew."""
    flight = Flight(scene_of(), "browse")
    assert flight.run(60, until=lambda: flight.agent.phase is Phase.MISSION)
    assert flight.agent.go_to((8.0, 8.0)) is None
    assert flight.run(10, until=lambda: flight.agent.ctx.planned_path[-1:] == [(8.0, 8.0)])
    assert flight.agent.go_to((-8.0, 0.0)) is None
    assert flight.agent.ctx.planned_path == []
    assert flight.run(30, until=lambda: flight.agent.ctx.planned_path[-1:] == [(-8.0, 0.0)])


def test_go_here_beside_a_cell_the_map_holds_goes_as_near_as_the_body_fits_from_the_vehicles_side(scene_of):
    """A far echo at a cone's edge can mark a cell in the open (the demo's rover had one 0.16 m from its
    operator's target): Go here no longer refuses a target the body does not fit at beside such a cell, but
    goes to the nearest spot on its side facing the vehicle where it fits, and says so."""
    flight = Flight(scene_of(), "browse")
    assert flight.run(60, until=lambda: flight.agent.phase is Phase.MISSION)
    memory, target = flight.agent.map, (6.0, 0.0)
    memory.grid[memory.cell_of(6.15, 0.05)] = memory.LIMIT  # west of the target is open ground: nothing there
    assert not flight.agent.ctx.is_clear(target, padding=0.0)
    assert flight.agent.go_to(target) is None
    said = flight.agent.messages[-1]
    assert said.startswith("Go here: the body does not fit at (6.0, 0.0) beside a known obstacle; on the way to ")
    assert flight.run(40, until=lambda: flight.agent.pause_reason.startswith("holding at"))
    assert 0.1 <= math.dist(flight.xy, target) <= 0.5 + 0.5  # as near as it fits, within the arrival tolerance
    assert flight.xy[0] < target[0]  # on the side it came from (the west: home), not past the cell


def test_go_here_behind_a_walls_face_is_refused_not_taken_round_it(scene_of):
    """Behind a wall's face the body fits further in, where the map knows nothing: no spot on the near side."""
    flight = Flight(scene_of(wall(0.0, 6.0, 8.0, 1.0)), "browse")
    assert flight.run(60, until=lambda: flight.agent.phase is Phase.MISSION)
    memory = flight.agent.map
    for x in np.arange(-2.0, 2.05, 0.1):  # the wall's south face, as the sonars would have drawn it
        memory.grid[memory.cell_of(x, 5.55)] = memory.LIMIT
    assert flight.agent.go_to((0.0, 5.8)) == "(0.0, 5.8) is inside a known obstacle"


def test_a_take_off_the_autopilot_refuses_pauses_the_agent_and_a_resume_asks_again(scene_of):
    """A copter bigger than the default rests higher, and its autopilot refuses a take-off to 0.5 m, which would
    not leave the ground. The agent waited for ever in silence; it now pauses, saying why, and asks again when
    resumed: once the operator has raised the altitude (as PARAM_SET SCN_ALTITUDE does), it takes off. Before it
    pauses it asks twice more, 2 s apart, saying so."""
    settings = Settings(**{**SMALL, "altitude": 0.5})
    stepper = simulate(scene_of(), "browse", "copter", settings, limits=Limits(radius=0.6))
    agent = stepper.agent
    assert stepper.run(10, until=lambda: agent.paused)
    assert agent.pause_reason == "flight controller: nav_takeoff failed"
    asked_again = "Preflight: flight controller: nav_takeoff failed; asking again in 2 s"
    assert list(agent.messages).count(asked_again) == 2 and 4.0 <= stepper.simulation.autopilot.time < 5.0
    assert "Agent: paused, flight controller: nav_takeoff failed" in agent.messages
    assert agent.resume()
    assert stepper.run(10, until=lambda: agent.paused)  # refused again: paused again, not waiting in silence
    assert list(agent.messages).count(asked_again) == 4
    agent.settings.altitude = 1.5
    assert agent.resume()
    assert stepper.run(10, until=lambda: agent.phase is Phase.MISSION)
    assert stepper.simulation.autopilot.flying and not agent.paused


def test_the_preflight_asks_as_often_again_after_an_operators_pause(scene_of):
    """A refusal counted before an operator paused the agent does not count after the resume: the operator's
    resume asks as often as the start did (three times, then it pauses, saying why)."""
    settings = Settings(**{**SMALL, "altitude": 0.5})  # a take-off its autopilot refuses (see above)
    stepper = simulate(scene_of(), "browse", "copter", settings, limits=Limits(radius=0.6))
    agent = stepper.agent
    asked_again = "Preflight: flight controller: nav_takeoff failed; asking again in 2 s"
    assert stepper.run(5, until=lambda: asked_again in agent.messages)
    assert agent.hold_for_operator(control=False) is None and agent.resume()
    assert stepper.run(10, until=lambda: agent.paused)
    assert agent.pause_reason == "flight controller: nav_takeoff failed"
    assert list(agent.messages).count(asked_again) == 3  # one before the pause, two after


def test_a_copter_the_autopilot_disarmed_before_its_take_off_is_armed_again_and_flies(scene_of):
    """Against two ArduCopter SITL instances on a loaded machine, an agent's take-off failed: the copter was not
    armed (ArduCopter disarms one left idle on the ground, and a loaded one's pre-arm checks flicker). One refusal
    paused the agent for good, and the mission never started. Now it arms and asks again, and flies."""
    stepper = simulate(scene_of(), "browse", "copter", Settings(**SMALL))
    autopilot, agent = stepper.simulation.autopilot, stepper.agent
    takeoff, refused = autopilot.takeoff, []

    def disarmed_first(altitude):
        if not refused:
            autopilot.disarm()
        refused.append(result := takeoff(altitude))
        return result
    autopilot.takeoff = disarmed_first
    assert stepper.run(20, until=lambda: agent.phase is Phase.MISSION)
    assert refused[0] != mavlink.MAV_RESULT_ACCEPTED and refused[-1] == mavlink.MAV_RESULT_ACCEPTED
    assert "Preflight: flight controller: nav_takeoff temporarily rejected; asking again in 2 s" in agent.messages
    assert autopilot.flying and not agent.paused


def test_resumed_after_an_operator_stopped_its_climb_the_agent_takes_over_in_guided(scene_of):
    """A BRAKE mid-climb paused the agent in its take-off; the resume left the mode as it was, and the mission
    began in BRAKE, every target of it refused."""
    flight = Flight(scene_of(), "browse")
    assert flight.run(10, until=lambda: flight.world.pose.z > 2.0 and flight.agent.phase is Phase.TAKEOFF)
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    assert flight.run(2, until=lambda: flight.agent.paused)
    assert flight.agent.resume()
    assert flight.run(10, until=lambda: flight.agent.phase is Phase.MISSION)
    flight.run(3)
    assert flight.world.autopilot.mode == "GUIDED" and not flight.agent.paused


def test_a_headless_run_that_times_out_paused_says_why_it_paused(scene_of):
    """Nobody resumes an agent in a headless run: its outcome names the pause, not only the phase."""
    settings = Settings(**{**SMALL, "altitude": 0.5, "time_limit": 20})
    stepper = simulate(scene_of(), "browse", "copter", settings, limits=Limits(radius=0.6))
    assert _fly(stepper, None) == ("timeout", "time limit of 20 s reached in phase preflight, the agent paused "
                                              "(flight controller: nav_takeoff failed)")


def test_resume_hands_control_back_to_the_agent(scene_of):
    flight = Flight(scene_of(), "pathfind", waypoints=[(0.0, 8.0)])
    assert not flight.agent.resume()  # not paused: nothing to resume
    assert flight.run(30, until=lambda: flight.xy[1] > 3.0)
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    flight.run(2)
    assert flight.agent.resume()
    assert not flight.agent.paused
    assert flight.world.autopilot.mode == "GUIDED"
    flight.run(1)
    assert not flight.agent.paused  # its own mode change does not count as the operator's


def _pause_and_resume(flight, stop_mode="BRAKE"):
    flight.run(30, until=lambda: flight.agent.phase.value == "mission")
    flight.run(3)
    flight.world.autopilot.set_mode(stop_mode, source="gcs")
    flight.run(5)
    assert flight.agent.paused
    assert flight.agent.resume()
    flight.run(120, until=lambda: flight.agent.done)


def test_bug2_resumed_pathfind_continues_to_its_waypoints():
    flight = Flight(scene((0, 6, 2, 8, 0.2, 6)), "pathfind", waypoints=[(0.0, 3.0), (5.0, 3.0)])
    _pause_and_resume(flight)
    assert flight.agent.done and flight.agent.outcome == "finished", (flight.agent.outcome, flight.agent.reason)


def test_bug2_resumed_browse_finishes_its_turn():
    flight = Flight(scene((0, 6, 2, 8, 0.2, 6)), "browse")
    _pause_and_resume(flight)
    assert flight.agent.done and flight.agent.outcome == "finished", (flight.agent.outcome, flight.agent.reason)


def test_time_the_operator_held_the_vehicle_does_not_count_against_the_missions_time_limit(scene_of):
    """Held in BRAKE for longer than the whole time limit, then resumed: the mission flies on from where it
    was, with the time it had left (it gave up at once, "time used", and went home)."""
    flight = Flight(scene_of(), "pathfind", waypoints=[(15.0, 15.0), (-15.0, 15.0), (-15.0, -15.0)], time_limit=120)
    assert flight.run(60, until=lambda: flight.agent.phase is Phase.MISSION)
    flight.run(3)
    left = flight.agent.ctx.time_left
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    flight.run(300)  # paused all along
    assert flight.agent.paused
    assert flight.agent.resume()
    assert flight.agent.ctx.time_left == pytest.approx(left, abs=0.5)
    flight.run(10)
    assert flight.agent.phase is Phase.MISSION and not flight.agent.paused
    assert flight.agent.ctx.time_left == pytest.approx(left - 10, abs=0.5)


def test_an_auto_mission_resumes_when_the_operator_switches_back_to_auto_and_starts_it(scene_of):
    flight = Flight(scene_of(), "square")
    assert flight.run(30, until=lambda: flight.xy[1] > 2.0)  # on the first leg, to the north-west corner
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    flight.run(3)
    assert flight.agent.paused
    held = flight.xy
    flight.run(5)
    assert math.dist(flight.xy, held) < 0.2
    assert flight.world.autopilot.set_mode("AUTO", source="gcs") == 0
    flight.run(1)
    assert flight.world.autopilot.start_mission() == 0  # MISSION_START
    assert flight.agent.resume()
    assert flight.run(120, until=lambda: flight.agent.done)
    assert flight.agent.outcome == "finished", flight.agent.reason
    assert math.dist(flight.xy, (0.0, 0.0)) < 0.5


def test_bug2_auto_and_mission_start_within_one_monitor_period_pause_the_agent_again():
    # The endpoint's AUTO (set_mode source "gcs") + MISSION_START (agent.resume()) arriving in the same
    # 0.25 s monitor period: resume() does not take the operator's AUTO as seen (_mode_changes), so the
    # next Agent.step() treats it as a new takeover and pauses again ("paused, operator switched to AUTO").
    # The square then flies on unmonitored and the agent never finishes.
    flight = Flight(scene((0, 6, 2, 8, 0.2, 6)), "square")
    flight.run(8)
    flight.world.autopilot.set_mode("BRAKE", source="gcs")
    flight.run(3)
    assert flight.agent.paused
    flight.world.autopilot.set_mode("AUTO", source="gcs")
    flight.world.autopilot.start_mission()
    assert flight.agent.resume()
    flight.run(1)
    assert not flight.agent.paused, flight.agent.messages[-2:]


# ---- planning through the Context -------------------------------------------------------------
class Planner:
    """A Context on a hand-made memory map (20 m either side of the origin, 10 cells/m)."""

    def __init__(self, scene, position=(0.0, 0.0)):
        self.settings = Settings(space_size=20)
        self.world = Simulation(scene, "copter")
        self.map = MemoryMap((0.0, 0.0), 20, 10)
        monitor = Monitor(self.settings, self.map, (0.0, 0.0), self.world.limits.radius)
        self.ctx = Context(SimController(self.world), self.map, monitor, self.settings, say=lambda text: None)
        self.move(*position)

    def move(self, x, y):
        self.world.body.pose.x, self.world.body.pose.y = x, y

    def mark(self, x0, x1, y0, y1, value=MemoryMap.LIMIT):
        """Set every cell of the rectangle (scene metres) to ``value`` (default: surely occupied)."""
        (r0, c0), (r1, c1) = self.map.cell_of(x0, y0), self.map.cell_of(x1, y1)
        self.map.grid[r0:r1 + 1, c0:c1 + 1] = value

    def clearance(self, path):
        """Least distance from the polyline (current position, then ``path``) to an occupied cell centre."""
        chain = np.array([self.ctx.position, *path], dtype=float)
        occupied = self.map.occupied_points()
        least = math.inf
        for a, b in zip(chain[:-1], chain[1:], strict=True):
            samples = a + np.linspace(0, 1, max(2, int(math.dist(a, b) * 20)))[:, None] * (b - a)
            d = np.hypot(*(samples[:, None, :] - occupied[None, :, :]).transpose(2, 0, 1))
            least = min(least, float(d.min()))
        return least


def crossing_x(path, start, y):
    """x where the polyline from ``start`` through ``path`` first crosses the line at height y."""
    chain = [start, *path]
    for (ax, ay), (bx, by) in zip(chain[:-1], chain[1:], strict=True):
        if (ay - y) * (by - y) <= 0 and ay != by:
            return ax + (bx - ax) * (y - ay) / (by - ay)
    return None


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


def test_a_star_plans_around_a_wall(flat_scene):
    planner = Planner(flat_scene)
    planner.mark(-2, 2, 4.9, 5.1)
    path, _ = planner.ctx.plan((0.0, 10.0))
    assert path is not None and len(path) >= 2
    assert path[-1] == (0.0, 10.0)
    assert planner.clearance(path) >= planner.world.limits.radius + planner.settings.padding - 0.1
    assert planner.ctx.path_clear(path, horizon=math.inf)
    assert not planner.ctx.path_clear([(0.0, 10.0)], horizon=math.inf)  # the straight line is not


def test_a_star_finds_no_path_to_an_enclosed_goal(flat_scene):
    planner = Planner(flat_scene)
    planner.mark(4, 8, -2, 2)  # a solid block, hollowed out below
    planner.mark(4.5, 7.5, -1.5, 1.5, MemoryMap.FREE_AT)
    path, _ = planner.ctx.plan((6.0, 0.0))
    assert path is None
    assert planner.ctx.is_clear((6.0, 0.0))  # the goal itself is open; there is just no way in


def test_a_star_from_right_next_to_a_wall_plans_away_from_it(flat_scene):
    planner = Planner(flat_scene, position=(0.0, 4.45))  # 0.45 m from the wall face: inside the clearance
    planner.mark(-19, 19, -19, 4.8, MemoryMap.FREE_AT)  # flying up to it, the sonar saw the way free
    planner.mark(-5, 5, 4.9, 5.1)
    assert not planner.ctx.is_clear(planner.ctx.position)
    path, _ = planner.ctx.plan((0.0, -5.0))
    assert path is not None and path[-1] == (0.0, -5.0)
    assert planner.clearance(path) >= planner.world.limits.radius


def test_bug1_path_clear_says_a_line_through_a_known_wall_is_clear_when_starting_within_the_margin():
    # vehicle 0.6 m in front of the wall (inside radius + padding = 0.8 m), goal straight behind it
    ctx = context_near_wall((0.0, 4.3))
    assert not ctx.path_clear([(0.0, 14.0)], horizon=math.inf, padding=0.5)


def test_bug1_plan_from_next_to_a_wall_goes_straight_through_it():
    ctx = context_near_wall((0.0, 4.4))
    path, _ = ctx.plan((-8.0, 8.0))
    assert path is not None
    assert not crosses_wall([ctx.position, *path]), path


def test_a_star_presumes_the_unseen_continuation_of_a_wall(flat_scene):
    seen = Planner(flat_scene)
    seen.mark(-2, 2, 4.9, 5.1)  # the face the sonar saw; what lies beyond its ends is unknown
    path, _ = seen.ctx.plan((0.0, 10.0))
    keep = 2.0 + UNSEEN_EXTENT + seen.world.limits.radius + seen.settings.padding
    assert abs(crossing_x(path, seen.ctx.position, 5.0)) >= keep - 0.25

    known = Planner(flat_scene)
    known.mark(-8, 8, -2, 12, MemoryMap.FREE_AT)  # the same wall with free space seen all around it
    known.mark(-2, 2, 4.9, 5.1)
    path, _ = known.ctx.plan((0.0, 10.0))
    assert abs(crossing_x(path, known.ctx.position, 5.0)) < keep - 0.25  # now it may pass closer


def test_a_copter_comes_to_rest_over_home_before_it_lands(scene_of):
    """LAND descends where it begins (the autopilot comes back there): begun at speed on arrival, it landed
    0.3 m off a home 0.4 m from a bed in the house, onto the bed's edge."""
    flight = Flight(scene_of(), "pathfind", waypoints=[(0.0, 8.0)])
    assert flight.run(120, until=lambda: flight.agent.phase is Phase.LANDING)
    assert flight.world.autopilot.mode == "LAND"
    assert flight.world.body.speed <= 0.1, flight.world.body.speed
    flight.run(60, until=lambda: not flight.world.autopilot.armed)
    assert not flight.world.autopilot.armed
    assert math.dist(flight.xy, flight.world.home[:2]) < 0.15, (flight.xy, flight.world.home)


def test_a_copter_at_rest_off_home_flies_over_it_before_it_lands(scene_of, monkeypatch):
    """LAND descends where it begins. A copter whose way home ended at rest off home (it had given way to a
    team-mate there, within the way home's 0.5 m) landed where it rested: 0.3 m from home, on a bed's edge,
    in a team run in the house. It now flies over home first. Here the way home ends about 5 m out (its reach
    widened to 8 m), after a Pathfind to 6 m east of home."""
    from vehicle.agent import agent as agent_module

    monkeypatch.setattr(agent_module, "HOME_TOLERANCE", 8.0)
    stepper = simulate(scene_of(), "pathfind", "copter", Settings(**SMALL), waypoints=[(6.0, 0.0)])
    autopilot = stepper.simulation.autopilot
    assert stepper.run(120, until=lambda: stepper.agent.done)
    assert stepper.agent.outcome == "finished" and not autopilot.armed
    home = stepper.simulation.home
    assert math.dist(stepper.simulation.pose.xyz()[:2], home[:2]) < agent_module.OVER_HOME
