"""Replays keep their scene: recordings name it (file name and SHA-256), replay finds and checks it.

A station with the default scene records a simulated copter; a second station
with no scene at all replays that recording through the API and shows it in
the default scene (its 3D view is sent the scene's mesh, the vehicle stands
where it stood in the scene), then goes back to no scene. Crafted recordings
name a scene nobody has, a file that differs, or a path out of the folders the
station looks in: the status says so and the view loads nothing.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import re
import shutil
import struct
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
import viser
import websockets.sync.client
import zstandard
from harness import (
    RunningStation,
    WaitTimeout,
    during,
    launch_chromium,
    load_default_scene,
    needs_chromium,
    start_sim,
    wait_wall,
)
from PIL import Image

from groundstation.recorder import Recorder
from groundstation.replay import Replay
from groundstation.replay_scene import find_scene, logged_scene
from groundstation.state import Fleet
from groundstation.viz import MATTE, matte_glb
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.scene_note import NOTE_PERIOD, SceneNotes, is_scene_name, read_note
from vehicle.protocol.statustext import statustexts
from vehicle.protocol.tlog import TlogWriter
from vehicle.world.bundled import default_scene, scenes_dir
from vehicle.world.scene import load_scene

START = (4.0, -3.0)  # where the recorded copter stands in the default scene (not its origin)
DEFAULT_DIGEST = hashlib.sha256(default_scene().read_bytes()).hexdigest()[:16]


def view_nodes(port: int, wanted: str | None = None, seconds: float = 3.0) -> set[str]:
    """Names of the nodes viser sends a new client of the 3D view (until ``wanted`` came, or ``seconds``)."""
    names: set[str] = set()
    with websockets.sync.client.connect(f"ws://127.0.0.1:{port}", max_size=None,
                                        subprotocols=[f"viser-v{viser.__version__}"]) as socket:
        for _ in during(seconds):
            if wanted in names:
                break
            try:
                payload = socket.recv(timeout=0.3)
            except TimeoutError:
                continue
            size, compressed = int.from_bytes(payload[:8], "little"), int.from_bytes(payload[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(payload[16:16 + compressed], max_output_size=size)
            names |= {m["name"] for m in msgspec.msgpack.decode(inner).get("messages", ())
                      if isinstance(m, dict) and "name" in m and m.get("type") != "RemoveSceneNodeMessage"}
    return names


def notes_in(path: Path) -> list[tuple[int, int, str]]:
    """(system, component, text) of every STATUSTEXT in a tlog."""
    from vehicle.protocol.mav import mavutil

    reader = mavutil.mavlink_connection(str(path))
    found = []
    while (message := reader.recv_match(type="STATUSTEXT")) is not None:
        found.append((message.get_srcSystem(), message.get_srcComponent(), message.text))
    reader.close()
    return found


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A session recorded by a station showing the default scene: a copter standing at START for a while."""
    scene = load_default_scene()
    with RunningStation(scene, tmp_path_factory.mktemp("recorded")) as running, running.api() as api:
        with start_sim(running, scene, start=START):
            api.wait_vehicle(1, lambda v: v["position"] is not None and v["home"] is not None, what="position")
            api.wait_sim_time(1, 3.0)
        return running.station.recorder.path


@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    """A station with no scene, whose record folder gets the recordings to replay."""
    with RunningStation(None, tmp_path_factory.mktemp("bare") / "recordings") as running, running.api() as api:
        yield running, api


def copy_in(recording: Path, running) -> str:
    """Copy a recording into the station's record folder under a name of its own (the station records there
    too: a station started within the same second as the recording's names its own session the same)."""
    name = f"copied-{recording.name}"
    shutil.copy(recording, running.station.record_dir / name)
    return name


def replay(running, api, name: str) -> dict:
    started = api.post("/api/replay", json={"name": name}, headers=api.operator)
    assert started.status_code == 200, started.text
    return started.json()


def stop(api) -> None:
    assert api.post("/api/replay/stop", headers=api.operator).status_code == 200


def test_a_session_recording_names_the_stations_scene_first(recorded):
    first = Replay.open(recorded, Fleet()).decode(0)  # the very first record of the session
    assert (first.get_srcSystem(), first.get_srcComponent()) == (255, mavlink.MAV_COMP_ID_LOG)
    assert first.text == f"scene default.wrl sha256 {DEFAULT_DIGEST}"
    assert hashlib.sha256(default_scene().read_bytes()).hexdigest().startswith(DEFAULT_DIGEST)


