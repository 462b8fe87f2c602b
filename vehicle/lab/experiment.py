"""One headless mission on simulated time: scene + vehicle + agent (or a team of them), stepped until an outcome.

The result is a plain dict (the JSON that ``vehicle experiment --json`` prints);
everything in it but ``wall_time_s`` is a function of the arguments and seed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vehicle import __version__
from vehicle.agent.settings import Settings
from vehicle.ctrl_c import reraise_ctrl_c
from vehicle.lab.stepper import Stepper, TeamStepper, simulate
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.rangefinder import Reading
from vehicle.protocol.waypoints import parse_points
from vehicle.world.scene import Scene, load_scene
from vehicle.world.suites import DEFAULT_SUITE, sensor_suite

OUTCOMES = ("finished", "stopped", "collision", "timeout", "error")
TRAIL_SPACING = 0.3  # m between the points of the trail drawn on the map's picture


@dataclass
class Experiment:
    """Everything that defines a run (and nothing that does not)."""

    scene: str
    mission: str
    vehicle: str = "copter"
    start: tuple[float, ...] | None = None
    heading: float | None = None
    settings: Settings = field(default_factory=Settings)
    seed: int = 0
    waypoints: list[tuple[float, float]] | None = None
    sensors: str = DEFAULT_SUITE
    datum: Datum | None = None  # None: the scene's datum hint, else the default (it places only the --log)


def run_experiment(experiment: Experiment, scene: Scene | None = None, map_out: str | Path | None = None,
                   on_step: Callable[[Stepper, list[Reading]], None] | None = None) -> dict:
    """Run the mission to its outcome; ``on_step(stepper, readings)`` is called after every step."""
    started = time.perf_counter()
    settings = experiment.settings
    result = {
        "mission": experiment.mission,
        "scene": Path(experiment.scene).name,
        "vehicle": experiment.vehicle,
        "sensors": experiment.sensors,
        "seed": experiment.seed,
        "version": __version__,
        "settings": settings.model_dump(),
        "resolution": settings.resolution,
    }
    stepper = None
    trail = _Trail(on_step) if map_out else None  # for the map's picture
    try:
        scene = scene or load_scene(experiment.scene)
        waypoints = experiment.waypoints
        if waypoints is None and "waypoints" in scene.hints:
            waypoints = parse_points(scene.hints["waypoints"])
        stepper = simulate(scene, experiment.mission, experiment.vehicle, settings, experiment.start,
                           experiment.heading, waypoints, seed=experiment.seed,
                           sensors=sensor_suite(experiment.sensors, experiment.vehicle),
                           datum=Datum.of_scene(scene.hints, experiment.datum))
        outcome, reason = _fly(stepper, trail or on_step)
    except Exception as error:  # noqa: BLE001 - any failure is an outcome of the run, reported, not raised
        reraise_ctrl_c(error)
        outcome, reason = "error", f"{type(error).__name__}: {error}"
    result.update(outcome=outcome, reason=reason)
    agent = stepper.agent if stepper is not None else None
    if stepper is not None:
        world = stepper.simulation
        pose = world.pose
        result.update(start=[round(world.home[0], 3), round(world.home[1], 3)],
                      sim_time_s=round(world.time, 3), distance_m=round(world.distance_travelled, 2),
                      final_position=[round(float(v), 2) for v in pose.xyz()])
    if agent is not None:
        result.update(detections=agent.map.detections, cells_ever_hit=agent.map.cells_ever_hit,
                      messages=list(agent.messages)[-20:])
        if map_out:
            out = Path(map_out)
            out.mkdir(parents=True, exist_ok=True)
            stem = f"{Path(experiment.scene).stem}-{experiment.mission}-{experiment.seed}"
            agent.map.save_npy(out / f"{stem}.npy")
            agent.map.save_png(out / f"{stem}.png", title=map_title(result, settings), home=world.home[:2],
                               trail=trail.points, planned_path=agent.ctx.planned_path, waypoints=_waypoints(agent),
                               position=(pose.x, pose.y))
    result.setdefault("detections", 0)
    result.setdefault("cells_ever_hit", 0)
    result["wall_time_s"] = round(time.perf_counter() - started, 3)
    return result


class _Trail:
    """Notes where the vehicle went (a point every TRAIL_SPACING metres), then calls ``on_step`` if any."""

    def __init__(self, on_step: Callable[[Stepper, list[Reading]], None] | None):
        self.on_step = on_step
        self.points: list[tuple[float, float]] = []

    def __call__(self, stepper: Stepper, readings: list[Reading]) -> None:
        pose = stepper.simulation.pose
        if not self.points or math.dist(self.points[-1], (pose.x, pose.y)) >= TRAIL_SPACING:
            self.points.append((pose.x, pose.y))
        if self.on_step is not None:
            self.on_step(stepper, readings)


def _waypoints(agent) -> list[tuple[float, float]]:
    """The points the agent's mission flies to: Pathfind's waypoints, Square's corners (none for the others)."""
    mission = agent.mission
    return list(getattr(mission, "waypoints", None) or getattr(mission, "corners", None) or ())


