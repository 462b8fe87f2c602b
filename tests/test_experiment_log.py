"""``vehicle experiment --log FILE.tlog`` (vehicle.lab.log): a standard telemetry log on simulated time.

One pathfind run in a small scene is logged twice (and its final map saved with
``--map-out``); the log is read back with pymavlink's own ``mavlink_connection``.
The autopilot's messages come from component 1, the agent's from component 191;
the note naming the scene from the ground station's system id and the logging
component.
"""

import hashlib
import json
import os
import signal
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest
from harness import wait_wall

from vehicle.cli import main
from vehicle.protocol import agent_status
from vehicle.protocol.mapstream import MapReceiver
from vehicle.protocol.mav import mavlink, mavutil
from vehicle.protocol.tlog import LOG_EPOCH

SCENE = """#VRML V2.0 utf8
WorldInfo { info ["space_size=20" "waypoints=-3,6; 3,6"] }
Transform { translation 0 0 -0.05 children Shape { geometry Box { size 80 80 0.1 } } }
Transform { translation 0 4 2 children Shape { geometry Box { size 4 0.2 6 } } }
Transform { translation -7 -3 2 children Shape { geometry Box { size 2 2 6 } } }
"""
FULL = "/dev/full"  # every write to it fails: No space left on device
needs_a_full_disk = pytest.mark.skipif(not (sys.platform.startswith("linux") and os.path.exists(FULL)),
                                       reason="a full disk is Linux's /dev/full, not on this system")


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """A folder with the scene, two logs of the same run (a.tlog, b.tlog) and the first run's maps/."""
    folder = tmp_path_factory.mktemp("log")
    scene = folder / "yard.wrl"
    scene.write_text(SCENE)
    for name, extra in (("a", ["--map-out", str(folder / "maps")]), ("b", [])):
        code = main(["experiment", "--scene", str(scene), "--mission", "pathfind", "--time-limit", "150", "--json",
                     "--log", str(folder / f"{name}.tlog"), *extra])
        assert code == 0
    return folder


@pytest.fixture(scope="module")
def messages(logged):
    """Message type (the agent's: "TYPE@191") -> list of (timestamp, message), in log order."""
    reader = mavutil.mavlink_connection(str(logged / "a.tlog"))
    by_type = defaultdict(list)
    order = []
    while (message := reader.recv_match()) is not None:
        if message.get_type() == "BAD_DATA":
            pytest.fail(f"undecodable data in the log: {message}")
        component = message.get_srcComponent()
        assert (message.get_srcSystem(), component) in ((1, 1), (1, 191), (255, mavlink.MAV_COMP_ID_LOG))
        key = message.get_type() if component == 1 else f"{message.get_type()}@{component}"
        by_type[key].append((message._timestamp, message))
        order.append(message._timestamp)
    reader.close()
    by_type["_order"] = order
    return by_type


def intervals(entries):
    stamps = np.array([t for t, _ in entries])
    return np.diff(stamps)


def test_the_log_reads_back_and_starts_at_the_log_epoch(messages):
    order = messages["_order"]
    assert len(order) > 1000
    assert order[0] == pytest.approx(LOG_EPOCH, abs=0.5)  # 2026-01-01T00:00:00Z plus simulated time
    assert all(b >= a for a, b in zip(order, order[1:], strict=False))  # never back in time


def test_heartbeats_come_at_1_hz_of_simulated_time(messages):
    beats = messages["HEARTBEAT"]
    assert len(beats) >= 20
    gaps = intervals(beats[:-1])  # the last one is the closing heartbeat
    assert np.median(gaps) == pytest.approx(1.0, abs=0.01)
    assert gaps.min() >= 0.9 and gaps.max() <= 1.1
    _, first = beats[0]
    assert first.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert first.type == mavlink.MAV_TYPE_QUADROTOR
    assert first.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert any(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED for _, m in beats)  # it flew
    assert any(m.custom_mode == 4 for _, m in beats)  # GUIDED


def test_positions_come_at_20_hz_with_boot_times_on_the_same_clock(messages):
    positions = messages["GLOBAL_POSITION_INT"]
    span = positions[-2][0] - positions[0][0]
    assert (len(positions) - 2) / span == pytest.approx(20, rel=0.05)
    assert np.median(intervals(positions)) == pytest.approx(0.05, abs=0.002)
    for stamp, message in positions[::50]:
        assert message.time_boot_ms / 1000 == pytest.approx(stamp - LOG_EPOCH, abs=0.002)
    heights = [m.relative_alt / 1000 for _, m in positions]
    assert max(heights) == pytest.approx(4.0, abs=0.3)  # flown at the default altitude