def test_a_station_without_a_scene_replays_a_recording_in_its_scene(recorded, bare):
    running, api = bare
    name = copy_in(recorded, running)
    assert "/layers/scene/mesh" not in view_nodes(running.station.view.port, seconds=2.0)  # no scene of its own
    status = replay(running, api, name)
    try:
        assert status["scene"] == {"name": "default.wrl", "sha256": DEFAULT_DIGEST, "found": True,
                                   "shown": "default.wrl", "note": "default.wrl found in the bundled scenes"}
        assert api.get("/api/replay").json()["replay"]["scene"]["found"] is True
        assert "/layers/scene/mesh" in view_nodes(running.station.view.port, "/layers/scene/mesh")
        # the copter stands at START from its first message to the recording's end (when that first message
        # comes after the recording's start depends on how long the simulator took to start)
        end = api.get("/api/replay").json()["replay"]["duration"]
        api.post("/api/replay/control", json={"seek": end, "play": False}, headers=api.operator)
        position = api.vehicle(1)["position"]  # placed by the scene's datum, not at the first home heard
        assert (position["x"], position["y"]) == (pytest.approx(START[0], abs=0.3), pytest.approx(START[1], abs=0.3))
    finally:
        stop(api)
    # back to the live view's none
    assert "/layers/scene/mesh" not in view_nodes(running.station.view.port, seconds=2.0)


def crafted_log(path: Path, text: str) -> Path:
    """A short log of a copter's heartbeats with ``text`` as a STATUSTEXT from the station's logging
    component (chunked if long), as a recording that names a scene looks."""
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=mavlink.MAV_COMP_ID_LOG)
    copter = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    writer = TlogWriter(path)
    start = time.time() - 10
    for message in statustexts(text, mavlink.MAV_SEVERITY_INFO, 7):
        writer.write(pack(message, gcs), start)
    for second in range(5):
        beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                 mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3, 3)
        writer.write(pack(beat, copter), start + second)
    writer.close()
    return path


@pytest.mark.parametrize("text, found, shown, says", [
    ("scene nowhere.wrl sha256 0123456789abcdef", False, None, "nowhere.wrl (sha256 0123456789abcdef) was not found"),
    ("scene default.wrl sha256 0000000000000000", False, None, "default.wrl in the bundled scenes is not the recorded"),
    (f"scene default.wrl sha256 {DEFAULT_DIGEST}", True, "default.wrl", "found in the bundled scenes"),
    (f"scene {'a-very-long-but-valid-name-' * 3}.wrl sha256 0123456789abcdef", False, None, "was not found"),
])
def test_a_recording_whose_scene_is_missing_or_differs_says_so(bare, text, found, shown, says):
    running, api = bare
    name = f"crafted-{hashlib.md5(text.encode()).hexdigest()[:8]}.tlog"
    crafted_log(running.station.record_dir / name, text)
    status = replay(running, api, name)
    try:
        assert status["scene"]["found"] is found and status["scene"]["shown"] == shown
        assert says in status["scene"]["note"]
        mesh = "/layers/scene/mesh"
        assert (mesh in view_nodes(running.station.view.port, mesh, 2.0)) is (shown is not None)
    finally:
        stop(api)


@pytest.mark.parametrize("name", ["../outside.wrl", "../../outside.wrl", "/tmp/outside.wrl", "..", "outside",
                                  ".outside.wrl", "sub/outside.wrl", "..\\outside.wrl", "outside.wrl\0.txt"])
def test_a_recording_naming_a_path_loads_nothing(bare, name):
    """A file that exists beside the record folder, with the right hash: a log naming it by a path gets nothing."""
    running, api = bare
    outside = running.station.record_dir.parent / "outside.wrl"
    shutil.copy(default_scene(), outside)
    digest = hashlib.sha256(outside.read_bytes()).hexdigest()[:16]
    log = crafted_log(running.station.record_dir / "hostile.tlog", f"scene {name} sha256 {digest}")
    status = replay(running, api, log.name)
    try:
        assert status["scene"]["name"] is None and status["scene"]["shown"] is None
        assert status["scene"]["note"] == "the recording names no scene"
        assert "/layers/scene/mesh" not in view_nodes(running.station.view.port, seconds=1.5)
    finally:
        stop(api)


@pytest.mark.parametrize("name, valid", [
    ("default.wrl", True), ("castle.wrl.gz", True), ("a_b+c-1.WRL", True), ("x.wrz", True),
    ("../default.wrl", False), ("/etc/passwd", False), ("passwd", False), (".wrl", False), ("..wrl", False),
    ("a/b.wrl", False), ("a\\b.wrl", False), ("a b.wrl", False), ("x" * 97 + ".wrl", False), ("a..b.wrl", False),
    ("default.wrl\n", False), ("défaut.wrl", False),
])
def test_only_bare_scene_file_names_are_accepted(name, valid):
    assert is_scene_name(name) is valid
    assert (read_note(f"scene {name} sha256 {'ab' * 8}") is not None) is valid


