"""``vehicle``: the onboard side's command line (scene, experiment, sweep, sim, agent)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from vehicle import __version__, options
from vehicle.agent.missions import MISSIONS
from vehicle.protocol.geodesy import datum_option
from vehicle.world.bundled import default_scene
from vehicle.world.suites import DEFAULT_SUITE, SENSOR_SUITES

DEFAULT_SCENE = default_scene()
DEFAULT_SIM_LINK = "udpout:127.0.0.1:14550"  # a ground station on this machine; the vehicle's port is loopback only


def _point(text: str) -> tuple[float, ...]:
    """``X,Y`` or ``X,Y,Z`` in scene metres."""
    try:
        point = tuple(float(v) for v in text.split(","))
    except ValueError:
        point = ()
    if len(point) not in (2, 3) or not all(map(math.isfinite, point)):
        raise argparse.ArgumentTypeError(f"expected X,Y or X,Y,Z, not {text!r}")
    return point


def _signing_key(value: str) -> bytes:
    from vehicle.protocol.signing import key_option  # pymavlink loads only when the option is given

    return key_option(value)


SIGNING_HELP = ("MAVLink 2 signing key: a file (32 bytes, or one line of 64 hex digits or of base64) or a "
                "passphrase (its SHA-256 is the key, as QGroundControl and MAVProxy make one); then everything sent "
                "is signed and whatever is not signed with it (but RADIO_STATUS) is refused")


def add_run_options(parser: argparse.ArgumentParser, mission_required: bool = True,
                    kinds: tuple[str, ...] = ("rover", "copter")) -> None:
    """Options shared by ``experiment`` and ``sim``: what to fly, where, and with which settings."""
    from vehicle.agent.settings import Settings

    parser.add_argument("--scene", default=str(DEFAULT_SCENE), help="VRML scene (default: %(default)s)")
    parser.add_argument("--mission", required=mission_required, type=str.lower, choices=list(MISSIONS),
                        help="; ".join(f"{name}: {text}" for name, text in MISSIONS.items()))
    parser.add_argument("--vehicle", default="copter", choices=list(kinds))
    parser.add_argument("--start", type=_point, metavar="X,Y[,Z]", action="append",
                        help="start in scene metres (default: the scene's Start); with Z, on the highest surface "
                             "below Z (a floor under a roof); a team (experiment --vehicles N) takes one per vehicle")
    parser.add_argument("--heading", type=options.finite, help="start heading, compass degrees (0 = north)")
    parser.add_argument("--altitude", type=options.finite, help="operating altitude above the start's ground, m")
    parser.add_argument("--set", dest="assignments", action="append", default=[], metavar="NAME=VALUE",
                        help="set a mission parameter: " + ", ".join(
                            f"{n} ({u}, default {d:g}, {lo:g} to {hi:g}): {h}"
                            for n, d, u, h, _, (lo, hi) in Settings.describe()))
    parser.add_argument("--config", help="TOML file of mission parameters")
    parser.add_argument("--waypoints", help="QGC WPL 110 file of waypoints (square, pathfind)")
    parser.add_argument("--seed", type=options.whole(0), default=0, help="seed for sensor noise and random choices")
    parser.add_argument("--sensors", default=DEFAULT_SUITE, choices=list(SENSOR_SUITES),
                        help="; ".join(f"{name}: {text}" for name, text in SENSOR_SUITES.items())
                        + " (default %(default)s)")
    parser.add_argument("--datum", type=datum_option, metavar="LAT,LON[,ALT]",
                        help="where the scene origin lies on Earth, degrees and metres above sea level (default: "
                             "the scene's datum hint, else ArduPilot's simulator home -35.363261,149.165230,584)")
    options.add_radio_options(parser)


def _one_start(args: argparse.Namespace) -> tuple[float, ...] | None:
    """The start of a lone vehicle: --start given once at most."""
    if args.start and len(args.start) > 1:
        raise ValueError(f"--start given {len(args.start)} times for one vehicle (a team: --vehicles N)")
    return args.start[0] if args.start else None


def _system_ids(text: str) -> list[int]:
    """``1,2,3``: a team's MAVLink system ids."""
    try:
        return [options.system_id(v) for v in text.split(",")]
    except argparse.ArgumentTypeError as error:
        raise argparse.ArgumentTypeError(f"--sysids wants system ids 1 to 255 separated by commas: {error}") from None