def test_distance_sensor_readings_are_logged(messages):
    readings = messages["DISTANCE_SENSOR"]
    assert len(readings) > 100
    assert {m.type for _, m in readings} == {mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND}
    # the default suite's three level sonars and a copter's overhead one (pitched: a custom orientation)
    assert {m.orientation for _, m in readings} == {0, 1, 7, mavlink.MAV_SENSOR_ROTATION_CUSTOM}
    assert any(m.current_distance <= m.max_distance for _, m in readings)  # echoes
    assert all(m.current_distance <= m.max_distance + 1 for _, m in readings)


def test_the_agent_is_component_191_with_its_own_heartbeat_and_state(messages):
    beats = messages["HEARTBEAT@191"]
    assert len(beats) >= 20
    assert {m.type for _, m in beats} == {mavlink.MAV_TYPE_ONBOARD_CONTROLLER}
    assert np.median(intervals(beats[:-1])) == pytest.approx(1.0, abs=0.01)
    states = [agent_status.decode(bytes(m.payload[:m.payload_length])) for _, m in messages["TUNNEL@191"]
              if m.payload_type == agent_status.AGENT_STATUS]
    assert states[0].phase in ("preflight", "takeoff") and states[0].mission == "pathfind"
    assert states[-1] == agent_status.AgentStatus("done", False, "finished", "pathfind", "mission complete")
    assert not messages["TUNNEL"]  # the map is the agent's, not the autopilot's
    texts = [m.text for _, m in messages["STATUSTEXT@191"]]
    assert "Mission pathfind: start" in texts


def test_tunnel_payloads_rebuild_exactly_the_final_map(logged, messages):
    tunnels = messages["TUNNEL@191"]
    assert tunnels
    receiver = MapReceiver()
    for _, message in tunnels:
        assert message.payload_length <= 128
        receiver.feed(message.payload_type, bytes(message.payload[:message.payload_length]))
    final = np.load(next((logged / "maps").glob("*.npy")))
    assert receiver.synced
    assert receiver.gaps == 0
    assert np.count_nonzero(final) > 0
    assert np.array_equal(receiver.grid, final)


def test_the_planned_path_is_in_the_log(messages):
    receiver = MapReceiver()
    paths = []
    for _, message in messages["TUNNEL@191"]:
        before = receiver.path
        receiver.feed(message.payload_type, bytes(message.payload[:message.payload_length]))
        if receiver.path is not before and receiver.path:
            paths.append(receiver.path)
    assert paths
    ends = {tuple(round(v) for v in path[-1]) for path in paths}
    assert (-3, 6) in ends and (3, 6) in ends  # the waypoints, metres from home


def test_two_logs_of_the_same_run_are_byte_identical(logged):
    a, b = (logged / "a.tlog").read_bytes(), (logged / "b.tlog").read_bytes()
    assert len(a) > 10000
    assert a == b


def test_the_log_ends_on_the_final_state(messages):
    last_beat = messages["HEARTBEAT"][-1][1]
    assert not last_beat.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED  # landed and disarmed
    last_position = messages["GLOBAL_POSITION_INT"][-1][1]
    assert last_position.relative_alt < 500  # mm: on the ground


def test_cli_log_summary_mentions_the_log(tmp_path, capsys):
    scene = tmp_path / "yard.wrl"
    scene.write_text(SCENE)
    log = tmp_path / "deep" / "run.tlog"
    code = main(["experiment", "--scene", str(scene), "--mission", "browse", "--time-limit", "150", "--log",
                 str(log)])
    out = capsys.readouterr().out
    assert code == 0
    assert f"log written to {log}" in out
    assert log.stat().st_size > 0


def _first_home(log):
    reader = mavutil.mavlink_connection(str(log))
    home = reader.recv_match(type="HOME_POSITION")
    reader.close()
    return home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000