def map_title(result: dict, settings: Settings) -> str:
    """Two lines saying which run a map's picture is of: mission, vehicle, scene, outcome; then the figures
    and the settings that differ from the defaults."""
    changed = {k: v for k, v in settings.model_dump().items()
               if v != Settings.model_fields[k].default and k != "resolution"}
    tuned = "".join(f", {name} {value:g}" for name, value in changed.items())
    return (f"{result['mission']} mission, {result['vehicle']} in {result['scene']}: {result['outcome']}\n"
            f"{result.get('detections', 0)} occupied cells, {result.get('sim_time_s', 0):.0f} s simulated, "
            f"{result.get('distance_m', 0):.0f} m travelled, seed {result['seed']}, "
            f"{settings.resolution:g} cells/m{tuned}")


def _fly(stepper: Stepper, on_step) -> tuple[str, str]:
    simulation, agent = stepper.simulation, stepper.agent
    limit = stepper.settings.time_limit
    while True:
        readings = stepper.step()
        if simulation.collision is not None:
            return "collision", simulation.collision.describe()
        if on_step is not None:
            on_step(stepper, readings)
        if stepper.monitor_due and agent.done:
            return agent.outcome, agent.reason
        if simulation.time >= limit:
            paused = f", the agent paused ({agent.pause_reason})" if agent.paused else ""
            return "timeout", f"time limit of {limit:g} s reached in phase {agent.phase.value}{paused}"


WARM_UP_SCENE = """#VRML V2.0 utf8
WorldInfo { info ["space_size=12" "waypoints=0,9"] }
Transform { translation 0 0 -0.05 children Shape { geometry Box { size 30 30 0.1 } } }
Transform { translation 0 4.5 2 children Shape { geometry Box { size 5 0.3 4 } } }
"""


_warmed_up = False


def warm_up() -> float:
    """Fly a short Pathfind around a wall in a small built-in scene, once per process; returns the wall
    seconds it took (0 after the first call).

    The simulation's compiled loops are compiled on their first call after an install (a few
    seconds) and loaded from the disk cache after that (a quarter of a second). A live vehicle
    does this before its clock starts and its link opens, since a vehicle that froze for that
    long mid-flight would look lost to its ground station (and, compiling, it holds every other
    thread of its process); a benchmark does it so that its timings leave it out.
    """
    global _warmed_up
    if _warmed_up:
        return 0.0
    _warmed_up = True
    from vehicle.world.scene import parse_scene

    started = time.perf_counter()
    scene = parse_scene(WARM_UP_SCENE, "warm-up.wrl")
    settings = Settings().updated({"space_size": 12, "time_limit": 40})
    run_experiment(Experiment("warm-up.wrl", "pathfind", settings=settings, waypoints=[(0.0, 9.0)]), scene=scene)
    _warm_up_the_rest()
    return time.perf_counter() - started


def _warm_up_the_rest() -> None:
    """The loops a lone flight clear of walls does not reach: the swept body's exact check within a step of a
    wall, a team's look along a team-mate's track, and a team's map share."""
    import numpy as np

    from vehicle.agent.traffic import _meet
    from vehicle.mapping.sharing import _take
    from vehicle.world.collision import point_triangle_distance

    point_triangle_distance(np.zeros(3), np.eye(3)[None])
    _meet(0.0, 0.0, 1.0, 0.0, math.inf, 5.0, 0.0, -1.0, 0.0, 0.0, 1.0)
    grid = np.zeros((2, 2), dtype=np.int8)
    _take(grid, np.zeros((2, 2), dtype=bool), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64),
          np.full(1, 9, dtype=np.int8), -3, 6)


