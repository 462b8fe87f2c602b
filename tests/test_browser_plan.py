"""The plan view in a real headless Chromium, driven as a person would: waypoints clicked on the 2D map, one
dragged, an altitude typed, a leg through a building marked before upload, the upload's progress and the
vehicle's MISSION_ACK, files exported and imported (a hostile one refused with its reason), then Fly (AUTO), and
the vehicle seen flying the plan: its mode AUTO and waypoint 2 reached in /api/vehicles. Once on our
simulated copter (its onboard agent waiting: AUTO flies the uploaded plan, not the agent's mission), once on
ArduPilot's ArduCopter SITL (skipped with a reason where ../shared/sitl is absent).

The 3D view's frame gets an empty page (see ``test_browser``): this is about the panel and the 2D map.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import pytest
from harness import RunningStation, operator_page, skip_module_without_chromium, start_sim, wait_wall

from vehicle.agent.settings import Settings
from vehicle.protocol.mav import mavlink
from vehicle.protocol.waypoints import parse_mission

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "plan-view-test-token"
SPEEDUP = 5.0
UI_TIMEOUT = 20_000
SCREENSHOTS = Path(os.environ.get("SCREENSHOTS_DIR") or tempfile.mkdtemp())  # static/ for the README's
SITL = Path(__file__).resolve().parents[2] / "shared" / "sitl"
# In the default scene's open middle, round home at the origin: (8, 0), (8, 8), (0, 8) fly free; a leg from
# (0, 8) to (0, 25) passes through the Warehouse.
FIRST, SECOND_CLICKED, SECOND, THIRD, THROUGH_WAREHOUSE = (8, 0), (5, 10), (8, 8), (0, 8), (0, 25)

expect.set_options(timeout=UI_TIMEOUT)


def screen(page, x: float, y: float) -> tuple[float, float]:
    """Where scene point (x, y) is on the screen, through the 2D map's own projection."""
    box = page.locator("#map2d").bounding_box()
    sx, sy = page.evaluate("([x, y]) => window.map2d.toScreen(x, y)", [x, y])
    return box["x"] + sx, box["y"] + sy


def click_map(page, x: float, y: float) -> None:
    page.mouse.click(*screen(page, x, y))


def drag_on_map(page, start: tuple[float, float], end: tuple[float, float]) -> None:
    page.mouse.move(*screen(page, *start))
    page.mouse.down()
    page.mouse.move(*screen(page, *end), steps=8)
    page.mouse.up()


def rows(page):
    return page.locator("#plan-items tr")


def plan_by_clicks(page, sysid: int, picture: Path | None = None) -> None:
    """Click, drag and type a take-off and three waypoints; see a leg through the Warehouse marked, then deleted."""
    expect(page.locator("#plan-vehicle")).to_contain_text(f"vehicle {sysid}")
    page.click("#map2d-grow")
    expect(page.locator("#map2d-pane")).to_have_class(re.compile(r"\blarge\b"))
    page.click("#map2d-fit")
    scale_fitted = page.evaluate("window.map2d.view.scale")
    page.mouse.move(*screen(page, 4, 8))
    page.mouse.wheel(0, -700)  # zoom in round the plan (three times)
    wait_wall(lambda: page.evaluate("window.map2d.view.scale") > 2.5 * scale_fitted, 10, "the map zoomed in")
    page.click("#plan-edit")
    expect(page.locator("#plan-edit")).to_have_attribute("aria-pressed", "true")
    for point in (FIRST, SECOND_CLICKED, THIRD):
        click_map(page, *point)
    expect(rows(page)).to_have_count(4)  # the copter's take-off at home came with the first click
    expect(rows(page).nth(0).locator("select")).to_have_value("takeoff")
    expect(rows(page).nth(2).locator("select")).to_have_value("waypoint")
    near = 1.5 / page.evaluate("window.map2d.view.scale") + 0.01  # m: a pixel and a half
    clicked = page.evaluate("window.plan.items[2]")
    assert abs(clicked["x"] - SECOND_CLICKED[0]) < near and abs(clicked["y"] - SECOND_CLICKED[1]) < near, clicked

    drag_on_map(page, SECOND_CLICKED, SECOND)  # the second waypoint, dragged to where it should be
    moved = page.evaluate("window.plan.items[2]")
    assert abs(moved["x"] - SECOND[0]) < near and abs(moved["y"] - SECOND[1]) < near, moved
    assert page.evaluate("window.plan.items.length") == 4  # a drag adds nothing
    for field, value in (("alt", "6"), ("speed", "1.5")):  # the second waypoint a metre higher, flown slower
        box = page.locator(f'#plan-items tr:nth-child(3) input[data-field="{field}"]')
        box.fill(value)
        box.press("Enter")
        box.blur()
    wait_wall(lambda: page.evaluate("[window.plan.items[2].alt, window.plan.items[2].speed]") == [6, 1.5], 10,
              "the altitude and speed typed in")

    # a leg through a building is marked before upload, on the map and in words; deleted, the mark goes
    click_map(page, *THROUGH_WAREHOUSE)
    expect(rows(page)).to_have_count(5)
    expect(page.locator("#plan-blocked")).to_be_visible()
    expect(page.locator("#plan-blocked")).to_contain_text("Leg to item 5 goes through Warehouse at (0.0, 18.0, 5.0)")
    expect(rows(page).nth(4).locator("td.leg")).to_have_class(re.compile(r"\bblocked\b"))
    if picture is not None:
        page.locator("#plan").scroll_into_view_if_needed()
        page.screenshot(path=str(picture))
    rows(page).nth(4).locator(".plan-delete").click()
    expect(rows(page)).to_have_count(4)
    expect(page.locator("#plan-blocked")).to_be_hidden()
    expect(rows(page).nth(3).locator("td.leg")).to_have_text(re.compile(r"^\d+\.\d m$"))
    expect(page.locator("#plan-summary")).to_contain_text(re.compile(r"4 items · \d+\.\d m · about \d+ s"))
    page.click("#plan-edit")  # editing off: a click pans and measures again


