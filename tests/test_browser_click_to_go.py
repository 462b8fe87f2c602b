# ruff: noqa: F811 - the fixtures imported from test_browser are used by name
"""Browser tests of click-to-go and of the 3D view's proxy when a page closes (they share
tests/test_browser.py's fixtures and conftest's: one ground station, one Chromium)."""

from __future__ import annotations

import logging
import math
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path("tests").resolve()))  # run from the repository's root

import pytest  # noqa: E402
from playwright.sync_api import expect  # noqa: E402
from test_browser import (  # noqa: E402, F401 - fixtures are used by name
    FLYER,
    TOKEN,
    browser_page,
    copters,
    flyer,
    press,
    wait_sim,
    wait_wall,
)

pytestmark = pytest.mark.browser


def test_click_to_go(browser_page, station, copters, tmp_path):
    sysid = 5
    copters(sysid, start=(6.0, 6.0))  # north-east of the scene's centre, in the open
    assert station.http.result(sysid, action="set_mode", mode="GUIDED") == "accepted"
    assert station.http.result(sysid, action="arm") == "accepted"
    assert station.http.result(sysid, action="takeoff", altitude=4) == "accepted"
    wait_sim(station, sysid, lambda v: v["position"]["alt"] > 2.0, 20, "airborne")
    assert station.http.result(sysid, action="abort") == "accepted"  # hold there (the operator takes over)
    wait_sim(station, sysid, lambda v: v["mode"] == "BRAKE", 5, "holding in BRAKE")

    page = browser_page.open(f"#token={TOKEN}", view=True)
    expect(page.locator("#auth-status")).to_have_text("Signed in")
    browser_page.wait_for_view(tmp_path, sysid)
    coords = page.locator("#target-coords")
    expect(coords).to_have_text("Click the ground in the 3D view to pick a target")
    expect(page.locator("#go-here")).to_be_disabled()

    # the initial camera looks at the scene's centre from the south-west: the middle of the view is
    # open ground there (the start of the scene, clear for 6.9 m around)
    box = page.locator("#view").bounding_box()
    middle = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    # nothing of the page's own (the 2D map's pane and toolbar, a banner) lies over the view's middle
    on_top = page.evaluate("([x, y]) => document.elementFromPoint(x, y).closest('#view canvas, [id]').id || 'canvas'",
                           list(middle))
    assert on_top in ("canvas", "view"), f"#{on_top} covers the middle of the 3D view"
    page.mouse.click(*middle)
    expect(coords).to_have_text(re.compile(r"^x -?[\d.]+ m, y -?[\d.]+ m$"), timeout=30_000)
    target = tuple(float(v) for v in re.findall(r"-?[\d.]+", coords.inner_text()))
    assert math.hypot(*target) < 6, target  # near the centre, on the ground
    browser_page.poll(lambda: ("/target" in {name for _, name in browser_page.scene_nodes}), 10,
                      "the target marker is drawn in this viewer")
    page.screenshot(path=str(tmp_path / "target.png"))
    removed = ("RemoveSceneNodeMessage", "/target")
    assert removed not in browser_page.scene_nodes  # it stays while nobody has reached it

    page.select_option("#target-vehicle", str(sysid))
    go = page.locator("#go-here")
    expect(go).to_be_enabled()
    before = station.http.vehicle(sysid)["position"]
    distance = math.dist((before["x"], before["y"]), target)
    assert distance > 4, (before, target)
    press(go)
    expect(page.locator("#target .ack")).to_have_text(re.compile(rf"^Go here \(vehicle {sysid}\): accepted"))
    there = wait_sim(station, sysid, lambda v: math.dist((v["position"]["x"], v["position"]["y"]), target) < 1.0,
                     distance / 2.5 * 2 + 10, f"vehicle {sysid} reaches the target {target}")
    assert there["mode"] == "GUIDED"
    assert there["position"]["alt"] > 2.0  # it flew there
    # the marker is gone once the vehicle sent there reached it: not left behind after Go here is done
    browser_page.poll(lambda: removed in browser_page.scene_nodes, 10, "the target marker is taken away")
    page.screenshot(path=str(tmp_path / "arrived.png"))


class _Errors(logging.Handler):
    def __init__(self):
        super().__init__(logging.ERROR)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def test_closing_the_page_logs_no_server_error(browser_page, station, flyer, tmp_path):
    """A viewer closing the page is normal: the 3D view's proxy must not log an ASGI exception for it."""
    errors = _Errors()
    logger = logging.getLogger("uvicorn.error")
    logger.addHandler(errors)
    viser = station.station.view.server
    try:
        browser_page.open(view=True)
        browser_page.wait_for_view(tmp_path, FLYER)
        assert viser.get_clients()  # the viewer is connected through the proxy
        browser_page.context.close()  # the viewer leaves
        # the proxy has closed its side when viser has no client left (any error is logged by then)
        wait_wall(lambda: not viser.get_clients(), 10, "viser sees the viewer go")
    finally:
        logger.removeHandler(errors)
    messages = [r.getMessage() + (f" ({r.exc_info[1]!r})" if r.exc_info else "") for r in errors.records]
    assert not messages, messages
