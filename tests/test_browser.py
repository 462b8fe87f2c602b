"""The operator page in a real headless Chromium, against a real ground station and simulated copters.

One ground station (the default scene, a known token, recordings in a temporary
folder) and one browser serve the whole module; a copter flies the search
mission throughout (system id 1) and tests that command a vehicle start their
own copter with its own system id, on the ground and idle, so they do not
disturb each other. Waits on what a vehicle does are bounded in its simulated
time (``time_boot_s`` from /api/vehicles); waits on what the ground station
does on the wall clock (the status stream, link loss) are bounded on the wall
clock.

Only the tests about the 3D view load viser's client into the page's frame; the
others give that frame an empty page. The frame is same-origin, so it shares the
page's main thread, and with software WebGL (SwiftShader, on two cores) viser
receiving and drawing the scene stalls the whole page for up to about 7 s, and
for 0.5-1 s now and then afterwards: the panel's tests would measure that
instead of the page.
"""

from __future__ import annotations

import io
import re
import time
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zstandard
from harness import (
    CHROMIUM,
    RunningSim,
    RunningStation,
    start_sim,
    wait_wall,
)
from PIL import Image

from groundstation.export import battery_text
from vehicle.agent.settings import Settings

pytestmark = pytest.mark.browser

if not Path(CHROMIUM).exists():
    pytest.skip("needs Debian's chromium at /usr/bin/chromium (./scripts/test.sh installs it)", allow_module_level=True)

from playwright.sync_api import TimeoutError as PlaywrightTimeout  # noqa: E402 - once Chromium is known to exist
from playwright.sync_api import expect  # noqa: E402

TOKEN = "browser-test-token-4f2a"
SPEEDUP = 5.0
FLYER = 1  # system id of the copter that flies the search mission all along
SIGN_IN_HINT = "Sign in with the operator token to command vehicles"
REPLAY_HINT = "Commands are disabled in replay"
UI_TIMEOUT = 20_000  # ms, for the page to show what the stream (4 frames/s) already carries
ACTIONS = ["abort", "rtl", "guided", "resume", "pause", "continue", "take_control", "arm", "land", "takeoff", "kill"]

expect.set_options(timeout=UI_TIMEOUT)


# ---- fixtures ----------------------------------------------------------------------------------------
def copter_for(station: RunningStation, scene, sysid: int, mission: str = "browse", autostart: bool = False,
               start: tuple[float, float] | None = None) -> RunningSim:
    """A simulated copter in the scene sending to the station, started."""
    return start_sim(station, scene, sysid, "copter", mission, autostart, start, Settings(), SPEEDUP).start()


@pytest.fixture(scope="module")
def flyer(scene, station):
    """A copter flying the search mission from the scene's start for the whole module."""
    copter = copter_for(station, scene, FLYER, mission="search", autostart=True)
    wait_wall(lambda: station.http.vehicle(FLYER), 15, "the flying copter is heard")
    yield copter
    copter.stop()


@pytest.fixture
def copters(scene, station):
    """Start idle copters for one test: ``copters(sysid, start=(x, y))``; stopped at the end of the test."""
    started: list[RunningSim] = []

    def start(sysid: int, start: tuple[float, float] | None = None, mission: str = "browse") -> RunningSim:
        born = time.monotonic()
        copter = copter_for(station, scene, sysid, mission=mission, start=start)
        started.append(copter)

        def heard_anew() -> bool:  # this copter, not one of the same id an earlier try of the test left behind
            v = station.http.vehicle(sysid)
            booted = v and v.get("time_boot_s")
            return booted is not None and booted <= (time.monotonic() - born + 1.0) * SPEEDUP + 2.0
        wait_wall(heard_anew, 15, f"vehicle {sysid} is heard")
        return copter

    yield start
    for copter in started:
        copter.stop()


