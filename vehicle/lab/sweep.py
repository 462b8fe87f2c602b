"""Parameter sweeps: the cartesian product of settings over missions, scenes and seeds, run in parallel.

Every run is an independent ``run_experiment`` call, so the same job list runs
on local worker processes or on a Dask cluster unchanged. The results go to a
CSV of all runs, a Markdown table of the best run per mission and scene (the
form of the thesis's Table 1), and pictures of those best maps (the best runs
are flown again to draw them: runs are deterministic, so they are the same).
"""

from __future__ import annotations

import csv
import functools
import itertools
import math
import os
from collections.abc import Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from vehicle.agent.settings import Settings, SettingsError, load_settings
from vehicle.lab.experiment import Experiment, run_experiment
from vehicle.lab.presets import THESIS_TABLE
from vehicle.sim.simulation import FARTHEST_START
from vehicle.world.scene import Scene, load_scene


@dataclass(frozen=True)
class Job:
    scene: str  # "PATH" or "PATH@X,Y" (a start)
    mission: str
    settings: tuple[tuple[str, float], ...]  # the swept values (on top of the scene's suggestions)
    seed: int = 0
    vehicle: str = "copter"
    vehicles: int = 1  # a team of this many, in one world
    targets: str = ""  # radio tomography's targets, X,Y[;X,Y...] ("": none)

    @property
    def scene_path(self) -> str:
        return self.scene.split("@")[0]

    @property
    def start(self) -> tuple[float, float] | None:
        if "@" not in self.scene:
            return None
        return scene_start(self.scene)


@dataclass
class SweepSpec:
    missions: list[str]
    scenes: list[str]
    grid: dict[str, list[float]] = field(default_factory=dict)
    seeds: int = 1
    vehicle: str = "copter"
    teams: list[int] = field(default_factory=lambda: [1])  # team sizes
    targets: list[str] = field(default_factory=lambda: [""])  # tomography targets, one X,Y[;X,Y] per value

    def __post_init__(self):
        """Every run's inputs checked before any run starts, so a typo is not found in a worker, minutes in."""
        for text in self.targets:
            if text:
                from vehicle.world.radio import parse_targets

                parse_targets(text)
        for scene in self.scenes:
            if "@" in scene:
                scene_start(scene)
        names = list(self.grid)
        for values in itertools.product(*(self.grid[n] for n in names)):
            try:
                Settings().updated(dict(zip(names, values, strict=True)))
            except SettingsError as error:
                raise SettingsError(f"--grid: {error}") from None

    def jobs(self) -> list[Job]:
        names = list(self.grid)
        combos = list(itertools.product(*(self.grid[n] for n in names))) or [()]
        return [Job(scene, mission, tuple(zip(names, values, strict=True)), seed, self.vehicle, team, targets)
                for scene in self.scenes for mission in self.missions for values in combos
                for team in self.teams for targets in self.targets for seed in range(self.seeds)]


def scene_start(spec: str) -> tuple[float, float]:
    """The start of a ``PATH@X,Y`` scene spec."""
    try:
        x, y = (float(v) for v in spec.split("@", 1)[1].split(","))
    except ValueError:
        x = y = math.nan
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"--scene wants FILE or FILE@X,Y with X and Y in scene metres, not {spec!r}")
    if max(abs(x), abs(y)) > FARTHEST_START:
        raise ValueError(f"--scene {spec!r}: the start lies more than {FARTHEST_START / 1000:g} km from the "
                         "scene's origin")
    return x, y