@pytest.mark.parametrize(("hint", "option", "expected"), [
    ("", [], (-35.363261, 149.165230, 584.0)),  # ArduPilot's simulator home
    ('WorldInfo { info ["datum=47.3769,8.5417,408"] }\n', [], (47.3769, 8.5417, 408.0)),  # the scene's
    ('WorldInfo { info ["datum=47.3769,8.5417,408"] }\n', ["--datum=51.5,-0.12,11"], (51.5, -0.12, 11.0)),
])
def test_the_datum_places_the_scene_on_earth(tmp_path, hint, option, expected):
    scene = tmp_path / "open.wrl"
    scene.write_text("#VRML V2.0 utf8\n" + hint
                     + "Transform { translation 0 0 -0.05 children Shape { geometry Box { size 80 80 0.1 } } }\n")
    log = tmp_path / "run.tlog"
    code = main(["experiment", "--scene", str(scene), "--mission", "browse", "--time-limit", "30", "--log", str(log),
                 *option])
    assert code == 0
    assert _first_home(log) == pytest.approx(expected, abs=1e-6)  # home is the scene origin, on the ground


def test_a_bad_datum_exits_2_with_the_reason(tmp_path, capsys):
    scene = tmp_path / "open.wrl"
    scene.write_text(SCENE)
    with pytest.raises(SystemExit) as exit_:
        main(["experiment", "--scene", str(scene), "--mission", "browse", "--datum=north,east"])
    assert exit_.value.code == 2
    assert "LAT,LON[,ALT]" in capsys.readouterr().err
    scene.write_text('#VRML V2.0 utf8\nWorldInfo { info ["datum=95,0"] }\n')
    assert main(["experiment", "--scene", str(scene), "--mission", "browse"]) == 2
    assert "the scene's datum hint" in capsys.readouterr().err


def test_positions_hud_and_readings_carry_the_values_telemetry_builds(tmp_path):
    """The log notes these as numbers and makes their payloads in batches: each must be the very payload
    ``Telemetry``'s builders give at that step (byte for byte, pymavlink's packing)."""
    from vehicle.lab.experiment import Experiment, run_experiment
    from vehicle.lab.log import ExperimentLog
    from vehicle.sim.telemetry import Telemetry
    from vehicle.world.scene import parse_scene

    scene = parse_scene(SCENE, "yard.wrl")
    log = ExperimentLog(tmp_path / "run.tlog")
    packer = mavlink.MAVLink(None)
    expected = {}

    def on_step(stepper, readings):
        log(stepper, readings)
        telemetry = Telemetry(stepper.simulation)
        now = stepper.simulation.time
        stamp = int((LOG_EPOCH + now) * 1e6)
        for message in (telemetry.global_position(now), telemetry.local_position(now), telemetry.attitude(now),
                        telemetry.vfr_hud(now), *[telemetry.distance_sensor(r, now) for r in readings]):
            sensor = message.id if message.get_type() == "DISTANCE_SENSOR" else None
            expected[(message.get_type(), stamp, sensor)] = message.pack(packer)[10:-2]

    run_experiment(Experiment("yard.wrl", "pathfind", waypoints=[(-3.0, 6.0), (3.0, 6.0)]), scene=scene,
                   on_step=on_step)
    log.close()
    reader = mavutil.mavlink_connection(str(tmp_path / "run.tlog"))
    checked = {}
    while (message := reader.recv_match(type=["GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD",
                                              "DISTANCE_SENSOR"])) is not None:
        kind = message.get_type()
        stamp = round(message._timestamp * 1e6)
        if kind == "GLOBAL_POSITION_INT" and stamp not in {k[1] for k in expected}:
            continue  # the closing position, after the last step
        key = (kind, stamp, message.id if kind == "DISTANCE_SENSOR" else None)
        assert message.get_msgbuf()[10:-2] == expected[key], key
        checked[kind] = checked.get(kind, 0) + 1
    reader.close()
    assert checked["GLOBAL_POSITION_INT"] > 400 and checked["VFR_HUD"] > 90 and checked["DISTANCE_SENSOR"] > 600


