"""The page after its station restarts, in a real headless Chromium: the 3D view comes back with the new
session, and the new address's ``#token`` signs the page in again in the same tab.

A station is stopped and a new one started on the same web port, as ``groundstation serve`` started again
would be: a new session, a new operator token, other vehicles. The vehicles are fake autopilots on real
UDP sockets (``mavlink_peer.FakeVehicle``). What the 3D view shows is read in the frames its viser socket
was sent (the newest socket is the view now on screen) and in its frame's own text (viser's connection
badge); waits are in wall seconds, generous for software WebGL on two cores.
"""

from __future__ import annotations

import pytest
from harness import RunningStation, free_tcp_port, skip_module_without_chromium, small_scene, wait_wall

from groundstation.security import Access

skip_module_without_chromium()

import msgspec  # noqa: E402
import zstandard  # noqa: E402
from mavlink_peer import FakeVehicle  # noqa: E402
from playwright.sync_api import expect  # noqa: E402

pytestmark = pytest.mark.browser

FIRST_TOKEN, SECOND_TOKEN = "reconnect-first-token-5d1", "reconnect-second-token-9b7"
OLD, NEW = 1, 2  # the vehicle heard by the first station, and the one heard by the second
UI_TIMEOUT = 60_000
VIEW_BACK = 60  # s for the 3D view to show the new station (its client reloads and draws the scene again)

expect.set_options(timeout=UI_TIMEOUT)


class Page:
    """The operator page with its 3D view, and the viser messages each of its view's sockets was sent."""

    def __init__(self, browser):
        self.context = browser.new_context(viewport={"width": 1200, "height": 760})
        self.context.set_default_timeout(UI_TIMEOUT)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.views: list[list[dict]] = []  # per /viz socket, in the order they opened
        self.streams = 0  # /ws sockets opened
        self.page.on("pageerror", lambda error: self.errors.append(str(error)))
        self.page.on("websocket", self._socket)

    def _socket(self, socket) -> None:
        if "/viz" in socket.url:
            messages: list[dict] = []
            self.views.append(messages)
            socket.on("framereceived", lambda payload: messages.extend(_decode(payload)))
        elif "/ws" in socket.url:
            self.streams += 1

    def names(self) -> set[str]:
        """The scene nodes the view now on screen was sent."""
        return {m.get("name") for m in list(self.views[-1])} if self.views else set()

    def shows(self, sysid: int) -> bool:
        return any(isinstance(name, str) and name.startswith(f"/vehicles/{sysid}/") for name in self.names())

    def poll(self, condition, timeout: float, what: str):
        return wait_wall(condition, timeout, what, sleep=lambda: self.page.wait_for_timeout(250))

    def badge(self):
        """viser's connection badge in the view's frame: Connected, Connecting... or Inactive."""
        return self.page.frame_locator("#view").get_by_text("Inactive", exact=True)

    def close(self) -> None:
        self.context.close()
        assert not self.errors, f"JavaScript errors on the page: {self.errors}"