def parse_grid(items: Iterable[str]) -> dict[str, list[float]]:
    """``name=v1,v2,...`` strings -> {name: [values]}; names must be settings."""
    grid: dict[str, list[float]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or name not in Settings.model_fields:
            raise ValueError(f"--grid wants SETTING=V1,V2,... with a known setting, not {item!r}")
        try:
            grid[name] = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            grid[name] = []
        if not grid[name]:
            raise ValueError(f"--grid wants SETTING=V1,V2,... with numbers, not {item!r}")
    return grid


@functools.lru_cache(maxsize=8)
def _scene(path: str) -> Scene:
    return load_scene(path)


def run_job(job: Job, map_out: str | None = None) -> dict:
    """One run of a sweep (a top-level function, so worker processes and Dask can call it)."""
    scene = _scene(job.scene_path)
    settings = load_settings(scene_hints=scene.hints).updated(dict(job.settings))
    experiment = Experiment(job.scene_path, job.mission, job.vehicle, job.start, None, settings, job.seed)
    if job.vehicles > 1 or job.targets or job.mission == "rti":
        from vehicle.lab.tomograph import run_team_experiment

        targets = []
        if job.targets:
            from vehicle.world.radio import parse_targets

            targets = parse_targets(job.targets)
        starts = [job.start] if job.start and job.vehicles == 1 else None
        result = run_team_experiment(experiment, scene, job.vehicles, targets, starts)
    else:
        result = run_experiment(experiment, scene=scene, map_out=map_out)
    result["scene_spec"] = job.scene
    result["targets_spec"] = job.targets
    result["swept"] = dict(job.settings)
    return result


def run_local(jobs: list[Job], workers: int | None = None) -> Iterator[dict]:
    """Results as they finish, on local worker processes."""
    workers = workers or os.cpu_count() or 1
    if workers == 1:
        yield from map(run_job, jobs)
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        yield from pool.map(run_job, jobs, chunksize=1)


def run_dask(jobs: list[Job], address) -> Iterator[dict]:
    """Results as they finish, on a Dask cluster (an address like tcp://host:8786, or a Cluster object)."""
    from dask.distributed import Client, as_completed

    with Client(address) as client:
        futures = client.map(run_job, jobs, pure=False)
        for future in as_completed(futures):
            yield future.result()


def run_sweep(spec: SweepSpec, out: str | Path, workers: int | None = None, dask=None,
              progress: bool = True) -> list[dict]:
    """Run every job, write results.csv, best.md and the best maps into ``out``; returns the results."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = spec.jobs()
    runner = run_dask(jobs, dask) if dask is not None else run_local(jobs, workers)
    results = list(tqdm(runner, total=len(jobs), desc="sweep", unit="run", disable=not progress))
    order = {job: index for index, job in enumerate(jobs)}  # results in the order of the spec
    results.sort(key=lambda r: order[job_of(r)])
    write_csv(results, out / "results.csv")
    best = best_runs(results)
    (out / "best.md").write_text(markdown_table(best), encoding="utf-8")
    maps = out / "maps"
    for result in best.values():
        job = job_of(result)
        if job.vehicles == 1 and job.mission != "rti":  # a team's run draws no map
            run_job(job, map_out=str(maps))
    return results


def job_of(result: dict) -> Job:
    """The job a result came from."""
    return Job(result["scene_spec"], result["mission"], tuple(result["swept"].items()), result["seed"],
               result["vehicle"], result.get("team", 1), result.get("targets_spec", ""))


FIELDS = ["mission", "scene", "vehicle", "team", "targets_spec", "seed", "version", "outcome", "reason", "detections",
          "cells_ever_hit", "sim_time_s", "wall_time_s", "distance_m"]
RTI_FIELDS = ["found", "found_s", "links_heard", "links_imaged"]  # of a tomography run (vehicle.lab.tomograph)


def write_csv(results: list[dict], path: Path) -> None:
    setting_names = list(Settings.model_fields)
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["scene_spec", *FIELDS, *(f"rti_{f}" for f in RTI_FIELDS), *setting_names])
        for r in results:
            rti = r.get("rti") or {}
            writer.writerow([r["scene_spec"], *(r.get(f, "") for f in FIELDS), *(rti.get(f, "") for f in RTI_FIELDS),
                             *(r.get("settings", {}).get(n, "") for n in setting_names)])


def scene_name(result: dict) -> str:
    return Path(result["scene"]).stem


def best_runs(results: list[dict]) -> dict[tuple[str, str], dict]:
    """The run with the most detections per (mission, scene): safe endings (finished, stopped) rank first,
    then timeouts, then collisions and errors."""
    def rank(r: dict) -> tuple[int, int]:
        return ({"finished": 2, "stopped": 2, "timeout": 1}.get(r["outcome"], 0), r["detections"])

    best: dict[tuple[str, str], dict] = {}
    for r in results:
        key = (r["mission"], scene_name(r))
        if key not in best or rank(r) > rank(best[key]):
            best[key] = r
    return best


def markdown_table(best: dict[tuple[str, str], dict]) -> str:
    """Best detections per mission and scene, with outcome and time, beside the thesis's figures."""
    missions = list(dict.fromkeys(m for m, _ in best))
    scenes = list(dict.fromkeys(s for _, s in best))
    lines = ["| mission | " + " | ".join(scenes) + " |", "|---|" + "---|" * len(scenes)]
    for mission in missions:
        cells = []
        for scene in scenes:
            r = best.get((mission, scene))
            if r is None:
                cells.append("-")
                continue
            thesis = THESIS_TABLE.get(mission, {}).get(scene)
            note = "" if r["outcome"] == "finished" else f" ({r['outcome']})"
            versus = f" vs {thesis}" if thesis is not None else ""
            cells.append(f"{r['detections']}{note}, {_clock(r.get('sim_time_s', 0))}{versus}")
        lines.append(f"| {mission} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Best detections (occupied cells at the end), the outcome when not `finished`, the simulated "
                 "mission time, and the thesis's best count for that cell (its Table 1; all its Square runs "
                 "collided).")
    return "\n".join(lines) + "\n"


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600:02d}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"
