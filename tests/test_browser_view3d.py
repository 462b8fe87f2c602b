"""The operator's 3D view in a real headless Chromium: every vehicle seen at any zoom, camera modes per
viewer (buttons, keys, the wheel towards the cursor), layers per viewer.

One ground station with the default scene serves the module, with two copters: vehicle 1 idle on the
ground at the scene's start, vehicle 2 hovering at 4 m north-east of it. What the browser shows is
checked in screenshots of the view (the vehicles' colours, where they are on screen); what viser was
told, in the frames of the view's own websocket; where the camera is, in the camera state the browser
reports back to viser. Waits are on those observable conditions, with generous budgets: software WebGL
on two cores draws a few frames a second.
"""

from __future__ import annotations

import base64
import colorsys
import io
import math
import re
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zstandard
from harness import CHROMIUM, RunningStation, WaitTimeout, command_ok, load_default_scene, start_sim, wait_wall
from PIL import Image

from groundstation import camera
from groundstation.state import colour_of as colour
from groundstation.viewport import MARKER_PIXELS

pytestmark = pytest.mark.browser

if not Path(CHROMIUM).exists():
    pytest.skip("needs Debian's chromium at /usr/bin/chromium (./scripts/test.sh installs it)", allow_module_level=True)

from playwright.sync_api import Error as PlaywrightError  # noqa: E402 - once Chromium is known to exist
from playwright.sync_api import expect  # noqa: E402

TOKEN = "view3d-test-token-77c1"
GROUNDED, HOVERING = 1, 2
HOVER_AT = (6.0, 6.0)
UI_TIMEOUT = 30_000
BUSY_PAGE = 90_000  # ms for an action on the page: viser drawing in software WebGL holds its main thread
VIEWPORT = (1200, 760)
BYSTANDER = (400, 300)  # the other viewer's page: small, so that its software WebGL leaves the cores to ours
SHOTS = Path(__file__).resolve().parent.parent / "build" / "screenshots"  # left for a person to look at

expect.set_options(timeout=UI_TIMEOUT)


# ---- fixtures ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def station(tmp_path_factory):
    with RunningStation(load_default_scene(), tmp_path_factory.mktemp("recordings"), TOKEN) as running:
        yield running


@pytest.fixture(scope="module")
def vehicles(station):
    scene = station.station.scene
    # the hovering one taken up in simulated time: over the API, a loaded machine's late BRAKE let the mission
    # the take-off started fly it on, and it still drifted as the tests looked where it was
    sims = [start_sim(station, scene, GROUNDED).start(),
            start_sim(station, scene, HOVERING, start=HOVER_AT, hovering=4.0).start()]
    try:
        for sysid in (GROUNDED, HOVERING):
            wait_wall(lambda sysid=sysid: station.http.vehicle(sysid), 20, f"vehicle {sysid} is heard")
        station.http.wait_vehicle(HOVERING, lambda v: v["position"] is not None and v["position"]["alt"] > 3.5
                                  and (v["agent"] or {}).get("paused"), 10, what="hovering, its mission paused")
        # a metre east, for a trail to show; there it holds
        x, y = HOVER_AT[0] + 1.0, HOVER_AT[1]
        command_ok(station.http, HOVERING, action="goto", x=x, y=y)
        station.http.wait_vehicle(HOVERING, lambda v: math.hypot(v["position"]["x"] - x, v["position"]["y"] - y)
                                  < 0.3 and v["speed"] < 0.05, 30, what="holding a metre east")
        yield sims
    finally:
        for sim in sims:
            sim.stop()


