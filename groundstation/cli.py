"""``groundstation``: serve the ground station, run the demo, or replay a recording."""

from __future__ import annotations

import argparse
import atexit
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from vehicle import __version__, options
from vehicle.protocol.geodesy import datum_option
from vehicle.world.bundled import default_scene

DEFAULT_SCENE = default_scene()
DEFAULT_LINK = "udpin:127.0.0.1:14550"
TEAM_PORT_STEP = 10  # vehicle sim --vehicles N's default --port-step
DEMO_SPOTS = [(0.0, 0.0), (-4.0, -4.0), (4.0, -3.0), (-3.0, 4.0), (6.0, 6.0), (-7.0, 1.0), (1.0, -7.0), (8.0, -1.0)]


def _signing_key(value: str) -> bytes:
    from vehicle.protocol.signing import key_option  # pymavlink loads only when the option is given

    return key_option(value)


def _signing_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--signing-key", type=_signing_key, metavar="FILE|PASSPHRASE",
                        help="MAVLink 2 signing key: a file (32 bytes, or one line of 64 hex digits or of base64) "
                             "or a passphrase (its SHA-256 is the key, as QGroundControl and MAVProxy make one); "
                             "the station signs what it sends and shows which vehicles sign")
    parser.add_argument("--require-signing", action="store_true",
                        help="drop every message not signed with --signing-key: unsigned vehicles are not shown")


def _server_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default %(default)s)")
    parser.add_argument("--port", type=options.port, default=8000, help="port of the web app (default %(default)s)")
    parser.add_argument("--token", help="operator token (default: a new random one, printed at start)")
    parser.add_argument("--record-dir", default="recordings", help="where session recordings go (default "
                        "%(default)s; '' to not record)")
    parser.add_argument("--record-max-mb", type=options.whole(1), default=256, metavar="MB",
                        help="a recording this large is closed and the next begun (default %(default)s)")
    parser.add_argument("--record-max-minutes", type=options.positive, default=60.0, metavar="MIN",
                        help="likewise, a recording this long (default %(default)s)")
    parser.add_argument("--record-min-free-mb", type=options.whole(0), default=1000, metavar="MB",
                        help="no recording is begun while the disk has less free (default %(default)s)")
    parser.add_argument("--stranger-messages", type=options.whole(0), default=100, metavar="N",
                        help="messages a minute recorded from each sender that is not one of the vehicles "
                             "(default %(default)s)")
    parser.add_argument("--viewer-token", help="a read-only token for watching, needed (with the operator token "
                        "as the alternative) only when serving beyond loopback")
    parser.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                        help="a host name the page may be opened under, repeatable (IP addresses and localhost "
                             "always work; names guard against DNS rebinding)")
    parser.add_argument("--tls-cert", help="certificate file for HTTPS")
    parser.add_argument("--tls-key", help="private key file for HTTPS")
    parser.add_argument("--scene-dir", action="append", default=[], metavar="DIR",
                        help="a folder where replays look for the scene a recording names, repeatable (besides "
                             "the bundled scenes and the recording's own folder)")
    parser.add_argument("--datum", type=datum_option, metavar="LAT,LON[,ALT]",
                        help="where the scene origin lies on Earth (default: the scene's datum hint, else "
                             "ArduPilot's simulator home; without a scene, the first vehicle's home)")


def _station(args, urls: list[str], scene_path: str | None):
    from groundstation.recorder import Limits
    from groundstation.server import GroundStation
    from vehicle.world.scene import load_scene

    if args.require_signing and args.signing_key is None:
        raise ValueError("--require-signing needs --signing-key")
    scene = load_scene(scene_path) if scene_path else None
    return GroundStation(urls, scene, args.token, args.record_dir or None, datum=args.datum,
                         scene_dirs=args.scene_dir, signing_key=args.signing_key,
                         require_signing=args.require_signing,
                         record_limits=Limits(args.record_max_mb * 10**6, args.record_max_minutes * 60.0,
                                              args.record_min_free_mb * 10**6, args.stranger_messages))


def cmd_serve(args: argparse.Namespace) -> int:

    station = _station(args, args.mavlink or [DEFAULT_LINK], args.scene)
    _serve(station, args)
    return 0


def _serve(station, args) -> None:
    from groundstation.server import serve

    serve(station, args.host, args.port, args.tls_cert, args.tls_key, viewer_token=args.viewer_token,
          allowed_hosts=tuple(args.allowed_host))