def test_a_note_needs_a_16_digit_hex_digest():
    assert read_note("scene a.wrl sha256 0123456789abcdef") == ("a.wrl", "0123456789abcdef")
    for text in ("scene a.wrl sha256 0123456789abcde", "scene a.wrl sha256 0123456789ABCDEF",
                 "scene a.wrl sha256 0123456789abcdef0", "scene a.wrl md5 0123456789abcdef", "a.wrl"):
        assert read_note(text) is None, text


def test_the_note_comes_again_every_period_so_a_cut_log_still_has_it(tmp_path):
    text = f"scene default.wrl sha256 {DEFAULT_DIGEST}"
    recorder = Recorder(tmp_path, text)
    start = time.time()
    for second in range(1, 200):
        recorder.tick(start + second)
    recorder.close()
    notes = [note for note in notes_in(recorder.path) if note[2] == text]
    assert len(notes) == 1 + int(199 // NOTE_PERIOD)
    notes_clock = SceneNotes(text, period=10.0)
    assert notes_clock.take(0.0) and not notes_clock.take(9.9) and notes_clock.take(10.0)


def test_a_long_name_travels_in_chunks_and_is_read_back(tmp_path):
    name = "a-scene-whose-file-name-is-much-longer-than-fifty-bytes.wrl.gz"
    log = crafted_log(tmp_path / "long.tlog", f"scene {name} sha256 0123456789abcdef")
    assert len(notes_in(log)) == 2  # two chunks
    assert logged_scene(Replay.open(log, Fleet())) == (name, "0123456789abcdef")


def test_the_stations_own_scene_of_that_name_is_shown_even_when_it_differs(tmp_path):
    own_path = tmp_path / "default.wrl"
    own_path.write_bytes(default_scene().read_bytes() + b"\n# edited since\n")
    own = load_scene(own_path)
    own_digest = hashlib.sha256(own_path.read_bytes()).hexdigest()[:16]
    folders = [("the bundled scenes", scenes_dir())]
    matching = find_scene(("default.wrl", own_digest), own, own_digest, folders)
    assert matching.scene is own and matching.status["found"] is True
    recorded = find_scene(("default.wrl", DEFAULT_DIGEST), own, own_digest, folders)
    assert recorded.scene is not own and recorded.status["found"] is True  # the bundled one is the recorded one
    older = find_scene(("default.wrl", "0" * 16), own, own_digest, folders)
    assert older.scene is own and older.status["found"] is False and "shown anyway" in older.status["note"]
    nothing = find_scene(None, own, own_digest, folders)
    assert nothing.scene is own and nothing.status["note"] == "the recording names no scene; shown in the " \
                                                              "station's scene, default.wrl"


# ---- exports --------------------------------------------------------------------------------------------------
def embedded_messages(html: str) -> list[dict]:
    """The scene messages viser's serializer packed into an exported page (``__VISER_EMBED_DATA__``)."""
    data = base64.b64decode(re.search(r'__VISER_EMBED_DATA__="([^"]*)"', html).group(1))
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=int.from_bytes(data[:8], "little"))
    length = int.from_bytes(inner[:8], "little")
    return [message for _, message in msgspec.msgpack.decode(inner[8:8 + length])["messages"]]


def gltf_document(glb: bytes) -> dict:
    return json.loads(glb[20:20 + struct.unpack_from("<I", glb, 12)[0]])


def primitives(document: dict) -> list[dict]:
    return [p for m in document["meshes"] for p in m["primitives"]]


def glb_materials(glb: bytes) -> list[dict]:
    """The materials each primitive of a binary glTF uses."""
    document = gltf_document(glb)
    return [document["materials"][p["material"]] for p in primitives(document)]


def test_the_scene_mesh_goes_to_the_view_matte_with_its_geometry_and_colours_whole():
    """trimesh's own export, its colours per vertex (COLOR_0) and binary data as they were, but for a material."""
    mesh = load_scene(default_scene()).mesh
    glb, plain = matte_glb(mesh), mesh.export(file_type="glb")
    assert set(map(json.dumps, glb_materials(glb))) == {json.dumps(MATTE)}
    document, original = gltf_document(glb), gltf_document(plain)
    assert "materials" not in original and all("COLOR_0" in p["attributes"] for p in primitives(document))
    for primitive in primitives(document):
        del primitive["material"]
    del document["materials"]
    assert document == original
    assert glb.endswith(plain[20 + struct.unpack_from("<I", plain, 12)[0]:])  # the binary chunk
    assert struct.unpack_from("<I", glb, 8)[0] == len(glb) and len(glb) % 4 == 0


