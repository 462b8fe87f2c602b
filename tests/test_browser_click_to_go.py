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
    expect(coords).to_have_text("Click the ground in the 3D view or the 2D map to pick a target")
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


def test_the_2d_map_follows_the_vehicle_and_a_click_on_it_sends_the_vehicle_there(browser_page, station, copters,
                                                                                    tmp_path):
    """Follow keeps the selected vehicle in the map's middle; a plain click on the map picks the Go here target
    (drawn there and marked in the 3D view), and Go here flies the vehicle to it; there, both marks go."""
    sysid = 6
    copters(sysid, start=(6.0, 6.0))
    assert station.http.result(sysid, action="set_mode", mode="GUIDED") == "accepted"
    assert station.http.result(sysid, action="arm") == "accepted"
    assert station.http.result(sysid, action="takeoff", altitude=4) == "accepted"
    wait_sim(station, sysid, lambda v: v["position"]["alt"] > 2.0, 20, "airborne")
    assert station.http.result(sysid, action="abort") == "accepted"
    wait_sim(station, sysid, lambda v: v["mode"] == "BRAKE", 5, "holding in BRAKE")

    page = browser_page.open(f"#token={TOKEN}", view=True)
    expect(page.locator("#auth-status")).to_have_text("Signed in")
    browser_page.wait_for_view(tmp_path, sysid)
    page.locator(f'#fleet-list .fleet-item[data-sysid="{sysid}"]').click()  # select it (others may be here)
    expect(page.locator(f'#fleet-list .fleet-item[data-sysid="{sysid}"]')).to_have_attribute("aria-pressed", "true")
    canvas = page.locator("#map2d")
    box = canvas.bounding_box()
    middle = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)

    def scene_at(x: float, y: float) -> tuple[float, float]:
        page.mouse.move(x, y)
        return tuple(float(v) for v in re.findall(r"-?[\d.]+", page.locator("#map2d-cursor").inner_text()))

    here = station.http.vehicle(sysid)["position"]
    page.mouse.move(*middle)  # drag the map away from the vehicle first
    page.mouse.down()
    page.mouse.move(middle[0] + 120, middle[1] - 90, steps=5)
    page.mouse.up()
    assert math.dist(scene_at(*middle), (here["x"], here["y"])) > 3
    page.click("#map2d-follow")
    expect(page.locator("#map2d-follow")).to_have_attribute("aria-pressed", "true")
    browser_page.poll(lambda: math.dist(scene_at(*middle), (here["x"], here["y"])) < 0.5, 10,
                      "the map's middle on the vehicle")

    per_pixel = (scene_at(middle[0] + 40, middle[1])[0] - scene_at(*middle)[0]) / 40  # metres
    # 4 m south-west of the vehicle, in the open middle of the scene (clear for 6.9 m around the origin)
    spot = (middle[0] - 4 / per_pixel, middle[1] + 4 / per_pixel)
    picked = scene_at(*spot)
    page.mouse.click(*spot)
    coords = page.locator("#target-coords")
    expect(coords).to_have_text(re.compile(r"^x -?[\d.]+ m, y -?[\d.]+ m$"))
    target = tuple(float(v) for v in re.findall(r"-?[\d.]+", coords.inner_text()))
    assert math.dist(target, picked) < 0.1, (target, picked)
    ratio = page.evaluate("window.devicePixelRatio")
    colour = page.evaluate("""([x, y, r]) => Array.from(document.querySelector('#map2d').getContext('2d')
        .getImageData(Math.round(x * r), Math.round(y * r), 1, 1).data)""",
                           [spot[0] - box["x"], spot[1] - box["y"], ratio])
    def yellow_on_the_map() -> int:  # the target's pixels (#ffd23f): nothing else on the map is drawn in it
        return page.evaluate("""() => { const c = document.querySelector('#map2d');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
            for (let i = 0; i < d.length; i += 4) if (d[i] === 255 && d[i + 1] === 210 && d[i + 2] === 63) n++;
            return n; }""")

    assert all(abs(a - b) <= 8 for a, b in zip(colour, (255, 210, 63), strict=False)), colour  # the yellow cross
    assert yellow_on_the_map() > 20
    browser_page.poll(lambda: "/target" in {name for _, name in browser_page.scene_nodes}, 10,
                      "the map's pick marked in the 3D view too")
    distance = math.dist((here["x"], here["y"]), target)
    assert distance > 3, (here, target)

    page.select_option("#target-vehicle", str(sysid))
    press(page.locator("#go-here"))
    expect(page.locator("#target .ack")).to_have_text(re.compile(rf"^Go here \(vehicle {sysid}\): accepted"))
    wait_sim(station, sysid, lambda v: math.dist((v["position"]["x"], v["position"]["y"]), target) < 1.0,
             distance / 2.5 * 2 + 10, f"vehicle {sysid} reaches the target {target} picked on the map")
    # there, the target is done: its marks go from the 3D view and the map, and the panel says who reached it
    browser_page.poll(lambda: ("RemoveSceneNodeMessage", "/target") in browser_page.scene_nodes, 10,
                      "the 3D view's mark taken away")
    expect(coords).to_have_text(re.compile(rf"^Vehicle {sysid} · \w+ reached x -?[\d.]+ m, y -?[\d.]+ m\. Click"))
    browser_page.poll(lambda: yellow_on_the_map() == 0, 10, "the map's yellow target taken away")