class Page:
    """A fresh browser context (no stored token) with one page, recording JavaScript errors."""

    def __init__(self, browser, station: RunningStation):
        self.context = browser.new_context(viewport={"width": 1200, "height": 760})
        self.context.set_default_timeout(UI_TIMEOUT)
        self.page = self.context.new_page()
        self.station = station
        self.errors: list[str] = []
        self.scene_nodes: set[tuple[str, str]] = set()  # (message type, node name) the 3D view was sent
        self.commands: list[str] = []  # command POSTs the page sent
        self.requests: list[str] = []  # every request the page sent, in order
        self.page.on("pageerror", self._error)
        self.page.on("websocket", self._socket)
        self.page.on("request", self._request)

    def _error(self, error) -> None:
        # viser's bundle sets up its Gaussian-splat sorter (WebAssembly with embind, which compiles helpers
        # with Function()) at start; the view's policy forbids eval, and we draw no splats: expected
        self.errors.append(str(error))

    def _socket(self, socket) -> None:
        if "/viz" in socket.url:
            socket.on("framereceived", self._viser_frame)

    def _viser_frame(self, payload) -> None:
        """viser's wire format: sizes (2 x u64 little-endian), zstd-compressed msgpack, binary buffers."""
        if not isinstance(payload, bytes) or len(payload) < 16:
            return
        size, compressed = int.from_bytes(payload[:8], "little"), int.from_bytes(payload[8:16], "little")
        inner = zstandard.ZstdDecompressor().decompress(payload[16:16 + compressed], max_output_size=size)
        for message in msgspec.msgpack.decode(inner).get("messages", ()):
            if isinstance(message, dict) and "name" in message:
                self.scene_nodes.add((message.get("type", ""), message["name"]))

    def poll(self, condition, timeout: float, what: str):
        """Like ``poll``, but waiting inside Playwright so the page's events keep arriving."""
        return wait_wall(condition, timeout, what, sleep=lambda: self.page.wait_for_timeout(200))

    def _request(self, request) -> None:
        self.requests.append(request.url)
        if request.method == "POST" and "/commands" in request.url:
            self.commands.append(request.url)

    def settle(self) -> None:
        """Wait until every request the page has sent so far was seen: the page fetches a marker of its own,
        and Playwright reports requests in the order they were sent, so once the marker is seen nothing the
        page sent before it is still to come."""
        marker = f"{self.station.base}/api/health?settle={len(self.requests)}"
        self.page.evaluate("(url) => { fetch(url); }", marker)
        self.poll(lambda: marker in self.requests, 30, "the page's marker request seen")

    def open(self, fragment: str = "", view: bool = False):
        """Load the operator page; without ``view`` its 3D view's frame gets an empty page instead of
        viser's client (see the module's docstring)."""
        if not view:
            self.page.route("**/viz/**", lambda route: route.fulfill(
                body="<!doctype html><title>3D view left out</title>", content_type="text/html"))
        self.page.goto(f"{self.station.base}/{fragment}")
        return self.page

    def wait_for_view(self, tmp_path: Path, sysid: int) -> None:
        """Until the 3D view has been sent the scene and the vehicle, and shows the coloured scene."""
        root = f"/vehicles/{sysid}"
        wanted = {"/layers/scene/mesh", f"{root}/body", f"{root}/body/hull", f"/layers/trails/{sysid}"}
        self.poll(lambda: wanted <= {name for _, name in self.scene_nodes}, 45,
                  "the scene and the vehicle reach the 3D view")
        shots: list[tuple[int, float]] = []

        def drawn() -> bool:
            # a clip of the page, not an element screenshot: that waits for the element to be still
            # over two animation frames, and none come while viser holds the main thread; on a
            # loaded machine even a page screenshot can wait that long, so try again
            try:
                png = self.page.screenshot(clip=self.page.locator("#view").bounding_box(), timeout=15_000)
            except PlaywrightTimeout:
                shots.append((0, 1.0))
                return False
            (tmp_path / "view.png").write_bytes(png)
            shots.append(colours(png))
            count, dominant = shots[-1]
            return count > 100 and dominant < 0.5

        try:
            self.poll(drawn, 90, "the 3D view shows the coloured scene")
        except AssertionError as error:
            raise AssertionError(f"{error}; (colours, share of the commonest) seen: {shots[-10:]}") from None

    def card(self, sysid: int):
        return self.page.locator(f'.vehicle-card[data-sysid="{sysid}"]')

    def sign_in(self) -> None:
        self.page.fill("#token", TOKEN)
        self.page.click("#sign-in")
        expect(self.page.locator("#auth-status")).to_have_text("Signed in")