def _team_sizes(text: str) -> list[int]:
    """``1,2,4``: team sizes for a sweep."""
    try:
        return [options.whole(1, 8)(v) for v in text.split(",")]
    except argparse.ArgumentTypeError as error:
        raise argparse.ArgumentTypeError(f"--vehicles wants team sizes 1 to 8 separated by commas: {error}") from None


def settings_from(args: argparse.Namespace, scene, **extra):
    """Mission parameters: defaults < the scene's suggestions < --config < --set < --altitude and the like."""
    from vehicle.agent.settings import load_settings

    return load_settings(args.config, args.assignments, scene.hints, altitude=args.altitude, **extra)


def cmd_scene(args: argparse.Namespace) -> int:
    from vehicle.world.scene import load_scene
    from vehicle.world.topview import render_top_view

    scene = load_scene(args.file)
    bounds = [[round(float(v), 3) for v in row] for row in scene.bounds] if len(scene.faces) else None
    report = {"triangles": len(scene.faces), "objects": scene.objects, "bounds": bounds,
              "warnings": scene.warnings}
    if scene.start is not None:
        report["start"] = [round(v, 3) for v in scene.start]
    if args.top_view:
        render_top_view(scene, args.top_view, start=scene.start,
                        title=f"{Path(args.file).name}: scene metres, x east, y north")
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"{args.file}: {report['triangles']} triangles, {report['objects']} objects")
    if bounds:
        print(f"bounds: {bounds[0]} .. {bounds[1]}")
    if scene.start is not None:
        print(f"start: {report['start']} heading {scene.start_heading or 0:g}")
    for warning in scene.warnings:
        print(f"warning: {warning}")
    if args.top_view:
        print(f"top view: {args.top_view}")
    return 0


def cmd_experiment(args: argparse.Namespace) -> int:
    from vehicle.lab.experiment import Experiment, run_experiment
    from vehicle.protocol.geodesy import Datum
    from vehicle.protocol.waypoints import load_positions
    from vehicle.world.scene import load_scene

    scene = load_scene(args.scene)
    settings = settings_from(args, scene, time_limit=args.time_limit)
    datum = Datum.of_scene(scene.hints, args.datum)
    waypoints = load_positions(args.waypoints, datum) if args.waypoints else None
    if args.vehicles is not None or args.sysids is not None or _with_radios(args):
        return _team_experiment(args, scene, settings, datum, waypoints)
    experiment = Experiment(args.scene, args.mission, args.vehicle, _one_start(args), args.heading, settings,
                            args.seed, waypoints, args.sensors, datum)
    log = None
    if args.log:
        from vehicle.lab.log import ExperimentLog

        log = ExperimentLog(args.log, scene=args.scene)
    log_error = None
    try:
        result = run_experiment(experiment, scene=scene, map_out=args.map_out, on_step=log)
    finally:
        if log is not None:
            try:
                log.close()
            except OSError as error:  # the log failed, not the run: its result first, then the error (exit 2)
                log_error = error
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['mission']} in {result['scene']} ({result['vehicle']}): {result['outcome']}"
              f" - {result['reason']}")
        print(f"detections {result['detections']} (cells ever hit {result['cells_ever_hit']}) at "
              f"{result['resolution']:g} cells/m; {result.get('sim_time_s', 0):.1f} s simulated in "
              f"{result['wall_time_s']:.2f} s; {result.get('distance_m', 0):.1f} m flown")
        if args.map_out:
            print(f"map written to {args.map_out}")
        if log is not None and log_error is None:
            print(f"log written to {args.log} ({log.messages} messages)")
    if log_error is not None:
        print(f"vehicle {args.command}: {log_error}", file=sys.stderr)
        return 2
    return failed(result)


