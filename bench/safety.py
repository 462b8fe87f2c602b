"""Safety: no mission may end in a collision, in the known scenes or in seeded random obstacle fields.

Groups of runs (every mission: square, browse, search, pathfind):

- copter in castle.wrl (start -40, 0, altitude 4; when ../shared is there) and in the
  project's scenes (default, trees, house, apartment: their own start and suggested settings);
- copter in the apartment from a spot in each of five rooms (living room, kitchen, both
  bedrooms, study; its scene's header names them), and with ``--room-starts N`` from N - 1 more
  starts within ``JITTER`` of each spot (the same draw every time): a mission indoors is chaotic,
  a start a hand's width away can end in another room, so five runs say little of how often
  Search covers a room or a vehicle gets home;
- copter in ``--fields`` random obstacle fields (default 100);
- rover in the first ``--rover-fields`` of those fields (default 20), and in the project's scenes.

A random field is VRML text, a pure function of its seed: a ground plane and 15-40
obstacles within about 35 m of the origin (boxes of random size and yaw, thin walls,
poles), none nearer than 2.5 m to the start at the origin. ``--dump-field K`` prints
field K, so a run can be reproduced with ``vehicle experiment --scene field.wrl``.

Copter runs in the closed indoor scenes (house, apartment) also report the share of the floor
reachable from their start (where the body and its doorway clearance fit at flight height) that
their memory map knows ("floor known", ``vehicle.world.floor``); the issue's target for Search is 80 %.

Prints a Markdown table of outcomes per mission for each group and every collision and
error with what reproduces it; saves a top view of each collision and timeout (scene, memory map,
path) and the field's VRML into /tmp/bench-out (bench/out/ is not git-ignored). Exits
with status 1 if any run collided.
Run: python bench/safety.py [--fields N] [--rover-fields N] [--room-starts N] [--workers N]
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import random
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from common import CASTLE, ROOT, code_state, table

from vehicle.agent.settings import load_settings
from vehicle.lab.experiment import OUTCOMES, Experiment, run_experiment
from vehicle.mapping.planner import DOORWAY_CLEARANCE
from vehicle.world.floor import Floor, reachable_floor
from vehicle.world.scene import Scene, load_scene, parse_scene

MISSIONS = ["square", "browse", "search", "pathfind"]
PROJECT_SCENES = [ROOT / "scenes" / name for name in ("default.wrl", "trees.wrl", "house.wrl", "apartment.wrl")]
APARTMENT = ROOT / "scenes" / "apartment.wrl"
APARTMENT_ROOMS = [(-4.8, -3.0), (1.8, -2.6), (-5.8, 2.9), (-1.0, 2.9), (3.2, 3.3)]  # clear spots, one per room
JITTER = 0.4  # m either way of a room's spot that its further starts lie (each spot has 1.5 m clear round it)
INDOOR = ("house.wrl", "apartment.wrl")  # closed scenes: their reachable floor is the measure of coverage
BODY = 0.3 + DOORWAY_CLEARANCE  # the default copter's radius and the clearance planning keeps in a doorway
OUT = Path("/tmp/bench-out")
CLEARANCE = 2.5  # no obstacle nearer than this to the start (the origin)
RADIUS = 35.0  # obstacle centres within this distance of the origin


# ---- random obstacle fields ---------------------------------------------------------------------------------

def _distance_to_box(cx: float, cy: float, width: float, depth: float, yaw: float) -> float:
    """Distance from the origin to a box footprint centred at (cx, cy), turned by yaw (radians, CCW)."""
    # the origin in the box's own frame
    c, s = math.cos(-yaw), math.sin(-yaw)
    lx, ly = c * -cx - s * -cy, s * -cx + c * -cy
    dx, dy = max(abs(lx) - width / 2, 0.0), max(abs(ly) - depth / 2, 0.0)
    return math.hypot(dx, dy)


def _shape(geometry: str, colour: tuple[float, float, float]) -> str:
    r, g, b = colour
    return (f"Shape {{ appearance Appearance {{ material Material {{ diffuseColor {r:.2f} {g:.2f} {b:.2f} }} }} "
            f"geometry {geometry} }}")


def field_vrml(seed: int) -> str:
    """The VRML text of random obstacle field ``seed`` (the same text for the same seed, always)."""
    rng = random.Random(seed)
    count = rng.randint(15, 40)
    lines = ["#VRML V2.0 utf8", f"# random obstacle field {seed} (bench/safety.py): {count} obstacles", "",
             "DEF Ground Transform { children [",
             "  " + _shape("IndexedFaceSet { solid FALSE coord Coordinate { point [ -60 -60 0, 60 -60 0, "
                           "60 60 0, -60 60 0 ] } coordIndex [ 0 1 2 3 -1 ] }", (0.5, 0.58, 0.45)),
             "] }"]
    placed = 0
    while placed < count:
        kind = rng.choices(["box", "wall", "pole"], weights=[5, 2, 3])[0]
        angle = rng.uniform(0, 2 * math.pi)
        distance = RADIUS * math.sqrt(rng.random())
        cx, cy = distance * math.cos(angle), distance * math.sin(angle)
        if kind == "pole":
            radius, height = rng.uniform(0.1, 0.5), rng.uniform(1, 12)
            if math.hypot(cx, cy) - radius < CLEARANCE:
                continue
            geometry = f"Cylinder {{ radius {radius:.3f} height {height:.3f} }}"
            lines.append(f"DEF Pole{placed:02d} Transform {{ translation {cx:.3f} {cy:.3f} {height / 2:.3f} "
                         f"rotation 1 0 0 1.5708 children [ {_shape(geometry, (0.95, 0.75, 0.1))} ] }}")
        else:
            yaw = rng.uniform(0, math.pi)
            if kind == "box":
                width, depth, height = rng.uniform(0.3, 10), rng.uniform(0.3, 10), rng.uniform(1, 12)
                colour = (0.75, 0.45, 0.3)
            else:
                width, depth, height = rng.uniform(3, 15), rng.uniform(0.1, 0.4), rng.uniform(1, 6)
                colour = (0.6, 0.6, 0.65)
            if _distance_to_box(cx, cy, width, depth, yaw) < CLEARANCE:
                continue
            geometry = f"Box {{ size {width:.3f} {depth:.3f} {height:.3f} }}"
            name = "Box" if kind == "box" else "Wall"
            lines.append(f"DEF {name}{placed:02d} Transform {{ translation {cx:.3f} {cy:.3f} {height / 2:.3f} "
                         f"rotation 0 0 1 {yaw:.4f} children [ {_shape(geometry, colour)} ] }}")
        placed += 1
    return "\n".join(lines) + "\n"


@functools.lru_cache(maxsize=4)
def field_scene(seed: int) -> Scene:
    return parse_scene(field_vrml(seed), f"field-{seed}.wrl")


@functools.lru_cache(maxsize=8)
def file_scene(path: str) -> Scene:
    return load_scene(path)


@functools.lru_cache(maxsize=8)
def indoor_floor(path: str, altitude: float) -> Floor:
    return reachable_floor(file_scene(path), altitude, BODY)


# ---- runs ---------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Job:
    group: str
    scene: str  # a path, or "field-K"
    mission: str
    vehicle: str = "copter"
    start: tuple[float, float] | None = None

    @property
    def field(self) -> int | None:
        return int(self.scene.split("-", 1)[1]) if self.scene.startswith("field-") else None

    def reproduce(self) -> str:
        if self.field is not None:
            wrl = OUT / f"field-{self.field}.wrl"
            prefix = f"mkdir -p {OUT} && python bench/safety.py --dump-field {self.field} > {wrl} && "
            scene = str(wrl)
        else:
            prefix, scene = "", self.scene
        start = f" --start={self.start[0]:g},{self.start[1]:g}" if self.start else ""
        return (f"{prefix}vehicle experiment --scene {scene}{start} --mission {self.mission} "
                f"--vehicle {self.vehicle}")


def run_job(job: Job) -> dict:
    """One mission to its outcome; on a collision or timeout, a top view of it is saved. Never raises."""
    started = time.perf_counter()
    try:
        if job.field is not None:
            scene = field_scene(job.field)
        else:
            scene = file_scene(job.scene)
        settings = load_settings(scene_hints=scene.hints)
        route: list[tuple[float, float]] = []
        seen = {}

        def on_step(stepper, _readings) -> None:
            world = stepper.simulation
            seen["agent"] = stepper.agent
            if world.steps % 5 == 0:
                route.append((world.pose.x, world.pose.y))

        name = f"{job.scene}.wrl" if job.field is not None else job.scene
        result = run_experiment(Experiment(name, job.mission, job.vehicle, job.start, None, settings),
                                scene=scene, on_step=on_step)
        if result["outcome"] in ("collision", "timeout"):
            result["picture"] = _picture(job, scene, seen.get("agent"), route, result)
        if job.vehicle == "copter" and Path(job.scene).name in INDOOR and "agent" in seen:
            floor = indoor_floor(job.scene, settings.altitude)
            result["floor_known"] = floor.known_share(seen["agent"].map, tuple(result["start"][:2]))
    except Exception as error:  # noqa: BLE001 - a failure is a finding, reported with the others
        result = {"outcome": "error", "reason": f"{type(error).__name__}: {error}", "detections": 0}
    result["job"] = job
    result.setdefault("wall_time_s", round(time.perf_counter() - started, 3))
    return result


def _picture(job: Job, scene: Scene, agent, route: list[tuple[float, float]], result: dict) -> str:
    from vehicle.world.topview import render_top_view

    OUT.mkdir(parents=True, exist_ok=True)
    stem = f"{result['outcome']}-{Path(job.scene).stem}-{job.mission}-{job.vehicle}{_at(job.start)}"
    if job.field is not None:
        (OUT / f"{job.scene}.wrl").write_text(field_vrml(job.field), encoding="utf-8")
    final = result.get("final_position")
    if final:
        route = [*route, (final[0], final[1])]
    path = OUT / f"{stem}.png"
    render_top_view(scene, path, memory_map=agent.map if agent is not None else None, route=route,
                    start=tuple(result.get("start") or (0.0, 0.0)),
                    title=f"{result['outcome']}: {job.vehicle} {job.mission} in {Path(job.scene).stem}")
    return str(path)


def indoor_summary(results: list[dict]) -> str:
    """Per mission over a group's indoor runs: how many know 80 % of the reachable floor (the issue's target
    for Search), the median share, and how many ended home (finished, or stopped with the vehicle home)."""
    rows = []
    for mission in ("search", "pathfind"):
        runs = [r for r in results if r["job"].mission == mission and r.get("floor_known") is not None]
        if not runs:
            continue
        shares = sorted(r["floor_known"] for r in runs)
        home = sum(r["outcome"] in ("finished", "stopped") and "could not get home" not in r["reason"] for r in runs)
        rows.append([mission, len(runs), f"{sum(s >= 0.8 for s in shares)} of {len(runs)}",
                     _percent(shares[len(shares) // 2]), f"{home} of {len(runs)}"])
    return table(["mission", "runs", "floor known >= 80 %", "median floor known", "ended home"], rows)


def _percent(share: float | None) -> str:
    return "-" if share is None else f"{100 * share:.0f} %"


def _at(start: tuple[float, float] | None) -> str:
    return f"@{start[0]:g},{start[1]:g}" if start else ""


def _xy(position) -> str:
    return "-" if not position else "(" + ", ".join(f"{float(v):.2f}" for v in position) + ")"


def room_starts(per_room: int) -> list[tuple[float, float]]:
    """Each room's spot, and ``per_room - 1`` starts within ``JITTER`` of it (a fixed draw per room)."""
    starts = []
    for k, (x, y) in enumerate(APARTMENT_ROOMS):
        draw = random.Random(f"room-{k}")
        starts.append((x, y))
        starts += [(round(x + draw.uniform(-JITTER, JITTER), 2), round(y + draw.uniform(-JITTER, JITTER), 2))
                   for _ in range(per_room - 1)]
    return starts