@pytest.fixture
def browser_page(browser, station):
    page = Page(browser, station)
    yield page
    page.context.close()
    assert not page.errors, f"JavaScript errors on the page: {page.errors}"


# ---- helpers -----------------------------------------------------------------------------------------
def colours(png: bytes) -> tuple[int, float]:
    """Distinct colours (5 bits a channel) in the middle of a screenshot of the 3D view, downscaled,
    and the share of the most common one.

    The middle leaves out viser's own overlays (notices, the connection panel). An empty view is
    one background colour (98 % of the pixels) and the world axes (about 50 colours); the
    default scene, lit, gives hundreds, none above 20 %.
    """
    image = Image.open(io.BytesIO(png)).convert("RGB")
    width, height = image.size
    middle = image.crop((int(width * 0.2), int(height * 0.25), int(width * 0.8), int(height * 0.85)))
    pixels = np.asarray(middle.resize((160, 120))) >> 3
    _, counts = np.unique(pixels.reshape(-1, 3), axis=0, return_counts=True)
    return len(counts), float(counts.max() / counts.sum())


def fixed(value: float) -> str:
    """A number as the page writes it: JavaScript's toFixed(1), which rounds halves up."""
    return str(Decimal(value).quantize(Decimal("0.1"), rounding=ROUND_HALF_UP))


def sim_time(text: str) -> float:
    """The vehicle clock a card shows, "t = 12.3 s"."""
    match = re.fullmatch(r"t = (-?[\d.]+) s", text.strip())
    assert match, f"unexpected clock text {text!r}"
    return float(match.group(1))


def position(text: str) -> tuple[float, float, float]:
    """x, y, alt from a card's "x 1.0 m, y -2.0 m, alt 4.0 m"."""
    match = re.fullmatch(r"x (-?[\d.]+) m, y (-?[\d.]+) m, alt (-?[\d.]+) m", text.strip())
    assert match, f"unexpected position text {text!r}"
    return tuple(float(v) for v in match.groups())


def press(button) -> None:
    """Click a button in the side panel once it can take the click (visible, enabled, not covered, still).

    The click is dispatched to the button itself: cards above it grow and shrink as the stream
    updates them (a wrapped status line, a "link lost" banner), so a click at the button's
    position a moment after Playwright measured it can land on the wrong button.
    """
    button.click(trial=True)
    button.dispatch_event("click")


def wait_sim(station: RunningStation, sysid: int, condition, sim_timeout: float, what: str) -> dict:
    return station.http.wait_vehicle(sysid, condition, sim_timeout, SPEEDUP, what)


# ---- the tests ---------------------------------------------------------------------------------------
def test_page_shows_the_vehicle_and_draws_the_scene(browser_page, station, flyer, tmp_path):
    page = browser_page.open(view=True)
    card = browser_page.card(FLYER)
    expect(card).to_be_visible()
    expect(card.locator(".vehicle-title")).to_have_text(f"Vehicle {FLYER} · copter")
    expect(page.locator("#no-vehicles")).to_be_hidden()
    expect(page.locator("#connection")).to_have_class(re.compile(r"\bconnected\b"))
    # through the app's proxy, the 3D view is sent the scene's mesh and this vehicle's body, hull and
    # trail, and draws them: before the scene is in, it is one flat background with the axes
    browser_page.wait_for_view(tmp_path, FLYER)  # leaves its last screenshot in tmp_path / "view.png"
    assert not browser_page.errors