def upload(page, station: RunningStation, sysid: int) -> list:
    expect(page.locator("#plan-fly")).to_be_disabled()  # nothing to fly yet, and the button says so
    expect(page.locator("#plan-fly")).to_have_attribute("title", re.compile("^The vehicle holds no mission"))
    page.click("#plan-upload")
    expect(page.locator("#plan-ack")).to_have_text(
        re.compile(rf"^Upload to vehicle {sysid}: accepted \(MISSION_ACK, 6 items with home\) · "), timeout=60_000)
    assert page.evaluate("[document.querySelector('#plan-progress').value, "
                         "document.querySelector('#plan-progress').max]") == [6, 6]
    expect(page.locator("#plan-fly")).to_be_enabled()
    on_board = parse_mission(station.http.get(f"/api/vehicles/{sysid}/mission").text)
    assert [i.command for i in on_board[1:]] == [mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_WAYPOINT,
                                                 mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_WAYPOINT,
                                                 mavlink.MAV_CMD_NAV_WAYPOINT]
    assert [round(i.alt, 3) for i in on_board[1:]] == [5, 5, 0, 6, 5] and on_board[3].param2 == 1.5
    return on_board


def fly_and_watch(page, station: RunningStation, sysid: int, speedup: float, tries: int = 1) -> dict:
    """Fly (AUTO), and see the vehicle in AUTO reach waypoint 2 (mission item 4: home 0, take-off 1, waypoint 1 2,
    its speed 3), and the page mark it (the plan's item 3, index 2) while it is flown."""
    page.evaluate("""window.flown = []; window.addEventListener("plan-changed", (e) => {
                     if (e.detail.current !== null) window.flown.push(e.detail.current); })""")
    ack = page.locator("#plan-ack")
    for attempt in range(tries):
        page.click("#plan-fly")
        expect(ack).not_to_contain_text("sending")
        if re.match(rf"^Fly \(AUTO\) vehicle {sysid}: accepted · ", ack.inner_text()) or attempt == tries - 1:
            break
        station.http.wait_sim_time(sysid, 10, speedup)  # ArduPilot arms once its position estimate settles
    expect(ack).to_have_text(re.compile(rf"^Fly \(AUTO\) vehicle {sysid}: accepted · "))
    station.http.wait_vehicle(sysid, lambda v: v["mode"] == "AUTO" and (v["mission"]["current"] or 0) >= 2, 60,
                              speedup, "AUTO, flying the plan")
    # the card says what is left of it: the legs, and the time at the plan's speeds
    expect(page.locator(f'.vehicle-card[data-sysid="{sysid}"] .progress-item')).to_have_text(
        re.compile(r"^item \d+ / \d+ · \d+ m left, about \d+ (s|min) at [\d.]+ m/s$"))
    flown = station.http.wait_vehicle(
        sysid, lambda v: v["mode"] == "AUTO" and (v["mission"]["reached"] or 0) >= 4, 180, speedup,
        "waypoint 2 (mission item 4) reached")
    wait_wall(lambda: 2 in page.evaluate("window.flown"), 10, "the page marked waypoint 2 as it was flown")
    return flown