def test_a_writer_in_the_same_process_writes_the_same_log(logged, monkeypatch, tmp_path):
    """Where no process can be forked, the log is written in the run's own process: byte for byte the same."""
    from vehicle.lab import log

    monkeypatch.setattr(log.multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    code = main(["experiment", "--scene", str(logged / "yard.wrl"), "--mission", "pathfind", "--time-limit", "150",
                 "--json", "--log", str(tmp_path / "same.tlog")])
    assert code == 0
    assert (tmp_path / "same.tlog").read_bytes() == (logged / "a.tlog").read_bytes()


def test_the_log_names_its_scene_at_its_start(logged, messages):
    notes = messages[f"STATUSTEXT@{mavlink.MAV_COMP_ID_LOG}"]
    digest = hashlib.sha256((logged / "yard.wrl").read_bytes()).hexdigest()[:16]
    assert notes and all(m.text == f"scene yard.wrl sha256 {digest}" for _, m in notes)
    assert notes[0][0] == pytest.approx(LOG_EPOCH, abs=0.1)  # before anything else that happened


def test_ctrl_c_ends_a_logged_run_with_one_line_and_a_whole_log(tmp_path):
    """A terminal's Ctrl-C reaches the whole process group, the log's forked writer too: it printed a
    traceback, and the run 'Connection reset by peer' with exit code 2 and a log cut anywhere. Now the writer
    leaves Ctrl-C to the run, which closes the log: what was flown so far is in it, every message whole."""
    log = tmp_path / "run.tlog"
    run = subprocess.Popen([sys.executable, "-m", "vehicle.cli", "experiment", "--mission", "pathfind",
                            "--set", "speed=0.1", "--set", "time_limit=86400", "--log", str(log)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:  # a slow flight of a day's simulated time: the writer has written for a while when Ctrl-C comes
        wait_wall(lambda: log.exists() and log.stat().st_size > 1_000_000, 120, "the log growing")
        os.killpg(run.pid, signal.SIGINT)
        out, err = run.communicate(timeout=60)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == 130, (err, out)
    assert err.strip() == "vehicle experiment: interrupted"
    connection = mavutil.mavlink_connection(str(log))
    kinds = defaultdict(int)
    while (message := connection.recv_match()) is not None:
        kinds[message.get_type()] += 1
    assert kinds["GLOBAL_POSITION_INT"] > 100 and kinds["DISTANCE_SENSOR"] > 100 and not kinds["BAD_DATA"], kinds


@needs_a_full_disk
def test_a_full_disk_loses_the_log_not_the_run(tmp_path):
    """A write error killed the log's forked writer, then the thread sending it batches (two tracebacks); the
    run queued batches for no one and ended on 'Connection reset by peer', exit code 2, its result lost. Now the
    run's result is printed, the log's error said once, in one line, and the exit code is 2 (an OS error)."""
    scene = tmp_path / "yard.wrl"
    scene.write_text(SCENE)
    done = subprocess.run([sys.executable, "-m", "vehicle.cli", "experiment", "--scene", str(scene), "--mission",
                           "pathfind", "--time-limit", "150", "--json", "--log", FULL],
                          capture_output=True, text=True, timeout=240)
    assert done.stderr == f"vehicle experiment: log {FULL}: No space left on device\n"
    assert done.returncode == 2
    result = json.loads(done.stdout)
    assert result["outcome"] == "finished" and result["detections"] > 0


@needs_a_full_disk
def test_a_full_disk_loses_the_log_not_the_run_without_fork(monkeypatch, capfd, tmp_path):
    """The same where the log is written in the run's process (the write error ended the run as an 'error',
    then closing the log raised it again): the result, one line, exit code 2; and no batch once it failed."""
    from vehicle.lab import log

    monkeypatch.setattr(log.multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    failed_before = []  # at each batch given to the writer: had it failed already?

    def write(writer, batch, write=log._Writer.write):
        failed_before.append(writer.error is not None)
        write(writer, batch)

    monkeypatch.setattr(log._Writer, "write", write)
    scene = tmp_path / "yard.wrl"
    scene.write_text(SCENE)
    code = main(["experiment", "--scene", str(scene), "--mission", "pathfind", "--time-limit", "150", "--json",
                 "--log", FULL])
    out, err = capfd.readouterr()
    assert err == f"vehicle experiment: log {FULL}: No space left on device\n"
    assert code == 2
    assert json.loads(out)["outcome"] == "finished"
    assert failed_before and not any(failed_before)


@needs_a_full_disk
def test_a_failed_writer_is_sent_nothing_more(monkeypatch):
    """Once the forked writer has failed, the run's batches go nowhere: it stops handing them over (it queued
    them all for no one), soon after the first."""
    from vehicle.agent.settings import Settings
    from vehicle.lab import log as logs
    from vehicle.lab.experiment import Experiment, run_experiment
    from vehicle.sim.simulation import DEFAULT_STEP
    from vehicle.world.scene import parse_scene

    handed = []  # per batch handed over, the writer's error as the run knew it then
    write = logs._Forked.write

    def handing(writer, batch) -> None:
        handed.append(writer.error)
        write(writer, batch)

    monkeypatch.setattr(logs._Forked, "write", handing)
    log = logs.ExperimentLog(FULL)
    settings = Settings().updated({"speed": 0.1})  # a slow flight: some forty batches
    result = run_experiment(Experiment("yard.wrl", "pathfind", settings=settings, waypoints=[(-3.0, 6.0)]),
                            scene=parse_scene(SCENE, "yard.wrl"), on_step=log)
    with pytest.raises(logs.LogError) as error:
        log.close()
    assert str(error.value) == f"log {FULL}: No space left on device" and error.value.errno == 28
    assert result["outcome"] == "finished"
    batches = round(result["sim_time_s"] / DEFAULT_STEP) // logs.BATCH_STEPS  # the run's, had all been noted
    # the writer fails on its first batch; when the run hears of it depends on the machine's load, but once it
    # has, it hands over nothing more and notes no more steps
    assert batches > 20 and all(error is None for error in handed), handed
    assert log._steps <= (len(handed) + 1) * logs.BATCH_STEPS
    # left queued: close's end mark, and those handed over before the run heard (how many of them the sender had
    # already put into the pipe depends on the machine's load: 5 was once 7)
    assert log._writer.batches.qsize() <= len(handed) + 1


@pytest.mark.parametrize(("where", "reason"), [
    ("", "Is a directory"),
    ("file/run.tlog", "{folder}/file: File exists"),  # Path.mkdir's word for a folder that is a file
    ("file/deep/run.tlog", "{folder}/file/deep: Not a directory"),
], ids=["a directory", "in a file", "deep in a file"])
def test_a_log_that_cannot_be_opened_loses_nothing_but_the_log(tmp_path, capfd, where, reason):
    """Said before the run ('[Errno 21] Is a directory: ...', exit code 2, no run); now as a failed write is: the
    run's result, then the log's error in one line, exit code 2."""
    scene = tmp_path / "yard.wrl"
    scene.write_text(SCENE)
    (tmp_path / "file").write_text("")
    log = tmp_path / where
    code = main(["experiment", "--scene", str(scene), "--mission", "pathfind", "--time-limit", "150", "--json",
                 "--log", str(log)])
    out, err = capfd.readouterr()
    assert err == f"vehicle experiment: log {log}: {reason.format(folder=tmp_path)}\n"
    assert code == 2
    assert json.loads(out)["outcome"] == "finished"


@pytest.mark.parametrize("message", [
    mavlink.MAVLink_heartbeat_message(2, 3, 81, 4, 4, 3),
    mavlink.MAVLink_sys_status_message(1, 1, 1, 500, 12000, -1, 90, 0, 0, 0, 0, 0, 0),  # trailing zeros dropped
    mavlink.MAVLink_statustext_message(4, b"obstacle ahead", 7, 1),  # a string and an extension field
    mavlink.MAVLink_battery_status_message(0, 1, 3, 2500, [16600] + [65535] * 9, 1400, 120, -1, 93),
], ids=lambda message: message.get_type())
def test_a_rare_message_is_framed_in_the_log_as_pymavlink_frames_it(message):
    """The run hands the writer a message's payload only (framing one with pymavlink costs ten times as much), and
    the writer frames it: the same bytes as pymavlink's own packet."""
    from vehicle.lab.log import COMPONENTS, _frame, _payload

    expected = message.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    payload = np.frombuffer(_payload(message), dtype=np.uint8)
    one = np.zeros(1, dtype=np.int64)
    kind = type(message)  # (STATUSTEXT and BATTERY_STATUS have a field named id)
    record = _frame(payload, one, one + len(payload), one, one, one + kind.id, one + kind.crc_extra, one,
                    np.zeros(len(COMPONENTS), dtype=np.int64), 1, np.array(COMPONENTS))
    assert record[8:].tobytes() == expected  # after the record's 8-byte time stamp