def test_status_updates_while_the_vehicle_flies(browser_page, station, flyer):
    browser_page.open()
    card = browser_page.card(FLYER)
    expect(card.locator(".sim-time")).to_have_text(re.compile(r"^t = "))
    expect(card.locator(".position")).to_have_text(re.compile(r"^x "))
    first_clock = card.locator(".sim-time").inner_text()
    first_position = card.locator(".position").inner_text()
    start = station.http.vehicle(FLYER)["time_boot_s"]
    clocks, positions = {first_clock}, {first_position}
    deadline = time.monotonic() + 30 / SPEEDUP * 4 + 15
    while len(clocks) < 3 or len(positions) < 3:
        clocks.add(card.locator(".sim-time").inner_text())
        positions.add(card.locator(".position").inner_text())
        now = station.http.vehicle(FLYER)["time_boot_s"]
        assert now - start <= 30 and time.monotonic() < deadline, \
            f"the card did not follow the vehicle for 30 s of its time: clocks {clocks}, positions {positions}"
        # the page shows the vehicle's own clock (to 0.1 s), never ahead of what the vehicle reported since
        assert sim_time(card.locator(".sim-time").inner_text()) <= station.http.vehicle(FLYER)["time_boot_s"] + 0.05
        browser_page.page.wait_for_timeout(200)
    for text in positions:
        position(text)  # every one is a well-formed position


def test_commands_need_the_token(browser_page, station, flyer):
    page = browser_page.open()
    card = browser_page.card(FLYER)
    expect(card).to_be_visible()
    expect(page.locator("#auth-status")).to_have_text("Not signed in")
    for action in ACTIONS:
        button = card.locator(f'button[data-action="{action}"]')
        expect(button).to_be_disabled()
        expect(button).to_have_attribute("title", SIGN_IN_HINT)
    expect(card.locator(".command-hint")).to_be_visible()
    expect(card.locator(".command-hint")).to_have_text(SIGN_IN_HINT)
    expect(page.locator("#go-here")).to_be_disabled()

    status = page.evaluate("""async ([sysid, token]) => {
        const send = (headers) => fetch(`/api/vehicles/${sysid}/commands`, {method: "POST",
            headers: {"Content-Type": "application/json", ...headers}, body: JSON.stringify({action: "rtl"})});
        return [(await send({})).status, (await send({Authorization: `Bearer ${token}`})).status];
    }""", [FLYER, TOKEN + "-wrong"])
    assert status == [401, 401]
    assert station.http.vehicle(FLYER)["mode"] != "RTL"
    assert browser_page.commands == [f"{station.base}/api/vehicles/{FLYER}/commands"] * 2  # only ours


def test_sign_in_and_return_home(browser_page, station, copters):
    sysid = 2
    copters(sysid)
    browser_page.open()
    card = browser_page.card(sysid)
    expect(card.locator(".mode")).to_have_text("GUIDED")
    rtl = card.locator('button[data-action="rtl"]')
    expect(rtl).to_be_disabled()
    browser_page.sign_in()
    expect(rtl).to_be_enabled()
    expect(card.locator(".command-hint")).to_be_hidden()
    press(rtl)
    expect(card.locator(".ack")).to_have_text(re.compile(r"^Return home: accepted"))
    expect(card.locator(".mode")).to_have_text("RTL")
    assert wait_sim(station, sysid, lambda v: v["mode"] == "RTL", 5, "mode RTL")["mode"] == "RTL"


def test_token_in_the_url_signs_in(browser_page, station, flyer):
    page = browser_page.open(f"#token={TOKEN}")
    expect(page.locator("#auth-status")).to_have_text("Signed in")
    expect(page.locator("#auth-form")).to_be_hidden()
    assert TOKEN not in page.evaluate("location.href")  # it leaves the address bar at once
    expect(browser_page.card(FLYER).locator('button[data-action="rtl"]')).to_be_enabled()
    assert page.evaluate("localStorage.getItem('scanstation.token')") == TOKEN  # remembered for the next visit