def demo_starts(count: int) -> list[tuple[float, float]]:
    """Start positions a few metres apart in the default scene's open middle."""
    return DEMO_SPOTS[:count]


def cmd_demo(args: argparse.Namespace) -> int:
    """The station and, per vehicle, the two processes a user deploys: a flight controller (our simulator as a
    plain autopilot, in the scene) and the onboard agent beside it, speaking MAVLink as a companion computer."""

    from vehicle.cli import team_kind

    port = args.mavlink_port or _demo_port()
    station = _station(args, [f"udpin:127.0.0.1:{port}"], args.scene)
    if args.targets:  # the simulation's targets, ground truth on the page's radio tomography layer
        from groundstation.api.rti import imager_for

        imager_for(station).targets = [[x, y] for x, y in args.targets]
    vehicle = [sys.executable, "-m", "vehicle.cli"]
    datum = [f"--datum={args.datum.lat},{args.datum.lon},{args.datum.alt}"] if args.datum is not None else []
    common = [*datum, *_key_for_children(args.signing_key)]  # what both vehicle processes are told
    nodes = [f"--radio-nodes={';'.join(','.join(f'{v:g}' for v in p) for p in args.radio_nodes)}"] \
        if args.radio_nodes else []
    radio = [*nodes, *(f"--radio={text}" for text in args.radio_settings)]  # the world's radios
    if args.targets:
        radio.append(f"--targets={';'.join(f'{x:g},{y:g}' for x, y in args.targets)}")
    if args.mission == "rti" and not radio:  # the flight controllers' world carries radios when told of any
        radio.append("--radio=channel=11")
    output = subprocess.DEVNULL if args.quiet else None
    processes, roles = [], []
    if args.vehicles == 1 and args.vehicle != "mixed":  # a lone vehicle: its own flight controller process
        x, y = demo_starts(1)[0]
        agent_port = _free_udp_port()
        processes.append(_child([*vehicle, "sim", "--role", "autopilot", "--scene", args.scene, "--vehicle",
                                 args.vehicle, f"--start={x},{y}", "--sysid", "1", "--speedup", str(args.speedup),
                                 "--mavlink", f"udpout:127.0.0.1:{port}", "--mavlink",
                                 f"udpout:127.0.0.1:{agent_port}", *common, *radio], output))
        agent_ports, roles = [agent_port], ["vehicle 1's flight controller"]
    else:  # a team: one world serving every flight controller, vehicle k's agent on the base port + 10 k
        agent_base = _free_udp_ports_apart(args.vehicles)
        starts = [f"--start={x},{y}" for x, y in demo_starts(args.vehicles)]
        processes.append(_child([*vehicle, "sim", "--role", "autopilot", "--scene", args.scene, "--vehicle",
                                 args.vehicle, "--vehicles", str(args.vehicles), *starts, "--speedup",
                                 str(args.speedup), "--team-link", f"udpout:127.0.0.1:{port}", "--mavlink",
                                 f"udpout:127.0.0.1:{agent_base}", *common, *radio], output))
        agent_ports = [agent_base + TEAM_PORT_STEP * k for k in range(args.vehicles)]
        roles = ["the team's world (every vehicle's flight controller)"]
    for index, agent_port in enumerate(agent_ports):
        processes.append(_child([*vehicle, "agent", "--connect", f"udpin:127.0.0.1:{agent_port}", "--mission",
                                 args.mission, "--vehicle", team_kind(args.vehicle, index), "--scene", args.scene,
                                 "--stay", *common, *nodes], output))
        roles.append(f"vehicle {index + 1}'s onboard agent")
    stopping = threading.Event()
    died: list[str] = []

    def watch(process: subprocess.Popen, role: str) -> None:
        """A vehicle process that ends while the demo runs ends the demo, saying so: a station showing a vehicle
        without its agent (a bad --mission), or no vehicle at all, would look like a demo that works."""
        code = process.wait()
        if not stopping.is_set():
            died.append(role)
            print(f"demo: {role} exited with code {code}; stopping", file=sys.stderr, flush=True)
            os.kill(os.getpid(), signal.SIGTERM)

    for process, role in zip(processes, roles, strict=True):
        threading.Thread(target=watch, args=(process, role), daemon=True).start()
    station.expect_vehicles()

    def stop_vehicles() -> None:
        stopping.set()
        for process in processes:
            process.terminate()
        for process in processes:
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                process.kill()

    atexit.register(stop_vehicles)
    for number in (signal.SIGTERM, signal.SIGHUP):  # as Ctrl-C does: the vehicles go down with the station
        signal.signal(number, _exit_quietly)
    world = "" if args.vehicles == 1 else ", all in one world"
    print(f"demo: {args.vehicles} simulated {args.vehicle}(s) in {Path(args.scene).name}, each a flight controller "
          f"and an onboard agent flying '{args.mission}'{world}", flush=True)
    try:
        _serve(station, args)
    except SystemExit:
        if not died:
            raise
    finally:
        stop_vehicles()
    return 1 if died else 0