def _decode(payload) -> list[dict]:
    if not isinstance(payload, bytes) or len(payload) < 16:
        return []
    size, compressed = int.from_bytes(payload[:8], "little"), int.from_bytes(payload[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(payload[16:16 + compressed], max_output_size=size)
    return [m for m in msgspec.msgpack.decode(inner).get("messages", ()) if isinstance(m, dict)]


@pytest.fixture
def page(browser):
    opened = Page(browser)
    yield opened
    opened.close()


def station(tmp_path, token: str, port: int, beyond_loopback: bool = False) -> RunningStation:
    """A station on ``port``; ``beyond_loopback``: as served beyond loopback, where watching needs a token."""
    access = Access(token, viewing_needs_token=True) if beyond_loopback else None
    return RunningStation(small_scene(), tmp_path / token, token, http_port=port, access=access)


@pytest.mark.parametrize("focused", [False, True], ids=["panel-focused", "view-focused"])
def test_the_3d_view_shows_the_new_session_after_the_station_restarts(browser, page, tmp_path, focused):
    port = free_tcp_port()
    with station(tmp_path, FIRST_TOKEN, port) as first, \
            FakeVehicle(("127.0.0.1", first.mavlink_port), OLD):
        page.page.goto(f"{first.base}/#token={FIRST_TOKEN}")
        expect(page.page.locator("#auth-status")).to_have_text("Signed in")
        page.poll(lambda: page.shows(OLD), VIEW_BACK, f"the 3D view shows vehicle {OLD}")
        if focused:  # the operator last clicked in the view: viser's client there reconnects by itself
            page.page.locator("#view").click(position={"x": 450, "y": 200})  # clear of the panels
            assert page.page.frame_locator("#view").locator("body").evaluate("() => document.hasFocus()")
        first_views = len(page.views)
    # the station restarts on the same port: another session, another token, another vehicle
    with station(tmp_path, SECOND_TOKEN, port) as second, \
            FakeVehicle(("127.0.0.1", second.mavlink_port), NEW):
        expect(page.page.locator("#connection-text")).to_have_text("connected")
        page.poll(lambda: len(page.views) > first_views and page.shows(NEW), VIEW_BACK,
                  f"the 3D view reconnects and shows vehicle {NEW}")
        assert not page.shows(OLD), f"the 3D view still shows vehicle {OLD} of the old session"
        expect(page.badge()).to_have_count(0)  # viser's "Inactive" badge is gone
        # the view stays with the new station: its socket is up, tied to this page
        viewer = page.page.evaluate("document.querySelector('#view').getAttribute('src')").strip("/").split("/")[2]
        page.poll(lambda: viewer in second.station.proxy.viewers.values(), VIEW_BACK,
                  "the new station ties the view to this page")


@pytest.mark.parametrize("beyond_loopback", [False, True], ids=["loopback", "beyond-loopback"])
def test_a_new_address_in_the_same_tab_signs_the_page_in_again(browser, page, tmp_path, beyond_loopback):
    port = free_tcp_port()
    with station(tmp_path, FIRST_TOKEN, port, beyond_loopback) as first:
        page.page.goto(f"{first.base}/#token={FIRST_TOKEN}")
        expect(page.page.locator("#auth-status")).to_have_text("Signed in")
    with station(tmp_path, SECOND_TOKEN, port, beyond_loopback) as second:
        # the page reconnects, and the old token is refused (beyond loopback, its session's cookie too: the page
        # may not even watch)
        expect(page.page.locator("#auth-status")).to_contain_text("no longer accepts this token")
        if beyond_loopback:
            expect(page.page.locator("#connection-text")).to_contain_text("needs a token to watch")
        page.page.evaluate("window.sameDocument = true")
        streams, views = page.streams, len(page.views)
        # the operator pastes the address the new station printed: only its #token differs
        page.page.goto(f"{second.base}/#token={SECOND_TOKEN}")
        expect(page.page.locator("#auth-status")).to_have_text("Signed in")
        assert page.page.evaluate("window.sameDocument") is True, "the page was loaded again"
        assert "token" not in page.page.url, "the token stays in the address bar"
        assert page.page.evaluate("localStorage.getItem('scanstation.token')") == SECOND_TOKEN
        # its stream and its 3D view connect again, with the new token
        page.poll(lambda: page.streams > streams and len(page.views) > views, VIEW_BACK,
                  "the page opens its stream and its 3D view again")
        expect(page.page.locator("#connection-text")).to_have_text("connected")
        viewer = page.page.evaluate("document.querySelector('#view').getAttribute('src')").strip("/").split("/")[2]
        page.poll(lambda: viewer in second.station.proxy.viewers.values(), VIEW_BACK,
                  "the station ties the view to this page")
        expect(page.badge()).to_have_count(0)


def test_the_3d_view_comes_back_when_its_socket_drops(browser, page, tmp_path):
    with station(tmp_path, FIRST_TOKEN, free_tcp_port()) as running, \
            FakeVehicle(("127.0.0.1", running.mavlink_port), OLD):
        page.page.goto(f"{running.base}/#token={FIRST_TOKEN}")
        page.poll(lambda: page.shows(OLD), VIEW_BACK, f"the 3D view shows vehicle {OLD}")
        views = len(page.views)
        # the view's socket drops, the station and the page's stream stay: viser's client, in a frame without
        # focus, does not connect again by itself (viser's own way to drop its clients, as for a network cut)
        running.station.view.server._websock_server.disconnect_all_clients()
        expect(page.badge()).to_have_count(1)
        page.poll(lambda: len(page.views) > views and page.shows(OLD), VIEW_BACK,
                  "the page loads its 3D view again, and it shows the vehicle")
        expect(page.badge()).to_have_count(0)