def test_swap_puts_the_map_large_and_the_3d_view_in_its_corner_and_back(browser_page, station, flyer, tmp_path):
    """Swap (picture in picture): the map fills the view area and the 3D view goes on, small, in a corner
    above it, where a click reaches it; Swap again, and hiding the map, give the 3D view the whole area back."""
    page = browser_page.open(view=True)
    browser_page.wait_for_view(tmp_path, FLYER)
    area = page.locator(".view-area").bounding_box()

    def view_box() -> dict:
        return page.locator("#view").bounding_box()

    def on_top_at(box: dict) -> str:
        return page.evaluate("([x, y]) => document.elementFromPoint(x, y).id",
                             [box["x"] + box["width"] / 2, box["y"] + box["height"] / 2])

    assert view_box()["width"] > 0.9 * area["width"]
    # the station knows what of this viewer's 3D view the map lies over (the orbit camera keeps vehicles out
    # from under it): the lower left, in the view's image coordinates
    viewer = page.eval_on_selector("#view", "f => f.src").rstrip("/").rsplit("/", 1)[-1]
    views = station.station.view.views

    def covered():
        settings = views.get(viewer)
        return settings.covered if settings is not None else "not yet"
    wait_wall(lambda: covered() not in (None, "not yet"), 10, "the map's box told to the station")
    x0, y0, x1, y1 = covered()
    assert x0 < -0.9 and y0 < -0.9 and -0.5 < x1 < 0.2 and -0.4 < y1 < 0.6, covered()
    page.click("#map2d-grow")
    expect(page.locator("#map2d-grow")).to_have_attribute("aria-pressed", "true")
    pane, small = page.locator("#map2d-pane").bounding_box(), view_box()
    assert pane["width"] > 0.9 * area["width"] and pane["height"] > 0.9 * area["height"], (pane, area)
    assert small["width"] < 0.4 * area["width"] and small["height"] < 0.45 * area["height"], small
    assert small["x"] > area["x"] + area["width"] / 2 and small["y"] > area["y"] + area["height"] / 2, small
    assert on_top_at(small) == "view"  # above the map, not under it
    wait_wall(lambda: covered() is None, 10, "nothing covers the small 3D view")
    page.screenshot(path=str(tmp_path / "swapped.png"))
    page.click("#map2d-toggle")  # the map hidden: the 3D view has the whole area again
    wait_wall(lambda: view_box()["width"] > 0.9 * area["width"], 5, "the 3D view large with the map hidden")
    page.click("#map2d-toggle")
    wait_wall(lambda: view_box()["width"] < 0.4 * area["width"], 5, "back in the corner with the map shown")
    page.click("#map2d-grow")
    expect(page.locator("#map2d-grow")).to_have_attribute("aria-pressed", "false")
    wait_wall(lambda: view_box()["width"] > 0.9 * area["width"], 5, "the 3D view large again")