def _team_experiment(args: argparse.Namespace, scene, settings, datum, waypoints) -> int:
    """``vehicle experiment --vehicles N``: the team is made (and refused, exit 2) before anything flies."""
    from vehicle.lab.experiment import Experiment, run_team
    from vehicle.lab.stepper import simulate_team

    count = args.vehicles if args.vehicles is not None else len(args.sysids) if args.sysids is not None else 1
    if args.sysids is not None and len(args.sysids) != count:
        raise ValueError(f"--sysids names {len(args.sysids)} vehicles, --vehicles {count}")
    if args.start and len(args.start) != count:
        raise ValueError(f"--start given {len(args.start)} times for a team of {count}: once per vehicle, or not")
    if args.log or args.map_out:
        raise ValueError("--log and --map-out are for one vehicle; a team's run reports in its JSON")
    experiment = Experiment(args.scene, args.mission, args.vehicle, None, args.heading, settings, args.seed,
                            waypoints, args.sensors, datum)
    if _with_radios(args):  # the team's radios measured beside the flight, the targets imaged
        from vehicle.lab.tomograph import run_team_experiment
        from vehicle.world.radio import RadioModel

        model = RadioModel.from_options(args.radio_settings)
        result = run_team_experiment(experiment, scene, count, args.targets or [], args.start, args.sysids,
                                     args.radio_nodes, waypoints, model)
    else:
        stepper = simulate_team(scene, args.mission, count, args.vehicle, settings, args.start, args.sysids,
                                [waypoints] * count if waypoints else None, seed=args.seed, suite=args.sensors,
                                datum=datum)
        result = run_team(experiment, stepper)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['mission']} in {result['scene']} ({result['team']} {result['vehicle']}s): "
              f"{result['outcome']} - {result['reason'] or 'all finished'}")
        for v in result["vehicles"]:
            print(f"  vehicle {v['sysid']}: {v['outcome']} - {v['reason']}; {v['detections']} occupied cells, "
                  f"{v['distance_m']:.1f} m flown, gave way {v['gave_way']} times, closest to the scene "
                  f"{_metres(v['closest_scene_m'])}")
        if "rti" in result:
            rti = result["rti"]
            print(f"radio tomography: {rti['links_heard']} link records heard, {rti['links_imaged']} imaged; "
                  f"targets {'all found' if rti['found'] else 'not all found'} within {rti['found_within_m']} m "
                  f"(distance to the nearest peak: {', '.join(_metres(d) for d in rti['distances_m']) or '-'})")
        shared = "shared" if result["share_maps"] else "not shared"
        print(f"team: {result['detections']} occupied cells together (maps {shared}); "
              f"closest approach between vehicles {_metres(result['closest_vehicles_m'])}; "
              f"{result['sim_time_s']:.1f} s simulated in {result['wall_time_s']:.2f} s")
    return failed(result)


def _metres(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} m"


def _with_radios(args: argparse.Namespace) -> bool:
    """The vehicles carry radios: there are targets, fixed nodes or radio settings, or the mission is rti."""
    return bool(args.targets or args.radio_nodes or args.radio_settings or args.mission == "rti")


def _radios(args: argparse.Namespace, scene, ids: list[int], homes: list[tuple[float, ...]]):
    """The world's radios when the run has any (targets, fixed nodes or the rti mission), else None."""
    from vehicle.sim.radios import Radios
    from vehicle.world.radio import RadioModel

    model = RadioModel.from_options(args.radio_settings)  # a bad setting is refused even without radios
    if not _with_radios(args):
        return None
    return Radios(scene, ids, args.radio_nodes, args.targets, model, args.seed,
                  {sysid: (home[0], home[1]) for sysid, home in zip(ids, homes, strict=True)})


def _warm_up(warm_up, who: str) -> None:
    """Load (or, once after an install, compile: some 15 s) the simulation's loops, saying so first: a new
    user saw a silent terminal and a page saying "No vehicles yet" and took the start for a hang."""
    print(f"{who}: loading the simulation's compiled loops (the first start after an install compiles them, "
          "about 15 s)", file=sys.stderr, flush=True)
    warmed = warm_up()
    if warmed > 1.0:
        print(f"{who}: compiled the simulation's loops in {warmed:.1f} s (once after an install)", flush=True)