def _key_for_children(key: bytes | None) -> list[str]:
    """The vehicles' --signing-key: the station's key in a file only this user reads (a passphrase on their
    command lines would show in every process list), removed when the station exits."""
    if key is None:
        return []
    handle, path = tempfile.mkstemp(prefix="scanstation-key-")  # created 0600
    with os.fdopen(handle, "w") as file:
        file.write(key.hex() + "\n")
    atexit.register(lambda: Path(path).unlink(missing_ok=True))
    return ["--signing-key", path]


def _demo_port() -> int:
    """MAVLink's ground-station port, 14550, unless another program listens there (QGroundControl, say): then
    any free one, since only this station listens to the demo's vehicles."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 14550))
        return 14550
    except OSError:
        port = _free_udp_port()
        print(f"demo: UDP port 14550 is taken (another ground station?); the vehicles send to {port}", flush=True)
        return port


def _free_udp_ports_apart(count: int) -> int:
    """A UDP port P with P + 10 k free for every k below ``count`` (the team's agents' ports)."""
    for _ in range(100):
        base = _free_udp_port()
        if base + TEAM_PORT_STEP * count > 65535:
            continue
        probes = []
        try:
            for k in range(1, count):
                probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                probes.append(probe)
                probe.bind(("127.0.0.1", base + TEAM_PORT_STEP * k))
            return base
        except OSError:
            continue
        finally:
            for probe in probes:
                probe.close()
    raise OSError(f"no {count} free UDP ports {TEAM_PORT_STEP} apart for the team's agents")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _child(command: list[str], output) -> subprocess.Popen:
    """A process that dies with the station, even when the station is killed outright (Linux's parent-death
    signal; elsewhere the station's exit handlers stop it). In its own session: a terminal's Ctrl-C reaches the
    station alone, which stops its vehicles itself (else they died beside it, as if they had failed)."""
    return subprocess.Popen(command, stdout=output, preexec_fn=_die_with_parent, start_new_session=True)


def _die_with_parent() -> None:
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _exit_quietly(number, frame) -> None:
    raise SystemExit(0)


def cmd_replay(args: argparse.Namespace) -> int:
    from groundstation.replay import index_tlog
    from groundstation.server import GroundStation
    from vehicle.world.scene import load_scene

    path = Path(args.file).resolve()
    index = index_tlog(path)  # a clear error now, before anything starts, if it is no log
    if index.warning:
        print(f"warning: {index.warning}", file=sys.stderr)
    scene = load_scene(args.scene) if args.scene else None
    station = GroundStation([], scene, args.token, record_dir=path.parent, datum=args.datum,
                            scene_dirs=args.scene_dir)
    replay = station.replays.start(path)
    print(f"replaying {path.name}: {len(index)} messages, {index.duration:.1f} s; scene: {replay.scene['note']}",
          flush=True)
    _serve(station, args)
    return 0


def _bounds(text: str) -> tuple[float, float, float, float]:
    parts = text.split(",")
    values = [options.finite(part) for part in parts] if len(parts) == 4 else None
    if values is None:
        raise argparse.ArgumentTypeError(f"expected X0,Y0,X1,Y1 in metres, not {text!r}")
    return tuple(values)


def cmd_rti_reconstruct(args: argparse.Namespace) -> int:
    """A thin face over vehicle.tomography: read, image, write the JSON (and the picture)."""
    import json

    from vehicle.tomography.imaging import reconstruct
    from vehicle.tomography.links import read_links
    from vehicle.tomography.picture import draw

    records = read_links(args.links)
    calibration = read_links(args.calibration) if args.calibration else None
    for source in (records, calibration):
        for warning in source.warnings() if source else ():
            print(f"warning: {warning}", file=sys.stderr)
    result = reconstruct(records, calibration, args.calibration_seconds, args.bounds, args.cell, args.window,
                         args.peaks, args.solver, args.model, span=args.smooth, measure=args.measure,
                         variance=args.variance, reference=args.reference, prior=args.prior,
                         empty_from=args.empty_from)
    Path(args.json).write_text(json.dumps(result.to_json(images=args.images)) + "\n", encoding="utf-8")
    if args.png:
        draw(result, args.png)
    peaks = sum(bool(frame["peaks"]) for frame in result.frames)
    print(f"rti: {len(result.frames)} frame(s) of {result.grid.nx} x {result.grid.ny} cells of {result.grid.cell:g} m, "
          f"{peaks} with a peak; {result.info['links']['paths']} paths, "
          f"{result.info['links']['drifted_paths']} drifted -> {args.json}", flush=True)
    return 0


def cmd_rti_export(args: argparse.Namespace) -> int:
    """A recording's link records as LINKS.csv, read as the station reads them."""
    from groundstation.links_export import export_links
    from groundstation.replay import index_tlog
    from vehicle.world.scene import load_scene

    index = index_tlog(args.file)  # a clear error now if it is no log
    if index.warning:
        print(f"warning: {index.warning}", file=sys.stderr)
    scene = load_scene(args.scene) if args.scene else None
    count, frame = export_links(args.file, args.csv, scene, args.datum)
    print(f"rti: {count} link records -> {args.csv} (positions in metres, frame: {frame})", flush=True)
    return 0 if count else 1


def _rti_commands(commands) -> None:
    rti = commands.add_parser("rti", help="radio tomographic imaging from link signal strengths")
    actions = rti.add_subparsers(dest="action", required=True)
    rec = actions.add_parser("reconstruct", help="images of what stands in the area, from a LINKS.csv[.gz]",
                             description="Attenuation images from link records (t,tx,rx,tx_x,tx_y,rx_x,rx_y,rssi,"
                                         "channel); see docs/rti.md.")
    rec.add_argument("links", help="link records, CSV or gzipped CSV")
    calibration = rec.add_mutually_exclusive_group()
    calibration.add_argument("--calibration", metavar="EMPTY.csv", help="records measured with the area empty")
    calibration.add_argument("--calibration-seconds", type=options.positive, metavar="S",
                             help="take the first S seconds of LINKS as the empty area (default: estimate each "
                                  "link's empty level from the whole file)")
    rec.add_argument("--bounds", type=_bounds, metavar="X0,Y0,X1,Y1",
                     help="the imaged area in metres (default: the radios' bounding box)")
    rec.add_argument("--cell", type=options.positive, metavar="M",
                     help="pixel side in metres (default: about 50 pixels along the longer side, at least 0.1)")
    rec.add_argument("--window", type=options.positive, metavar="S",
                     help="one image per window of S seconds (default: one image of the whole file)")
    rec.add_argument("--peaks", type=options.whole(0), default=3, metavar="K",
                     help="at most K peaks per image, strongest first (default %(default)s)")
    rec.add_argument("--smooth", type=options.whole(1), default=3, metavar="N",
                     help="average each window's measurements with its neighbours', N windows in all "
                          "(default %(default)s; 1 = none)")
    rec.add_argument("--measure", choices=["kernel", "mean", "variance"], default="kernel",
                     help="per link and window: the kernel distance of its RSS histogram from the long-term one "
                          "(KRTI), the mean attenuation in dB, or the variance of its RSS (VRTI, moving people "
                          "only) (default %(default)s)")
    rec.add_argument("--reference", choices=["auto", "file", "empty"], default="auto",
                     help="with --measure kernel, the long-term histogram: the whole file's, or the empty area's "
                          "(sees a person who stands still all along); auto: the file's with --window, else the "
                          "empty area's (default %(default)s)")
    rec.add_argument("--variance", choices=["sub-mean", "plain"], default="sub-mean",
                     help="with --measure variance, take off each link's empty-room variance, or not "
                          "(default %(default)s)")
    rec.add_argument("--prior", choices=["exponential", "difference"], default="exponential",
                     help="the image prior: exponential covariance, or the Tikhonov gradient penalty of VRTI "
                          "(default %(default)s)")
    rec.add_argument("--solver", choices=["ls", "tv", "sparse"], default="ls",
                     help="regularised least squares with a spatial prior, total variation, or the sparse "
                          "non-negative solve for a few people standing still (default %(default)s)")
    rec.add_argument("--model", choices=["ellipse", "exponential", "line"], default="ellipse",
                     help="weight model: the ellipse of excess path length, its exponential fade, or a Gaussian "
                          "of the distance from the link's line (default %(default)s)")
    rec.add_argument("--empty-from", choices=["data", "model", "brief"], default="data",
                     help="without a calibration, each link's empty-area level: its own robust level over the "
                          "file, a path-loss model fitted across the links, or the model's for links heard only "
                          "briefly (radios on vehicles; the station's live image) (default %(default)s)")
    rec.add_argument("--json", required=True, metavar="OUT.json", help="where the frames go")
    rec.add_argument("--images", action="store_true", help="put each frame's image (rows of values) in the JSON")
    rec.add_argument("--png", metavar="OUT.png", help="draw the image (the mean of the frames) with the radios")
    rec.set_defaults(run=cmd_rti_reconstruct)
    export = actions.add_parser("export", help="a recording's radio link records as LINKS.csv",
                                description="The link records the vehicles' agents sent (TUNNEL RADIO_LINKS) in a "
                                            "recording, as LINKS.csv for rti reconstruct; see docs/rti.md.")
    export.add_argument("file", metavar="FILE.tlog", help="a recording (the station's, or a vehicle's --log)")
    export.add_argument("--csv", required=True, metavar="LINKS.csv", help="where the records go")
    export.add_argument("--scene", help="the scene whose frame the positions are in (default: the one the "
                                        "recording names, if found among the bundled scenes)")
    export.add_argument("--datum", type=datum_option, metavar="LAT,LON[,ALT]",
                        help="where the scene origin lies on Earth (default: the scene's)")
    export.set_defaults(run=cmd_rti_export)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="groundstation", description="Web ground station with a live 3D view.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    serve = commands.add_parser("serve", help="serve the ground station for vehicles on MAVLink links")
    serve.add_argument("--mavlink", action="append", metavar="URL", type=options.link_url,
                       help=f"pymavlink connection string, repeatable (default {DEFAULT_LINK})")
    serve.add_argument("--scene", help="VRML scene to show (default: none, vehicles over a ground grid)")
    _server_options(serve)
    _signing_options(serve)
    serve.set_defaults(run=cmd_serve)

    demo = commands.add_parser("demo", help="the ground station and simulated vehicles flying a mission")
    demo.add_argument("--scene", default=str(DEFAULT_SCENE), help="VRML scene (default: the demo scene)")
    demo.add_argument("--mission", default="search", help="mission the vehicles fly (default %(default)s)")
    demo.add_argument("--vehicles", type=options.whole(1, len(DEMO_SPOTS)), default=1,
                      help=f"how many, 1 to {len(DEMO_SPOTS)} (default %(default)s)")
    demo.add_argument("--vehicle", default="copter", choices=["copter", "rover", "mixed"],
                      help="what flies (default %(default)s); mixed: copters and rovers in turn, the first a copter; "
                           "two or more fly in one world, where each sees and keeps clear of the others")
    demo.add_argument("--speedup", type=options.positive, default=1.0, help="simulation speed-up (default %(default)s)")
    demo.add_argument("--mavlink-port", type=options.port,
                      help="UDP port the vehicles send to (default 14550, or a free one if that is taken)")
    demo.add_argument("--quiet", action="store_true", help="hide the vehicles' own output")
    options.add_radio_options(demo)
    _server_options(demo)
    _signing_options(demo)
    demo.set_defaults(run=cmd_demo)

    replay = commands.add_parser("replay", help="replay a recorded .tlog in the page")
    replay.add_argument("file", help="a telemetry log (.tlog): recorded here, by vehicle experiment --log, "
                        "or by any MAVLink tool")
    replay.add_argument("--scene", help="VRML scene to show it in when the recording names none, or names "
                        "this file (default: the scene the recording names, looked up by name and hash)")
    _server_options(replay)
    replay.set_defaults(run=cmd_replay)
    _rti_commands(commands)

    args = parser.parse_args(options.glue_negative_points(sys.argv[1:] if argv is None else argv))
    from groundstation.replay import ReplayError
    from vehicle.world.scene import SceneError

    try:
        return args.run(args)
    except (SceneError, ReplayError, OSError, ValueError) as error:
        print(f"groundstation {args.command}: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":
    sys.exit(main())