def round_trip_files(page, tmp: Path) -> None:
    """Export WPL and .plan, import each back (the same plan), and a hostile file refused with its reason."""
    before = page.evaluate("window.plan.items")
    for button, name in (("#plan-export-wpl", "mission.waypoints"), ("#plan-export-plan", "mission.plan")):
        with page.expect_download() as download:
            page.click(button)
        path = tmp / name
        download.value.save_as(path)
        assert download.value.suggested_filename == name
        if name.endswith(".plan"):
            assert json.loads(path.read_text())["fileType"] == "Plan"
        page.click("#plan-clear")
        expect(rows(page)).to_have_count(0)
        page.set_input_files("#plan-file", str(path))
        expect(page.locator("#plan-ack")).to_have_text(re.compile(rf"^Import {re.escape(name)}: 4 items · "))
        after = page.evaluate("window.plan.items")
        for a, b in zip(before, after, strict=True):
            assert a["action"] == b["action"] and abs(a["x"] - b["x"]) < 0.01 and abs(a["y"] - b["y"]) < 0.01
            assert abs(a["alt"] - b["alt"]) < 0.01 and a["speed"] == b["speed"]
    hostile = tmp / "hostile.plan"
    hostile.write_text(json.dumps({"fileType": "Plan", "mission": {"plannedHomePosition": [-35.36, 149.16, 584],
                                                                   "items": [{"type": "ComplexItem",
                                                                              "complexItemType": "survey"}]}}))
    page.set_input_files("#plan-file", str(hostile))
    expect(page.locator("#plan-ack")).to_have_text(re.compile(
        r"^Import hostile\.plan: the \.plan file: item 1 is a survey pattern; turn it into waypoints"))
    assert len(page.evaluate("window.plan.items")) == 4  # nothing lost


def test_plan_on_the_map_upload_and_fly_auto_on_our_copter(browser, scene, station, tmp_path):
    sysid = 1
    copter = start_sim(station, scene, sysid, "copter", "browse", False, None, Settings(), SPEEDUP).start()
    try:
        station.http.wait_vehicle(sysid, lambda v: v["position"] is not None and v["home"] is not None, 30, SPEEDUP,
                                  "position and home heard")
        with operator_page(browser, station.base, TOKEN, 1500, 950, UI_TIMEOUT) as page:
            plan_by_clicks(page, sysid, SCREENSHOTS / "operator-plan.png")
            round_trip_files(page, tmp_path)
            upload(page, station, sysid)
            flown = fly_and_watch(page, station, sysid, SPEEDUP)
            assert flown["agent"]["state"] != "RUNNING"  # the agent's own mission never started: AUTO flew the plan
            page.screenshot(path=str(SCREENSHOTS / "operator-auto.png"))
    finally:
        copter.stop()


@pytest.mark.skipif(not (SITL / "arducopter").exists(),
                    reason="needs ArduPilot SITL in ../shared/sitl (absent in a bare clone)")
def test_plan_on_the_map_upload_and_fly_auto_on_ardupilot_sitl(browser, scene, tmp_path):
    from test_sitl import SPEEDUP as SITL_SPEEDUP
    from test_sitl import sitl

    sysid = 1
    with sitl("copter", 6, tmp_path) as (first, _), \
            RunningStation(scene, tmp_path / "recordings", TOKEN, urls=[f"tcp:127.0.0.1:{first}"]) as station:
        station.http.wait_vehicle(sysid, lambda v: v["position"] is not None and v["home"] is not None, 120,
                                  SITL_SPEEDUP, "ArduCopter's position and home")
        with operator_page(browser, station.base, TOKEN, 1500, 950, UI_TIMEOUT) as page:
            plan_by_clicks(page, sysid)
            upload(page, station, sysid)
            station.http.wait_vehicle(sysid, lambda v: v["time_boot_s"] > 50, 120, SITL_SPEEDUP,
                                      "ArduCopter's position estimate settles")
            fly_and_watch(page, station, sysid, SITL_SPEEDUP, tries=6)