def test_kill_is_pressed_and_held(browser_page, station, copters):
    sysid = 3
    copters(sysid)
    assert station.http.result(sysid, action="arm") == "accepted"
    browser_page.open(f"#token={TOKEN}")
    card = browser_page.card(sysid)
    expect(card.locator(".armed")).to_have_text("ARMED")
    kill = card.locator('button[data-action="kill"]')
    expect(kill).to_be_enabled()

    press(kill)  # a click is no kill: it must be held
    kill.focus()
    page = kill.page
    page.keyboard.down(" ")
    expect(kill).to_have_text("Keep holding to kill…")
    expect(kill).to_have_class(re.compile(r"\bconfirming\b"))
    page.keyboard.up(" ")  # let go at once: nothing sent, and the card says so (before, a 5 s window lapsed silently)
    expect(card.locator(".ack")).to_have_text(re.compile(r"^Kill: not sent: released after \d\.\d s"))
    browser_page.settle()
    assert browser_page.commands == []
    assert station.http.vehicle(sysid)["armed"] is True
    expect(card.locator(".armed")).to_have_text("ARMED")

    page.keyboard.down(" ")
    page.wait_for_timeout(2000)  # held past its 1.5 s
    page.keyboard.up(" ")
    expect(card.locator(".ack")).to_have_text(re.compile(r"^Kill: accepted"))
    assert browser_page.commands == [f"{station.base}/api/vehicles/{sysid}/commands"]
    wait_sim(station, sysid, lambda v: v["armed"] is False, 5, "disarmed by the kill")
    expect(card.locator(".armed")).to_have_text("disarmed")
    expect(kill).to_have_text("Kill")


def test_link_loss_shows_and_clears(browser_page, station, scene):
    sysid = 4
    copter = copter_for(station, scene, sysid)
    try:
        page = browser_page.open()
        card = browser_page.card(sysid)
        expect(card.locator(".link")).to_have_text(re.compile(r"^link ok"))
        expect(card).not_to_have_class(re.compile(r"\blost\b"))

        stopped = time.monotonic()
        copter.stop()
        page.wait_for_function("(sysid) => document.querySelector(`.vehicle-card[data-sysid='${sysid}']`)"
                               ".classList.contains('lost')", arg=sysid, polling=50, timeout=8000)
        shown = time.monotonic() - stopped
        expect(card.locator(".link")).to_have_text("LINK LOST")
        expect(card.locator(".lost-banner")).to_be_visible()
        assert shown <= 5.0, f"link loss took {shown:.1f} s to show"

        copter = copter_for(station, scene, sysid)
        expect(card).not_to_have_class(re.compile(r"\blost\b"), timeout=8000)
        expect(card.locator(".link")).to_have_text(re.compile(r"^link ok"))
        expect(card.locator(".lost-banner")).to_be_hidden()
    finally:
        copter.stop()