def cmd_sim(args: argparse.Namespace) -> int:
    from vehicle.lab.experiment import warm_up
    from vehicle.lab.live import SimOptions, SimVehicle
    from vehicle.lab.stepper import simulate
    from vehicle.protocol.geodesy import Datum
    from vehicle.protocol.waypoints import load_mission, parse_points, positions
    from vehicle.world.scene import load_scene
    from vehicle.world.suites import sensor_suite

    autopilot = args.role == "autopilot"
    if autopilot == bool(args.mission):  # checked first: loading the scene and the loops takes a while
        raise ValueError("--mission NAME (a vehicle with its onboard agent) or --role autopilot (for an onboard "
                         "agent in another process), one of them")
    if args.vehicles is None and (args.sysids or args.team_link or args.port_step is not None
                                  or args.vehicle == "mixed"):
        raise ValueError("--sysids, --team-link, --port-step and --vehicle mixed are for a team: give --vehicles N")
    scene = load_scene(args.scene)
    settings = settings_from(args, scene)
    if args.vehicles is not None:
        return _sim_team(args, scene, settings)
    _warm_up(warm_up, f"vehicle {args.sysid}")  # before any link opens
    datum = Datum.of_scene(scene.hints, args.datum)
    items = load_mission(args.waypoints) if args.waypoints else None
    waypoints = positions(items, datum) if items else (
        parse_points(scene.hints["waypoints"]) if "waypoints" in scene.hints else None)
    stepper = simulate(scene, None if autopilot else args.mission, args.vehicle, settings, _one_start(args),
                       args.heading, waypoints, autostart=args.autostart, seed=args.seed,
                       sensors=sensor_suite(args.sensors, args.vehicle), datum=datum)
    world = stepper.simulation
    if items:
        world.autopilot.set_mission(items)
    sim_options = SimOptions(args.mavlink or [DEFAULT_SIM_LINK], args.sysid, args.speedup,
                             args.failsafe_timeout, args.log, sim_clock=autopilot, signing_key=args.signing_key)
    radios = _radios(args, scene, [args.sysid], [world.home])
    if radios is not None:
        stepper.controller.radio_nodes = [p[:2] for p in args.radio_nodes or []]
    sim = SimVehicle(stepper, sim_options, say=lambda text: print(f"vehicle {args.sysid}: {text}", file=sys.stderr,
                                                                   flush=True), radios=radios)
    if autopilot:
        start = "a plain autopilot: an onboard agent flies it over MAVLink"
    else:
        start = f"mission {args.mission}, " + ("starting now" if args.autostart else
                                                "waiting for arm + AUTO/MISSION_START or GUIDED takeoff")
    print(f"vehicle {args.sysid}: {args.vehicle} in {Path(args.scene).name} at {world.home[0]:.1f}, "
          f"{world.home[1]:.1f}, x{args.speedup:g}, on {', '.join(sim_options.urls)}; {start}", flush=True)
    try:
        sim.run(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        stats = ", ".join(f"{k} {v}" for k, v in sorted(sim.endpoint.stats.items()))
        print(f"vehicle {args.sysid}: stopped at {world.time:.1f} s simulated; {stats}", flush=True)
    return 0


def team_kind(vehicle: str, index: int) -> str:
    """A team's vehicle ``index``: ``mixed`` alternates copter and rover (the first a copter)."""
    return ("copter", "rover")[index % 2] if vehicle == "mixed" else vehicle


PORT_STEP = 10  # a team's vehicle k has its links' ports k * this up, as ArduPilot SITL's instance -I k


def _team_urls(urls: list[str], index: int, step: int) -> list[str]:
    """Vehicle ``index``'s links: each URL with its port ``index * step`` up."""
    out = []
    for url in urls:
        head, _, port = url.rpartition(":")
        if not port.isdigit() or not head:
            raise ValueError(f"--mavlink {url} names no port to give each vehicle of the team its own (a serial "
                             "link cannot be shared); give it as --team-link for a link every vehicle opens as is")
        if int(port) + index * step > 65535:
            raise ValueError(f"--mavlink {url}: vehicle {index + 1}'s port {int(port) + index * step} is past 65535")
        out.append(f"{head}:{int(port) + index * step}")
    return out


def _sim_team(args: argparse.Namespace, scene, settings) -> int:
    """``vehicle sim --vehicles N``: N autopilots (with their agents, given --mission) in one world, vehicle k
    (from 0) on the --mavlink links with their ports k * --port-step up, plus every --team-link as is, with the
    system id --sysid + k (or the k-th of --sysids). Refused (exit 2) before any link opens."""
    from vehicle.lab.experiment import warm_up
    from vehicle.lab.live import Autopilots, SimOptions, SimTeam
    from vehicle.lab.stepper import TeamStepper, team_starts
    from vehicle.protocol.geodesy import Datum
    from vehicle.sim.simulation import Simulation
    from vehicle.sim.team import Team
    from vehicle.world.suites import sensor_suite

    count = args.vehicles
    ids = args.sysids or list(range(args.sysid, args.sysid + count))
    if len(ids) != count or ids[-1] > 255:
        raise ValueError(f"a team of {count} needs {count} system ids of 1 to 255 (--sysids, or --sysid "
                         f"{args.sysid} and up)")
    if args.start and len(args.start) != count:
        raise ValueError(f"--start given {len(args.start)} times for a team of {count}: once per vehicle, or not")
    if args.waypoints:
        raise ValueError("--waypoints is for one vehicle; a team flies its mission's own")
    step = PORT_STEP if args.port_step is None else args.port_step
    urls = args.mavlink or ([] if args.team_link else [DEFAULT_SIM_LINK])
    links = [_team_urls(urls, k, step) + list(args.team_link or []) for k in range(count)]
    listening = [url for own in links for url in own if url.partition(":")[0] in ("udpin", "udp", "tcpin")]
    if len(set(listening)) < len(listening):
        raise ValueError("two vehicles of the team would listen on one port: give --port-step above 0, or "
                         "--team-link only for links that send (udpout, tcp)")
    datum = Datum.of_scene(scene.hints, args.datum)
    simulations = [Simulation(scene, team_kind(args.vehicle, k), start, args.heading, seed=args.seed + k,
                              sensors=sensor_suite(args.sensors, team_kind(args.vehicle, k)), datum=datum,
                              cruise_speed=settings.speed,
                              wp_radius=settings.closeness)
                   for k, start in enumerate(args.start or team_starts(scene, count))]
    team = Team(simulations, ids)
    stepper = TeamStepper(team, args.mission, settings, None, args.autostart) if args.mission else Autopilots(team)
    _warm_up(warm_up, "vehicle team")
    autopilot = args.role == "autopilot"
    per_vehicle = [SimOptions(own, sysid, args.speedup, args.failsafe_timeout, args.log if k == 0 else None,
                              sim_clock=autopilot, signing_key=args.signing_key)
                   for k, (own, sysid) in enumerate(zip(links, ids, strict=True))]
    radios = _radios(args, scene, ids, [world.home for world in simulations])
    for controller in getattr(stepper, "controllers", []) if radios is not None else []:
        controller.radio_nodes = [p[:2] for p in args.radio_nodes or []]
    sim = SimTeam(stepper, per_vehicle, say=lambda text: print(f"vehicle team: {text}", file=sys.stderr, flush=True),
                  radios=radios)
    what = "plain autopilots: an onboard agent flies each over MAVLink" if autopilot else f"mission {args.mission}"
    print(f"vehicle team: {count} vehicles ({args.vehicle}) in {Path(args.scene).name}, one world, "
          f"x{args.speedup:g}; {what}", flush=True)
    for world, sysid, own in zip(stepper.team.simulations, ids, links, strict=True):
        print(f"vehicle {sysid}: {world.kind.value} at {world.home[0]:.1f}, {world.home[1]:.1f} on {', '.join(own)}",
              flush=True)
    try:
        sim.run(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        print(f"vehicle team: stopped at {sim.world.time:.1f} s simulated", flush=True)
        for wire, sysid in zip(sim.wires, ids, strict=True):
            stats = ", ".join(f"{k} {v}" for k, v in sorted(wire.endpoint.stats.items()))
            print(f"vehicle {sysid}: {stats}", flush=True)
    return 0


def cmd_agent(args: argparse.Namespace) -> int:
    from vehicle.agent.process import AgentOptions, run_agent
    from vehicle.agent.settings import load_settings
    from vehicle.protocol.geodesy import Datum
    from vehicle.protocol.waypoints import load_positions, parse_points

    scene = None
    if args.scene:
        from vehicle.world.scene import load_scene

        scene = load_scene(args.scene)
    elif args.sensors == "scene":
        raise ValueError("--sensors scene needs --scene")
    hints = scene.hints if scene is not None else {}
    settings = load_settings(args.config, args.assignments, hints, altitude=args.altitude)
    datum = Datum.of_scene(hints, args.datum)
    waypoints = load_positions(args.waypoints, datum) if args.waypoints else (
        parse_points(hints["waypoints"]) if "waypoints" in hints else None)
    agent_options = AgentOptions(args.connect, args.mission, args.vehicle, settings, waypoints, scene, args.sensors,
                                 args.suite, args.gcs, datum, args.log, args.wait, args.stay, args.connect_timeout,
                                 args.signing_key, radio_nodes=args.radio_nodes or [])
    result = run_agent(agent_options, args.duration, say=lambda text: print(text, file=sys.stderr, flush=True))
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['mission']} ({args.vehicle} over {args.connect}): {result['outcome']} - {result['reason']}")
        if "detections" in result:
            print(f"detections {result['detections']}; {result['sim_time_s']:.1f} s of the autopilot's clock in "
                  f"{result['wall_time_s']:.1f} s; {result['distance_m']:.1f} m flown")
    return failed(result)


def failed(result: dict) -> int:
    """A run's exit code: 1 when it ended in an error or a collision (a script must not take it for a flight
    that went well), else 0; the result says which."""
    return 1 if result["outcome"] in ("error", "collision") else 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from vehicle.lab.presets import PRESETS
    from vehicle.lab.sweep import SweepSpec, parse_grid, run_sweep

    preset = PRESETS[args.preset] if args.preset else {}
    mission_names = args.missions.split(",") if args.missions else preset.get("missions", list(MISSIONS))
    for name in mission_names:
        if name not in MISSIONS:
            raise ValueError(f"unknown mission {name!r}; missions: {', '.join(MISSIONS)}")
    scenes = args.scene or (preset["scenes"]() if preset else [str(DEFAULT_SCENE)])
    grid = {**preset.get("grid", {}), **parse_grid(args.grid)}
    spec = SweepSpec(mission_names, scenes, grid, args.seeds, args.vehicle, args.vehicles or [1], args.targets or [""])
    print(f"{len(spec.jobs())} runs: {len(mission_names)} missions x {len(scenes)} scenes x "
          f"{len(spec.jobs()) // max(1, len(mission_names) * len(scenes) * args.seeds)} settings x {args.seeds} seeds",
          file=sys.stderr)
    results = run_sweep(spec, args.out, workers=args.workers, dask=args.dask)
    print((Path(args.out) / "best.md").read_text(encoding="utf-8"))
    outcomes: dict[str, int] = {}
    for r in results:
        outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
    print("outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    print(f"results in {args.out}/results.csv, table in {args.out}/best.md, maps in {args.out}/maps/")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vehicle", description="Onboard agent and simulated vehicle.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    scene = commands.add_parser("scene", help="load a VRML scene and describe it")
    scene.add_argument("file")
    scene.add_argument("--json", action="store_true", help="print a JSON object")
    scene.add_argument("--top-view", metavar="PNG", help="write a top-down picture of the scene")
    scene.set_defaults(run=cmd_scene)

    experiment = commands.add_parser("experiment", help="run one headless mission on simulated time")
    add_run_options(experiment)
    experiment.add_argument("--time-limit", type=options.finite, help="simulated seconds (default 600)")
    experiment.add_argument("--json", action="store_true", help="print the result as one JSON object")
    experiment.add_argument("--map-out", metavar="DIR", help="write the final memory map (.npy and .png)")
    experiment.add_argument("--log", metavar="FILE.tlog", help="write the run as a MAVLink telemetry log")
    experiment.add_argument("--vehicles", type=options.whole(1, 8), metavar="N",
                            help="fly a team of N (1 to 8) in one world, on the spots around the start (or one "
                                 "--start each); the JSON reports every vehicle and the closest approaches")
    experiment.add_argument("--sysids", type=_system_ids, metavar="ID,ID,...",
                            help="the team's MAVLink system ids (default 1 ... N); the lower id has the right of way")
    experiment.set_defaults(run=cmd_experiment)

    sim = commands.add_parser("sim", help="a simulated vehicle with its onboard agent, live on MAVLink")
    add_run_options(sim, mission_required=False, kinds=("rover", "copter", "mixed"))
    sim.add_argument("--role", choices=["vehicle", "autopilot"], default="vehicle",
                     help="vehicle: the autopilot and its onboard agent in one (default); autopilot: a plain "
                          "ArduPilot-like flight controller, for `vehicle agent` to fly")
    sim.add_argument("--mavlink", action="append", metavar="URL", type=options.link_url,
                     help=f"pymavlink connection string, repeatable (default {DEFAULT_SIM_LINK})")
    sim.add_argument("--sysid", type=options.system_id, default=1, help="MAVLink system id, 1 to 255 (default 1)")
    sim.add_argument("--speedup", type=options.positive, default=1.0,
                     help="simulated seconds per wall second (default 1)")
    sim.add_argument("--autostart", action="store_true", help="arm and start the mission without a GCS")
    sim.add_argument("--failsafe-timeout", type=options.positive, default=5.0,
                     help="wall seconds without a GCS heartbeat before the GCS failsafe (default 5)")
    sim.add_argument("--log", metavar="FILE.tlog", help="record the vehicle's own MAVLink traffic")
    sim.add_argument("--duration", type=options.positive, help="stop after this many wall seconds")
    sim.add_argument("--signing-key", type=_signing_key, metavar="FILE|PASSPHRASE", help=SIGNING_HELP)
    sim.add_argument("--vehicles", type=options.whole(1, 8), metavar="N",
                     help="N vehicles (1 to 8) in one world on one clock, on the team's spots around the start (or "
                          "one --start each); vehicle k (from 0) has the --mavlink links with their ports "
                          f"k * --port-step up (default {PORT_STEP}, as ArduPilot SITL's -I k) and the system id "
                          "--sysid + k; each autopilot reports the others as ADSB_VEHICLE at 4 Hz")
    sim.add_argument("--sysids", type=_system_ids, metavar="ID,ID,...", help="a team's system ids, one per vehicle")
    sim.add_argument("--port-step", type=options.whole(0), metavar="S",
                     help=f"a team's ports per vehicle (default {PORT_STEP}; 0: all on the same port, for udpout)")
    sim.add_argument("--team-link", action="append", metavar="URL", type=options.link_url,
                     help="a link every vehicle of a team opens as given, repeatable: say udpout to one ground "
                          "station's port (each vehicle sends from its own socket)")
    sim.set_defaults(run=cmd_sim)

    agent = commands.add_parser("agent", help="the onboard agent on a companion computer, flying an autopilot "
                                               "(ArduPilot, or vehicle sim --role autopilot) over MAVLink")
    agent.add_argument("--connect", required=True, metavar="URL", type=options.link_url,
                       help="the flight controller, in pymavlink's form: tcp:HOST:PORT, udpin:HOST:PORT, "
                            "/dev/ttyAMA0,921600 ...")
    agent.add_argument("--mission", required=True, type=str.lower, choices=list(MISSIONS),
                       help="; ".join(f"{name}: {text}" for name, text in MISSIONS.items()))
    agent.add_argument("--vehicle", default="copter", choices=["rover", "copter"],
                       help="what the flight controller must be (it is refused otherwise)")
    agent.add_argument("--scene", help="VRML scene the vehicle flies in (for --sensors scene; its hints apply too)")
    agent.add_argument("--sensors", default="fc", choices=["fc", "scene"],
                       help="fc: the autopilot's DISTANCE_SENSOR and OBSTACLE_DISTANCE (default); scene: sonar "
                            "cast in --scene at the pose the autopilot reports, fed to it as DISTANCE_SENSOR")
    agent.add_argument("--suite", default=DEFAULT_SUITE, choices=list(SENSOR_SUITES),
                       help="the sonars cast with --sensors scene (default %(default)s)")
    agent.add_argument("--altitude", type=options.finite, help="operating altitude above home, m")
    agent.add_argument("--set", dest="assignments", action="append", default=[], metavar="NAME=VALUE",
                       help="set a mission parameter (as for vehicle experiment)")
    agent.add_argument("--config", help="TOML file of mission parameters")
    agent.add_argument("--waypoints", help="QGC WPL 110 file of waypoints (square, pathfind)")
    agent.add_argument("--gcs", action="append", default=[], metavar="URL", type=options.link_url,
                       help="a ground station to send the map, path and state to directly too (repeatable)")
    agent.add_argument("--datum", type=datum_option, metavar="LAT,LON[,ALT]",
                       help="where the scene origin lies on Earth (default: the scene's hint, else ArduPilot's "
                            "simulator home)")
    agent.add_argument("--log", metavar="FILE.tlog", help="record the agent's MAVLink traffic, both ways")
    agent.add_argument("--wait", action="store_true",
                       help="wait for a ground station's MISSION_START (to component 191) before starting")
    agent.add_argument("--stay", action="store_true",
                       help="after the mission, stay on (as a companion computer does: MISSION_START flies it again); "
                            "without it the agent prints its result and exits")
    agent.add_argument("--connect-timeout", type=options.positive, default=60.0,
                       help="wall seconds to wait for the autopilot's heartbeat, home and position (default 60)")
    agent.add_argument("--duration", type=options.positive, help="stop after this many wall seconds")
    agent.add_argument("--json", action="store_true", help="print the result as one JSON object")
    agent.add_argument("--signing-key", type=_signing_key, metavar="FILE|PASSPHRASE", help=SIGNING_HELP)
    agent.add_argument("--radio-nodes", type=options.radio_nodes_option, metavar="X,Y[,Z][;...]|@FILE",
                       help="fixed radio nodes in scene metres, as the vehicle's simulator was given them (the rti "
                            "mission measures links to them)")
    agent.set_defaults(run=cmd_agent)

    from vehicle.lab.presets import PRESETS

    sweep = commands.add_parser("sweep", help="run many headless missions over a grid of settings")
    sweep.add_argument("--preset", choices=list(PRESETS),
                       help="; ".join(f"{name}: {p['help']}" for name, p in PRESETS.items()))
    sweep.add_argument("--missions", help="comma-separated missions (default: the preset's, or all)")
    sweep.add_argument("--scene", action="append", metavar="FILE[@X,Y]",
                       help="a scene, with an optional start (repeatable; default: the preset's)")
    sweep.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2",
                       help="values of a setting to sweep (repeatable; added to the preset's)")
    sweep.add_argument("--seeds", type=options.whole(1), default=1, help="seeds per combination (default 1)")
    sweep.add_argument("--vehicle", default="copter", choices=["rover", "copter"])
    sweep.add_argument("--vehicles", type=_team_sizes, metavar="N,N,...",
                       help="team sizes to sweep (1 to 8; default 1): a team flies in one world, as experiment "
                            "--vehicles N")
    sweep.add_argument("--targets", action="append", metavar="X,Y[;X,Y...]",
                       help="radio tomography targets to sweep, one set per --targets (repeatable): the runs "
                            "measure radio links and report what the image found (vehicle.lab.tomograph)")
    sweep.add_argument("--workers", type=options.whole(1), help="local worker processes (default: one per core)")
    sweep.add_argument("--dask", metavar="tcp://HOST:PORT", help="run on this Dask scheduler instead")
    sweep.add_argument("--out", default="sweep-results", help="output folder (default: %(default)s)")
    sweep.set_defaults(run=cmd_sweep)

    args = parser.parse_args(options.glue_negative_points(sys.argv[1:] if argv is None else argv))
    from vehicle.agent.settings import SettingsError
    from vehicle.protocol.waypoints import WaypointError
    from vehicle.sim.simulation import PlacementError
    from vehicle.world.scene import SceneError

    try:
        return args.run(args)
    except (SceneError, SettingsError, WaypointError, PlacementError, OSError, ValueError) as error:
        print(f"vehicle {args.command}: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback
        print(f"vehicle {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