def jobs(fields: int, rover_fields: int, per_room: int = 1) -> list[Job]:
    out: list[Job] = []
    known = []
    if CASTLE.exists():
        known.append((str(CASTLE), (-40.0, 0.0)))
    known += [(str(path), None) for path in PROJECT_SCENES]
    for path, start in known:
        out += [Job("copter, castle and project scenes", path, m, "copter", start) for m in MISSIONS]
    rooms = "copter, apartment from five rooms" + (f", {per_room} starts each" if per_room > 1 else "")
    for start in room_starts(per_room):
        out += [Job(rooms, str(APARTMENT), m, "copter", start) for m in MISSIONS]
    for k in range(fields):
        out += [Job(f"copter, {fields} random fields", f"field-{k}", m) for m in MISSIONS]
    for k in range(rover_fields):
        out += [Job(f"rover, {rover_fields} random fields", f"field-{k}", m, "rover") for m in MISSIONS]
    for path in PROJECT_SCENES:
        out += [Job("rover, project scenes", str(path), m, "rover") for m in MISSIONS]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--fields", type=int, default=100, help="random fields for the copter (default 100)")
    parser.add_argument("--rover-fields", type=int, default=20, help="random fields for the rover (default 20)")
    parser.add_argument("--room-starts", type=int, default=1, metavar="N",
                        help="starts in each of the apartment's five rooms (default 1: the room's spot)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: one per core)")
    parser.add_argument("--dump-field", type=int, metavar="K", help="print the VRML of random field K and exit")
    args = parser.parse_args()
    if args.dump_field is not None:
        sys.stdout.write(field_vrml(args.dump_field))
        return 0

    state = code_state()
    if args.room_starts < 1:
        parser.error("--room-starts must be at least 1")
    todo = jobs(args.fields, args.rover_fields, args.room_starts)
    print(f"{len(todo)} runs on {args.workers} workers", file=sys.stderr)
    started = time.perf_counter()
    results: list[dict] = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = [pool.submit(run_job, job) for job in todo]
        for done, future in enumerate(as_completed(futures), 1):
            results.append(future.result())
            if done % 50 == 0 or done == len(todo):
                print(f"  {done}/{len(todo)} runs, {time.perf_counter() - started:.0f} s", file=sys.stderr)
    wall = time.perf_counter() - started
    order = {job: i for i, job in enumerate(todo)}
    results.sort(key=lambda r: order[r["job"]])

    groups = list(dict.fromkeys(job.group for job in todo))
    for group in groups:
        mine = [r for r in results if r["job"].group == group]
        rows = []
        for mission in MISSIONS:
            runs = [r for r in mine if r["job"].mission == mission]
            counts = [sum(r["outcome"] == o for r in runs) for o in OUTCOMES]
            detections = sorted(r["detections"] for r in runs)
            sim = sum(r.get("sim_time_s", 0) for r in runs)
            rows.append([mission, len(runs), *counts, detections[len(detections) // 2] if detections else "-",
                         sum(d == 0 for d in detections), f"{sim / max(1, len(runs)):.0f}"])
        print(f"\n### {group}\n")
        print(table(["mission", "runs", *OUTCOMES, "median detections", "zero detections", "mean sim s"], rows))
        if group.startswith("copter, apartment"):
            print()
            print(indoor_summary(mine))
        if group.startswith(("copter, castle", "copter, apartment", "rover, project")):
            print()
            print(table(["scene", "mission", "outcome", "reason", "detections", "floor known", "sim s"],
                        [[Path(r["job"].scene).name + _at(r["job"].start), r["job"].mission, r["outcome"], r["reason"],
                          r["detections"], _percent(r.get("floor_known")), r.get("sim_time_s", "-")] for r in mine]))

    bad = [r for r in results if r["outcome"] in ("collision", "error")]
    print(f"\n### Collisions and errors: {sum(r['outcome'] == 'collision' for r in bad)} collisions, "
          f"{sum(r['outcome'] == 'error' for r in bad)} errors\n")
    for r in bad:
        job = r["job"]
        print(f"- {r['outcome']}: {job.vehicle} {job.mission} in {Path(job.scene).name} "
              f"(field seed {job.field if job.field is not None else '-'}) at {r.get('sim_time_s', '-')} s, "
              f"position {_xy(r.get('final_position'))}: {r['reason']}")
        print(f"  reproduce: `{job.reproduce()}`")
        if r.get("picture"):
            print(f"  top view: {r['picture']}")
    timeouts = [r for r in results if r["outcome"] == "timeout"]
    if timeouts:
        print(f"\n### Timeouts: {len(timeouts)} (safe, but the mission never ended)\n")
        for r in timeouts:
            job = r["job"]
            print(f"- {job.vehicle} {job.mission} in {Path(job.scene).name}: {r['reason']}; "
                  f"{r.get('distance_m', '-')} m travelled, final position {_xy(r.get('final_position'))}; "
                  f"last message: {(r.get('messages') or ['-'])[-1]}")
            print(f"  reproduce: `{job.reproduce()}`; top view: {r.get('picture')}")
    print(f"\n{len(results)} runs in {wall:.0f} s wall on {args.workers} workers (load average at the end "
          f"{os.getloadavg()[0]:.1f}); vehicle code: {state}")
    return 1 if any(r["outcome"] == "collision" for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