def run_team(experiment: Experiment, stepper: TeamStepper,
             on_step: Callable[[TeamStepper], None] | None = None) -> dict:
    """Fly a team (``simulate_team``, made and checked by the caller before anything starts) to its outcome:
    every vehicle done or wrecked, or the time limit. A vehicle that crashes is reported as such and the rest
    fly on. The result has what a lone run reports, per vehicle, and the team's figures. ``on_step(stepper)``
    after every step (the radios of a tomography run, ``vehicle.lab.tomograph``); True from it ends the run
    there (what has not ended reports ``timeout``)."""
    started = time.perf_counter()
    settings = experiment.settings
    team = stepper.team
    result = {"mission": experiment.mission, "scene": Path(experiment.scene).name, "vehicle": experiment.vehicle,
              "sensors": experiment.sensors, "seed": experiment.seed, "version": __version__,
              "settings": settings.model_dump(), "resolution": settings.resolution, "team": len(team),
              "share_maps": stepper.share_maps}
    limit = settings.time_limit
    try:
        while team.time < limit:
            stepper.step()
            if on_step is not None and on_step(stepper):
                break  # the caller has what it wanted (a benchmark: the mission's end)
            if stepper.monitor_due and all(agent.done or sim.collision is not None
                                           for agent, sim in zip(stepper.agents, team.simulations, strict=True)):
                break
        error = None
    except Exception as failure:  # noqa: BLE001 - a failure is an outcome of the run, reported, not raised
        reraise_ctrl_c(failure)
        error = f"{type(failure).__name__}: {failure}"
    vehicles = [_vehicle_result(stepper, index, limit, error) for index in range(len(team))]
    outcomes = [v["outcome"] for v in vehicles]
    overall = next((o for o in ("error", "collision", "timeout", "stopped") if o in outcomes), "finished")
    reasons = [f"vehicle {v['sysid']}: {v['reason']}" for v in vehicles if v["outcome"] == overall]
    result.update(outcome=overall, reason="; ".join(reasons), vehicles=vehicles,
                  sim_time_s=round(team.time, 3), distance_m=round(sum(v["distance_m"] for v in vehicles), 2),
                  detections=_team_detections(stepper), cells_ever_hit=sum(v["cells_ever_hit"] for v in vehicles),
                  closest_vehicles_m=None if len(team) < 2 else round(team.closest_gap, 3),
                  closest_pair=list(team.closest_pair) if team.closest_pair else None,
                  cells_shared=stepper.cells_shared)
    result["wall_time_s"] = round(time.perf_counter() - started, 3)
    return result


def _vehicle_result(stepper: TeamStepper, index: int, limit: float, error: str | None) -> dict:
    """What a lone run reports, for one vehicle of a team, and its closest approach to the scene's walls."""
    sim, agent = stepper.team.simulations[index], stepper.agents[index]
    if error is not None:
        outcome, reason = "error", error
    elif sim.collision is not None:
        outcome, reason = "collision", sim.collision.describe()
    elif agent.done:
        outcome, reason = agent.outcome, agent.reason
    else:
        outcome, reason = "timeout", f"time limit of {limit:g} s reached in phase {agent.phase.value}"
    gap = stepper.team.scene_gaps[index].gap
    return {"sysid": stepper.team.ids[index], "outcome": outcome, "reason": reason,
            "start": [round(sim.home[0], 3), round(sim.home[1], 3)], "distance_m": round(sim.distance_travelled, 2),
            "final_position": [round(float(v), 2) for v in sim.pose.xyz()],
            "detections": agent.map.detections, "cells_ever_hit": agent.map.cells_ever_hit,
            "closest_scene_m": None if gap is None else round(gap, 3), "gave_way": agent.give_way.times,
            "messages": list(agent.messages)[-20:]}


def _team_detections(stepper: TeamStepper) -> int:
    """Occupied cells of the team's maps together (a cell found by two counts once), in scene cells."""
    cells = set()
    for agent in stepper.agents:
        m = agent.map
        rows, cols = map(list, m.occupied.nonzero())
        cells.update((round(m.origin[0] * m.resolution) + c, round(m.origin[1] * m.resolution) + r)
                     for r, c in zip(rows, cols, strict=True))
    return len(cells)