def texts_in(value) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [text for item in value.values() for text in texts_in(item)]
    if isinstance(value, list | tuple):
        return [text for item in value for text in texts_in(item)]
    return []


@pytest.fixture(scope="module")
def exported(recorded, bare, tmp_path_factory) -> Path:
    """The recording replayed in the station without a scene, exported as HTML (GET /api/replay/export)."""
    running, api = bare
    replay(running, api, copy_in(recorded, running))
    try:
        response = api.get("/api/replay/export", timeout=120)
    finally:
        stop(api)
    assert response.status_code == 200
    path = tmp_path_factory.mktemp("export") / "replay.html"
    path.write_text(response.text)
    return path


def test_an_export_carries_the_recordings_scene_and_a_telemetry_label(exported):
    messages = embedded_messages(exported.read_text())
    (mesh,) = [m for m in messages if m.get("name") == "/layers/scene/mesh" and m.get("type") == "GlbMessage"]
    # lit as the live view is without its environment map: matte (glTF's default material is a metal, which
    # reflects only that map: every wall facing away from the sun was black) and under an even light
    assert glb_materials(mesh["props"]["glb_data"]) == [MATTE]
    assert any(m.get("type") == "AmbientLightMessage" for m in messages)
    label = [text for m in messages if m.get("name") == "/telemetry/1" for text in texts_in(m)]
    panels = [text for text in label if "battery" in text]
    assert panels, label
    lines = panels[-1].splitlines()
    assert lines[0] == "1 copter  GUIDED  disarmed"  # the simulated copter waits on the ground
    assert re.fullmatch(r"alt -?0\.\d m  0\.\d m/s  heading \d+°", lines[1]), lines
    assert re.fullmatch(r"battery \d+\.\d V, \d+ %", lines[2]), lines
    assert lines[3].startswith("agent WAITING browse"), lines
    assert re.fullmatch(r"\d\d:\d\d:\d\d UTC, \+\d+\.\d s", lines[-1]), lines
    clocks = [float(re.search(r"\+([\d.]+) s", text).group(1)) for text in panels]
    assert clocks == sorted(clocks) and clocks[-1] > clocks[0]  # rewritten as the replay plays


@needs_chromium
@pytest.mark.browser
def test_an_export_plays_offline_in_chromium_and_draws_the_scene(exported, tmp_path):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = launch_chromium(playwright)
        try:
            context = browser.new_context(viewport={"width": 1000, "height": 700}, offline=True)
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            console: list[str] = []
            page.on("console", lambda message: console.append(f"{message.type}: {message.text}"))
            requests: list[str] = []
            page.on("request", lambda request: requests.append(request.url))
            page.goto(exported.as_uri())
            shots = []

            def drawn() -> bool:
                png = page.screenshot()
                shots.append(colours(png))
                (tmp_path / "export.png").write_bytes(png)
                return shots[-1][0] > 100 and shots[-1][1] < 0.7  # without the scene: 68 colours, 0.78

            # a page error ends the wait at once, to be reported below
            try:
                wait_wall(lambda: errors or drawn(), 90, "the exported page draws the scene",
                          sleep=lambda: page.wait_for_timeout(500))
            except WaitTimeout:
                opacity = page.evaluate("[...document.querySelectorAll('canvas')].map(c => c.style.opacity)")
                raise WaitTimeout(f"not drawn: last {shots[-3:]}, canvas opacity {opacity}, "
                                  f"console {console[-10:]}") from None
        finally:
            browser.close()
    assert not errors, errors
    assert all(url.startswith(("file:", "data:", "blob:")) for url in requests), requests  # nothing fetched


def colours(png: bytes) -> tuple[int, float]:
    """Distinct colours (5 bits a channel) in the middle of a screenshot and the share of the commonest: an
    empty view is one background colour and the axes, the default scene hundreds of colours."""
    image = Image.open(io.BytesIO(png)).convert("RGB")
    width, height = image.size
    middle = image.crop((int(width * 0.2), int(height * 0.25), int(width * 0.8), int(height * 0.85)))
    pixels = np.asarray(middle.resize((160, 120))) >> 3
    _, counts = np.unique(pixels.reshape(-1, 3), axis=0, return_counts=True)
    return len(counts), float(counts.max() / counts.sum())