def test_replay_in_the_page(browser_page, station, flyer, tmp_path):
    # a recording with some flight in it
    wait_sim(station, FLYER, lambda v: v["time_boot_s"] >= 60, 60, "a minute of flight")
    recording = next(r for r in station.http.get("/api/recordings").json() if r["recording"])
    page = browser_page.open(f"#token={TOKEN}")
    card = browser_page.card(FLYER)
    expect(page.locator("#auth-status")).to_have_text("Signed in")
    live_position = card.locator(".position")
    expect(live_position).to_have_text(re.compile(r"^x "))
    try:
        press(page.locator("#recordings-refresh"))
        replay_button = page.locator(f'#recordings-list li[data-name="{recording["name"]}"] .replay-button')
        expect(replay_button).to_be_enabled()
        press(replay_button)
        expect(page.locator("#mode-banner")).to_have_text("REPLAY")
        expect(page.locator("#replay")).to_be_visible()
        expect(page.locator("#replay-name")).to_have_text(recording["name"])

        # commands are off while replaying: in the page, and at the API
        for action in ACTIONS:
            button = card.locator(f'button[data-action="{action}"]')
            expect(button).to_be_disabled()
            expect(button).to_have_attribute("title", REPLAY_HINT)
        expect(card.locator(".command-hint")).to_have_text(REPLAY_HINT)
        refused = station.http.post(f"/api/vehicles/{FLYER}/commands", json={"action": "rtl"},
                                       headers=station.http.operator)
        assert refused.status_code == 409, refused.text

        play = page.locator("#replay-play")
        expect(play).to_have_text("Pause")  # it starts playing
        play.click()
        expect(play).to_have_text("Play")
        duration = float(page.locator("#replay-time").get_attribute("max"))
        assert duration > 8, duration

        def seek(seconds: float) -> tuple[str, str]:
            page.eval_on_selector("#replay-time", """(slider, seconds) => {
                slider.value = String(seconds);
                slider.dispatchEvent(new Event("input", {bubbles: true}));
                slider.dispatchEvent(new Event("change", {bubbles: true}));
            }""", seconds)
            value = float(page.locator("#replay-time").input_value())
            clock = f"{fixed(value)} / {fixed(duration)} s"
            expect(page.locator("#replay-clock")).to_have_text(clock)
            # the server has seeked there, and the card shows the vehicle as it was then
            wait_wall(lambda: abs(station.http.get("/api/replay").json()["replay"]["time"] - value) < 0.05, 10,
                      f"the replay is at {value} s")
            replayed = station.http.vehicle(FLYER)
            expected = f"x {replayed['position']['x']:.1f} m, y {replayed['position']['y']:.1f} m, " \
                       f"alt {replayed['position']['z']:.1f} m"
            expect(card.locator(".position")).to_have_text(re.compile(
                r"^x -?[\d.]+ m, y -?[\d.]+ m, alt -?[\d.]+ m$"))
            wait_wall(lambda: _close(position(card.locator(".position").inner_text()), position(expected)), 10,
                      f"the card shows the replayed position {expected}")
            expect(page.locator("#replay-clock")).to_have_text(clock)
            return card.locator(".position").inner_text(), card.locator(".sim-time").inner_text()

        # the flyer joined the module's station some seconds into its recording: start where it is heard
        first_heard = next(t for t in range(3, int(duration) - 5)
                           if _replayed_at(station, t) is not None)
        early_position, early_clock = seek(float(first_heard))
        page.screenshot(path=str(tmp_path / "replay-early.png"))
        late_position, late_clock = seek(round(duration - 3.0, 1))
        page.screenshot(path=str(tmp_path / "replay-late.png"))
        assert early_position != late_position
        # the vehicle's clock in the card moved on about SPEEDUP times the log's (whose stamps are when the
        # ground station read each message: allow it 2 s of lag)
        elapsed = sim_time(late_clock) - sim_time(early_clock)
        assert 0 < elapsed <= (duration - 3.0 - first_heard + 2.0) * SPEEDUP, (early_clock, late_clock)

        page.click("#replay-stop")
        expect(page.locator("#mode-banner")).to_have_text("LIVE")
        expect(page.locator("#replay")).to_be_hidden()
        expect(card.locator('button[data-action="rtl"]')).to_be_enabled()
        expect(card.locator(".command-hint")).to_be_hidden()
        assert station.http.get("/api/replay").json()["mode"] == "live"
    finally:
        station.http.post("/api/replay/stop", json={}, headers=station.http.operator)


def _replayed_at(station: RunningStation, seconds: float) -> dict | None:
    """The flyer as the replay shows it once seeked to ``seconds`` (None when it is not in the log yet)."""
    station.http.post("/api/replay/control", json={"seek": float(seconds)}, headers=station.http.operator)
    wait_wall(lambda: abs(station.http.get("/api/replay").json()["replay"]["time"] - seconds) < 0.05, 10,
              f"the replay is at {seconds} s")
    return station.http.vehicle(FLYER)