class View:
    """One page with its 3D view: what its viser socket was sent, its viewer id, its viser client."""

    def __init__(self, browser, station: RunningStation, size: tuple[int, int] = VIEWPORT):
        self.station = station
        self.context = browser.new_context(viewport={"width": size[0], "height": size[1]})
        self.context.set_default_timeout(UI_TIMEOUT)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.messages: list[dict] = []  # every viser message this page's view was sent
        self._devtools = None  # a DevTools session for screenshots, opened with the first
        self.page.on("pageerror", self._error)
        self.page.on("websocket", self._socket)

    def _error(self, error) -> None:
        self.errors.append(str(error))

    def _socket(self, socket) -> None:
        if "/viz" in socket.url:
            socket.on("framereceived", self._frame)

    def _frame(self, payload) -> None:
        if not isinstance(payload, bytes) or len(payload) < 16:
            return
        size, compressed = int.from_bytes(payload[:8], "little"), int.from_bytes(payload[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompress(payload[16:16 + compressed], max_output_size=size)
        self.messages.extend(m for m in msgspec.msgpack.decode(inner).get("messages", ()) if isinstance(m, dict))

    def open(self) -> View:
        self.page.goto(self.station.base + "/")
        # the page sets its view's address once it knows it may watch: /viz/v/VIEWER/
        source = self.poll(lambda: self.page.evaluate("document.querySelector('#view').getAttribute('src')"), 30,
                           "the page opens its 3D view")
        self.viewer = source.strip("/").split("/")[2]
        self.poll(lambda: self.client_id is not None, 60, "the station ties the view's viser client to the page")
        return self

    @property
    def client_id(self) -> int | None:
        return next((cid for cid, viewer in self.station.station.proxy.viewers.items() if viewer == self.viewer), None)

    @property
    def camera(self):
        return self.station.station.view.server.get_clients()[self.client_id].camera

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera as the browser last reported it (eye, look-at)."""
        return np.array(self.camera.position), np.array(self.camera.look_at)

    def poll(self, condition, timeout: float, what: str):
        return wait_wall(condition, timeout, what, sleep=lambda: self.page.wait_for_timeout(200))

    def press_until(self, key, condition, what: str, tries: int = 3, each: float = 15.0) -> None:
        """Press a key (a locator's ``press``) until the camera shows ``condition``: on a loaded machine viser's
        client may reconnect between the key and the camera's move, which is then lost, as it would be for a
        person, who presses again."""
        for attempt in range(tries):
            key()
            try:
                self.poll(condition, each, what)
                return
            except WaitTimeout:
                if attempt == tries - 1:
                    raise

    def names(self, kind: str | None = None) -> set[str]:
        return {m.get("name") for m in list(self.messages) if kind is None or m.get("type") == kind}

    def updates(self, name: str, key: str) -> list:
        """The values viser was told for one property of one node, in order."""
        return [m["updates"][key] for m in list(self.messages)
                if m.get("type") == "SceneNodeUpdateMessage" and m.get("name") == name and key in m.get("updates", {})]

    def visibility(self, name: str) -> bool | None:
        """This page's own variant of a node: its visibility as last sent (None: never set)."""
        seen = [m["visible"] for m in list(self.messages)
                if m.get("type") == "SetSceneNodeVisibilityMessage" and m.get("name") == name
                and m.get("owner") == str(self.client_id)]
        return seen[-1] if seen else None

    def shot(self, path: Path | None = None) -> Image.Image | None:
        """A screenshot of the 3D view, straight from Chromium's compositor (DevTools' captureScreenshot).

        Playwright's own screenshot first asks the page where the view is and waits for its fonts and
        caret; viser drawing in software WebGL holds the page's main thread (its frame is same-origin),
        so that took 10 to 30 s a picture where this takes a few."""
        if self._devtools is None:
            self._devtools = self.context.new_cdp_session(self.page)
            self._box = self.page.locator("#view").bounding_box(timeout=BUSY_PAGE)  # the layout never moves it
        try:
            data = self._devtools.send("Page.captureScreenshot", {
                "format": "png", "clip": {**self._box, "scale": 1}, "optimizeForSpeed": True})
        except PlaywrightError:
            return None
        png = base64.b64decode(data["data"])
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(png)
        return Image.open(io.BytesIO(png)).convert("RGB")

    def wait_for_scene(self) -> None:
        wanted = {"/layers/scene/mesh", f"/vehicles/{GROUNDED}/body/dart", f"/vehicles/{HOVERING}/body/dart"}
        self.poll(lambda: wanted <= self.names(), 60, "the scene and both vehicles' markers reach the view")

    def mode_button(self, mode: str):
        return self.page.locator(f'#view3d [data-camera-mode="{mode}"]')


@pytest.fixture
def view(browser, station, vehicles):
    views: list[View] = []

    def make(size: tuple[int, int] = VIEWPORT) -> View:
        views.append(View(browser, station, size))
        return views[-1].open()

    yield make
    for one in views:
        one.context.close()
    for one in views:
        assert not one.errors, f"JavaScript errors on the page: {one.errors}"


# ---- helpers -----------------------------------------------------------------------------------------
def blob(image: Image.Image, rgb: tuple[int, int, int]) -> tuple[int, tuple[float, float] | None]:
    """Pixels of a vehicle's colour (its hue, saturated, lit or shaded), and their centroid (0..1 of the view)."""
    pixels = np.asarray(image, dtype=np.float32) / 255.0
    hsv = np.asarray(image.convert("HSV"), dtype=np.float32) / 255.0
    hue = colorsys.rgb_to_hsv(*(c / 255 for c in rgb))[0]
    distance = np.abs((hsv[..., 0] - hue + 0.5) % 1.0 - 0.5)
    mask = (distance < 0.035) & (hsv[..., 1] > 0.45) & (pixels.max(axis=2) > 0.3)
    count = int(mask.sum())
    if not count:
        return 0, None
    rows, cols = np.nonzero(mask)
    return count, (float(cols.mean() / mask.shape[1]), float(rows.mean() / mask.shape[0]))


def around(image: Image.Image, cam, point, half: int = 70) -> Image.Image:
    """The part of a view's screenshot around where ``point`` is, by the camera the browser reported."""
    local = camera.rotation(cam.wxyz).T @ (np.asarray(point, dtype=float) - np.array(cam.position))
    assert local[2] > 0, "the point is behind the camera"
    scale = math.tan(cam.fov / 2) * local[2]
    x = (local[0] / (scale * cam.aspect) + 1) / 2 * image.width
    y = (local[1] / scale + 1) / 2 * image.height  # OpenCV camera: +y is down
    return image.crop((int(x) - half, int(y) - half, int(x) + half, int(y) + half))


def position(station: RunningStation, sysid: int) -> np.ndarray:
    drawn = station.station.view._drawn[sysid]["body"].position
    return np.array(drawn, dtype=float)


def near(a, b, tolerance: float) -> bool:
    return float(np.linalg.norm(np.asarray(a, dtype=float) - np.asarray(b, dtype=float))) <= tolerance


def press(button) -> None:
    """Click a panel button. Dispatched to it, with time to spare: viser drawing in software WebGL holds
    the page's main thread (its frame is same-origin) for seconds now and then, longer with two views open."""
    button.dispatch_event("click", timeout=BUSY_PAGE)


def choose(view: View, sysid: int) -> None:
    """Select a vehicle in the panel's vehicle list (which tells the page with a ``vehicle-selected`` event)."""
    press(view.page.locator(f'#fleet-list .fleet-item[data-sysid="{sysid}"]'))


# ---- the tests ---------------------------------------------------------------------------------------
def test_every_vehicle_is_seen_at_the_default_view(view, station):
    one = view()
    one.wait_for_scene()
    # at the default view (about 80 m from the scene's centre) a 0.6 m body is a few pixels: each vehicle's
    # marker is scaled for this client's screen, and the selected one (the first: no selection yet) is ringed
    one.poll(lambda: any(s > 5 for s in one.updates(f"/vehicles/{GROUNDED}/body/dart", "scale")), 30,
             "the marker scaled up for the distance")
    one.poll(lambda: one.visibility(f"/vehicles/{GROUNDED}/at/halo") is True, 30, "the selected vehicle ringed")
    assert one.visibility(f"/vehicles/{HOVERING}/at/halo") is not True
    assert f"/vehicles/{HOVERING}/at/drop" in one.names()  # the hovering one has its line to the ground
    assert f"/layers/trails/{HOVERING}" in one.names()

    seen = []

    def both_seen() -> bool:
        image = one.shot(SHOTS / "view3d-default.png")
        if image is None:
            return False
        cam = one.camera
        seen.append(tuple(blob(around(image, cam, position(station, sysid)), colour(sysid))[0]
                          for sysid in (GROUNDED, HOVERING)))
        # where each vehicle is on screen, a dart MARKER_PIXELS long is some hundreds of pixels of its
        # colour; the bare body at this distance, a dozen
        return min(seen[-1]) >= MARKER_PIXELS * 5
    try:
        one.poll(both_seen, 150, "both vehicles drawn large enough to see, in their colours")
    except AssertionError as error:
        raise AssertionError(f"{error}; (blue, orange) pixels seen: {seen[-8:]}") from None


def test_follow_mode_chases_the_selected_vehicle_in_this_viewer_only(view, station):
    other = view(BYSTANDER)
    one = view()
    one.wait_for_scene()
    other.wait_for_scene()
    other_before = other.pose()

    press(one.mode_button("follow"))
    expect(one.mode_button("follow")).to_have_attribute("aria-pressed", "true")
    expect(one.mode_button("orbit")).to_have_attribute("aria-pressed", "false")

    def following(sysid: int) -> bool:
        eye, look = one.pose()
        target = position(station, sysid)
        return near(look[:2], target[:2], 3.0) and eye[2] > target[2] + 1.0 and near(eye, target, 15.0)

    one.poll(lambda: following(GROUNDED), 30, "the camera chases vehicle 1")
    centred = []

    def on_screen(sysid: int, name: str) -> bool:
        image = one.shot(SHOTS / name)
        if image is None:
            return False
        cam = one.camera
        where = position(station, sysid)
        local = camera.rotation(cam.wxyz).T @ (where - np.array(cam.position))
        across = local[0] / (local[2] * math.tan(cam.fov / 2) * cam.aspect)  # -1 .. 1, left to right
        count = blob(around(image, cam, where, half=90), colour(sysid))[0]
        centred.append((count, round(float(across), 2)))
        return count > 600 and abs(across) < 0.15
    try:
        one.poll(lambda: on_screen(GROUNDED, "view3d-follow-1.png"), 150, "vehicle 1 big in the middle of the view")
        choose(one, HOVERING)  # the panel's selection: the camera goes after vehicle 2
        expect(one.page.locator("#view3d-vehicle")).to_have_text(f"camera on vehicle {HOVERING}")
        one.poll(lambda: following(HOVERING), 30, "the camera chases vehicle 2")
        one.poll(lambda: on_screen(HOVERING, "view3d-follow.png"), 150, "vehicle 2 big in the middle of the view")
    except AssertionError as error:
        raise AssertionError(f"{error}; (pixels, centroid) seen: {centred[-6:]}") from None

    # the other viewer's camera never moved, and viser never told it to
    assert near(other.pose()[0], other_before[0], 0.01) and near(other.pose()[1], other_before[1], 0.01)
    assert not [m for m in other.messages if m.get("type") == "SetCameraPositionMessage" and not m.get("initial")]
    assert [m for m in one.messages if m.get("type") == "SetCameraPositionMessage" and not m.get("initial")]


def test_keys_switch_modes_fit_and_go_to_the_vehicle(view, station):
    one = view()
    one.wait_for_scene()
    page = one.page
    hover = position(station, HOVERING)
    choose(one, HOVERING)
    expect(page.locator("#view3d-vehicle")).to_have_text(f"camera on vehicle {HOVERING}")

    one.press_until(lambda: page.locator("body").press("4", timeout=BUSY_PAGE),  # top-down, north up
                    lambda: near(one.pose()[0][:2], hover[:2], 0.5) and one.pose()[0][2] > hover[2] + 10
                    and near(one.pose()[1], hover, 0.5), "the camera straight above vehicle 2")
    expect(one.mode_button("top")).to_have_attribute("aria-pressed", "true")

    # keys work with the focus inside the 3D view too (its frame is ours, same origin)
    frame = page.frame_locator("#view")
    frame.locator("canvas").first.focus(timeout=BUSY_PAGE)
    one.press_until(lambda: frame.locator("body").press("3", timeout=BUSY_PAGE),  # onboard, along its heading
                    lambda: near(one.pose()[0], hover, 0.6), "the camera on board vehicle 2")
    expect(one.mode_button("onboard")).to_have_attribute("aria-pressed", "true")
    assert one.visibility(f"/vehicles/{HOVERING}/body/dart") is False  # its own marker would fill the view

    low, high = station.station.scene.bounds
    cam = one.camera
    vehicles_at = [position(station, sysid) for sysid in (GROUNDED, HOVERING)]
    eye, look = camera.fit(np.min([low, *vehicles_at], axis=0), np.max([high, *vehicles_at], axis=0), cam.fov,
                           cam.aspect)
    one.press_until(lambda: page.locator("body").press("f", timeout=BUSY_PAGE),  # fit: the whole scene, camera free
                    lambda: near(one.pose()[0], eye, 2.0), "the camera fits the scene")
    expect(one.mode_button("orbit")).to_have_attribute("aria-pressed", "true")

    one.press_until(lambda: page.locator("body").press("v", timeout=BUSY_PAGE),  # go to the selected vehicle
                    lambda: near(one.pose()[1], hover, 1.0) and near(one.pose()[0], hover, 12.0),
                    "the camera next to vehicle 2")
    page.locator("body").press("1", timeout=BUSY_PAGE)
    expect(one.mode_button("orbit")).to_have_attribute("aria-pressed", "true")


def test_the_wheel_zooms_towards_the_cursor(view, station):
    one = view()
    one.wait_for_scene()
    one.poll(lambda: one.camera.image_height > 0, 30, "the view reported its size")
    box = one.page.locator("#view").bounding_box(timeout=BUSY_PAGE)
    x, y = 0.4, -0.3  # left of the middle and below it: the ground south-west of the centre
    cam = one.camera
    eye, look = one.pose()
    ray = camera.ray(cam.wxyz, cam.fov, cam.aspect, x, y)
    point = np.array(station.station.view.ground_point(eye, ray))
    one.page.mouse.move(box["x"] + box["width"] * (x + 1) / 2, box["y"] + box["height"] * (1 - y) / 2)
    one.page.mouse.wheel(0, -300)  # three steps closer
    factor = 0.85 ** 3
    one.poll(lambda: near(one.pose()[0], point + (eye - point) * factor, 1.0), 30,
             "the camera came closer to the point under the cursor")
    # viser's own wheel dolly would keep its orbit centre; ours moved it towards the cursor's point too
    assert near(one.pose()[1], point + (look - point) * factor, 1.0)
    new_eye = one.pose()[0]
    assert np.linalg.norm(new_eye - point) < np.linalg.norm(eye - point) * 0.7


def test_layers_and_map_opacity_are_each_viewers_own(view, station):
    other = view(BYSTANDER)
    one = view()
    one.wait_for_scene()
    other.wait_for_scene()
    page = one.page
    legend = page.locator("#view3d .legend li")
    expect(legend).to_have_count(3)
    expect(legend.nth(0)).to_have_text("free")
    expect(legend.nth(1)).to_have_text("occupied")

    layers = ["trails", "beams", "echoes", "waypoints", "paths", "map"]
    # six clicks in one turn of the page's main thread: a Playwright click waits for a turn of its own, 14 s
    # each while viser draws in software WebGL (see press)
    page.evaluate("(layers) => layers.forEach((layer) => document.querySelector("
                  "`#view3d input[data-layer='${layer}']`).click())", layers)
    for layer in layers:
        expect(page.locator(f'#view3d input[data-layer="{layer}"]')).not_to_be_checked()
        one.poll(lambda layer=layer: one.visibility(f"/layers/{layer}") is False, 30, f"{layer} hidden")
    page.select_option("#map-opacity", "0.3", timeout=BUSY_PAGE)
    one.poll(lambda: one.visibility("/layers/map/o30") is True and one.visibility("/layers/map/o100") is False,
             30, "the faint map shown instead of the opaque one")

    # the scene: colourful with it, nearly one colour without it
    def spread(image) -> float:
        pixels = np.asarray(image.resize((160, 120))) >> 3
        _, counts = np.unique(pixels.reshape(-1, 3), axis=0, return_counts=True)
        return float(counts.max() / counts.sum())
    shares = []

    def scene_shown(shown: bool) -> bool:
        image = one.shot(SHOTS / f"view3d-scene-{'on' if shown else 'off'}.png")
        if image is None:
            return False
        shares.append(spread(image))
        return shares[-1] < 0.5 if shown else shares[-1] > 0.6
    one.poll(lambda: scene_shown(True), 150, "the scene drawn")
    press(page.locator('#view3d input[data-layer="scene"]'))
    one.poll(lambda: one.visibility("/layers/scene") is False, 30, "the scene layer hidden")
    try:
        one.poll(lambda: scene_shown(False), 150, "the view without the scene")
    except AssertionError as error:
        raise AssertionError(f"{error}; share of the commonest colour: {shares[-6:]}") from None

    # nothing of it reached the other viewer
    for layer in ("scene", "trails", "map"):
        assert other.visibility(f"/layers/{layer}") is not False, layer
    assert other.visibility("/layers/map/o30") is not True


def test_a_refused_request_says_why_in_the_panel(view):
    one = view()
    # the page's own socket, used as the page would, with a mode the station does not know
    answer = one.page.evaluate("""(viewer) => new Promise((resolve) => {
        const socket = new WebSocket(`ws://${location.host}/ws?viewer=${viewer}`);
        socket.onopen = () => socket.send(JSON.stringify({type: "camera", mode: "<img src=x onerror=alert(1)>"}));
        socket.onmessage = (event) => {
            const msg = JSON.parse(event.data);
            if (msg.type === "view-error") { resolve(msg.detail); socket.close(); }
        };
    })""", one.viewer)
    assert answer.startswith("unknown camera mode") and "<img" not in answer
    assert re.fullmatch(r"unknown camera mode \(one of orbit, follow, onboard, top\)", answer)