def _close(shown: tuple[float, ...], expected: tuple[float, ...], tolerance: float = 0.11) -> bool:
    return all(abs(a - b) <= tolerance for a, b in zip(shown, expected, strict=True))



# ---- the page loads clean ------------------------------------------------------------------------------
def _console_errors(page) -> list[str]:
    """What a page says is wrong from now on: uncaught errors, console errors, policy violations of any level."""
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(f"uncaught: {error}"))
    page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}")
            if m.type == "error" or "Content Security Policy" in m.text else None)
    page.on("response", lambda r: errors.append(f"  (the answer {r.status} to {r.request.method} {r.url})")
            if r.status >= 400 else None)  # which request a "Failed to load resource" was
    return errors


def test_no_error_in_the_console_live_in_a_replay_and_in_an_export(browser_page, station, flyer, tmp_path):
    """viser's splat sorter started with every 3D view, and the view's policy (no unsafe-eval) refused the
    functions its WebAssembly glue makes from strings: an EvalError on every load. No error now, with the policy
    as strict: live, in a replay, and in the standalone file a replay exports."""
    errors = _console_errors(browser_page.page)
    page = browser_page.open(view=True)
    browser_page.wait_for_view(tmp_path, FLYER)
    assert not errors, errors

    wait_sim(station, FLYER, lambda v: v["time_boot_s"] >= 30, 60, "half a minute of flight")
    recording = next(r for r in station.http.get("/api/recordings").json() if r["recording"])
    try:
        started = station.http.post("/api/replay", json={"name": recording["name"]}, headers=station.http.operator)
        assert started.status_code == 200, started.text
        expect(page.locator("#mode-banner")).to_have_text("REPLAY")
        expect(page.locator("#instruments")).to_be_visible()  # the panels draw the replayed vehicle
        browser_page.settle()
        assert not errors, errors

        exported = station.http.get("/api/replay/export", timeout=180)
        assert exported.status_code == 200, exported.text[:200]
        path = tmp_path / "export.html"
        path.write_text(exported.text, encoding="utf-8")
    finally:
        station.http.post("/api/replay/stop", json={}, headers=station.http.operator)

    standalone = browser_page.context.new_page()
    errors = _console_errors(standalone)
    standalone.goto(path.as_uri())
    shots: list[tuple[int, float]] = []

    def drawn() -> bool:  # the exported scene in colour, as test_page_shows_the_vehicle_and_draws_the_scene's view
        try:
            shots.append(colours(standalone.screenshot(timeout=15_000)))
        except PlaywrightTimeout:
            return False
        # an empty view is one colour (98 %) and the axes; the export opens on its first vehicle, from above the
        # scene, where the lit ground fills more than half of the middle (58 %) among hundreds of colours
        return shots[-1][0] > 100 and shots[-1][1] < 0.8

    try:
        wait_wall(drawn, 90, "the export draws its scene", sleep=lambda: standalone.wait_for_timeout(500))
    except AssertionError as error:
        raise AssertionError(f"{error}; (colours, share of the commonest) seen: {shots[-5:]}") from None
    assert not errors, errors


def test_the_battery_reads_the_same_on_the_page_and_in_an_export(browser_page):
    """The page's batteryText (static/common.js) and the export's label (export.battery_text) say one thing."""
    cases = [None, {"voltage": 12.25, "remaining": 87, "current": 3.1}, {"voltage": 16.8, "remaining": -1},
             {"voltage": 11.04, "remaining": None}, {"voltage": -0.04, "remaining": 0}, {"voltage": None,
             "remaining": 49.5}, {"voltage": 0.35, "remaining": 100}, {}]
    page = browser_page.open()
    shown = page.evaluate("""async (cases) => {
        const { batteryText } = await import("/static/common.js");
        return cases.map((battery) => batteryText(battery));
    }""", cases)
    assert shown == [battery_text(battery) for battery in cases]
    assert shown[1:3] == ["12.3 V, 87 %", "16.8 V"]
