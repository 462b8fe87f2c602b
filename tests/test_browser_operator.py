"""The operator's view in a real headless Chromium: the vehicle list and its colours, the selected vehicle's
instruments and sonars, warnings as a banner, the 2D map with its distance tool, plots with events on the
replay's timeline (clicking seeks), and the recordings list kept live by the stream.

One ground station (the default scene, recordings in a temporary folder) serves the module, with two
copters: system id 1 flies the search mission throughout, 2 waits on the ground. Waits on what a vehicle
does are bounded in its simulated time; waits on the page on the wall clock, generously. The 3D view's frame
gets an empty page (see ``test_browser``): these tests are about the panel and the 2D map.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import pytest
from harness import RunningStation, canvas_colours, operator_page, skip_module_without_chromium, start_sim, wait_wall

from vehicle.agent.settings import Settings
from vehicle.protocol.mav import mavlink, mavutil
from vehicle.protocol.statustext import statustexts

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "operator-view-test-token"
SPEEDUP = 5.0
FLYER, IDLE = 1, 2
UI_TIMEOUT = 20_000
SCREENSHOTS = Path(os.environ.get("SCREENSHOTS_DIR") or tempfile.mkdtemp())  # static/ for the README's

expect.set_options(timeout=UI_TIMEOUT)


@pytest.fixture(scope="module")
def copters(scene, station):
    flying = start_sim(station, scene, FLYER, "copter", "search", True, None, Settings(), SPEEDUP).start()
    idle = start_sim(station, scene, IDLE, "copter", "browse", False, None, Settings(), SPEEDUP).start()
    wait_wall(lambda: station.http.vehicle(FLYER) and station.http.vehicle(IDLE), 20, "both copters are heard")
    yield flying, idle
    flying.stop()
    idle.stop()


@pytest.fixture
def page(browser, station, copters):
    with operator_page(browser, station.base, TOKEN, timeout_ms=UI_TIMEOUT) as found:
        yield found


def wait_sim(station: RunningStation, sysid: int, condition, sim_timeout: float, what: str) -> dict:
    return station.http.wait_vehicle(sysid, condition, sim_timeout, SPEEDUP, what)


def pixel(page, selector: str, x: float, y: float) -> tuple[int, int, int, int]:
    """The colour of a canvas at (x, y), as fractions of its own width and height."""
    return tuple(page.eval_on_selector(selector, """(c, [x, y]) =>
        Array.from(c.getContext("2d").getImageData(Math.floor(c.width * x), Math.floor(c.height * y), 1, 1).data)
    """, [x, y]))


def rgb(hex_colour: str) -> str:
    value = int(hex_colour[1:], 16)
    return f"rgb({value >> 16}, {(value >> 8) & 255}, {value & 255})"


# ---- 1. several vehicles: a list, each in its colour, one selected ----------------------------------------
def test_vehicles_are_listed_in_their_colours_and_one_is_selected(page, station):
    vehicles = station.http.vehicles()
    assert vehicles[FLYER]["colour"] != vehicles[IDLE]["colour"]
    items = page.locator("#fleet-list .fleet-item")
    expect(items).to_have_count(2)
    for sysid in (FLYER, IDLE):
        item = page.locator(f'#fleet-list .fleet-item[data-sysid="{sysid}"]')
        expect(item).to_contain_text(f"{sysid} copter")
        expect(item.locator(".fleet-mode")).to_have_text(re.compile(r"^[A-Z_]+ · mission (running|waiting)"))
        dot = item.locator(".swatch-dot")
        assert dot.evaluate("d => getComputedStyle(d).backgroundColor") == rgb(vehicles[sysid]["colour"])
        card = page.locator(f'.vehicle-card[data-sysid="{sysid}"]')
        expect(card).to_have_css("border-left-color", rgb(vehicles[sysid]["colour"]))

    # the first vehicle is selected until the operator picks another; the page says so to the rest of it
    expect(page.locator(f'.fleet-item[data-sysid="{FLYER}"]')).to_have_attribute("aria-pressed", "true")
    assert page.evaluate("window.selectedVehicle") == FLYER
    page.evaluate("""window.heard = []; window.addEventListener("vehicle-selected",
                     (e) => window.heard.push(e.detail.sysid))""")
    page.click(f'.fleet-item[data-sysid="{IDLE}"]')
    expect(page.locator(f'.fleet-item[data-sysid="{IDLE}"]')).to_have_attribute("aria-pressed", "true")
    expect(page.locator(f'.fleet-item[data-sysid="{FLYER}"]')).to_have_attribute("aria-pressed", "false")
    expect(page.locator(f'.vehicle-card[data-sysid="{IDLE}"]')).to_have_class(re.compile(r"\bselected\b"))
    expect(page.locator(f'.vehicle-card[data-sysid="{FLYER}"]')).not_to_have_class(re.compile(r"\bselected\b"))
    assert page.evaluate("window.selectedVehicle") == IDLE
    assert page.evaluate("window.heard") == [IDLE]
    expect(page.locator("#target-vehicle")).to_have_value(str(IDLE))  # "Go here" follows the selection
    expect(page.locator("#instruments-vehicle")).to_have_text(f"{IDLE} copter")
    # the selection stays across status frames (the stream sends four a second)
    page.evaluate("""window.statusFrames = 0; window.addEventListener("station-status", () => window.statusFrames++)""")
    wait_wall(lambda: page.evaluate("window.statusFrames") >= 3, 20, "three more status frames",
              sleep=lambda: page.wait_for_timeout(100))
    assert page.evaluate("window.selectedVehicle") == IDLE


# ---- 2. instruments and the sonars' proximity view -------------------------------------------------------
def test_instruments_show_the_selected_vehicle(page, station):
    flying = wait_sim(station, FLYER, lambda v: (v["position"] or {}).get("alt", 0) > 1.5 and v["sonar"], 120,
                      "the flyer is airborne with its sonars")
    expect(page.locator("#instruments")).to_be_visible()
    expect(page.locator("#instruments-vehicle")).to_have_text(f"{FLYER} copter")
    expect(page.locator("#readout-altitude")).to_have_text(re.compile(r"^\d+\.\d m$"))
    expect(page.locator("#readout-speed")).to_have_text(re.compile(r"^\d+\.\d m/s$"))
    expect(page.locator("#readout-climb")).to_have_text(re.compile(r"^[+-]\d+\.\d m/s$"))
    expect(page.locator("#readout-heading")).to_have_text(re.compile(r"^\d{1,3}°$"))
    expect(page.locator("#readout-attitude")).to_have_text(re.compile(r"^roll -?\d+\.\d°, pitch -?\d+\.\d°$"))
    expect(page.locator("#readout-battery")).to_have_text(re.compile(r"^\d+\.\d V"))
    expect(page.locator("#readout-sonar")).to_have_text(re.compile(r"^\d+°: "))
    altitude = float(page.locator("#readout-altitude").inner_text().split()[0])
    assert altitude > 0.5, altitude  # the copter is flying (the page shows the live value, not a stale one)
    assert len(page.locator("#readout-sonar").inner_text().split(" · ")) == len(flying["sonar"])
    # the overhead sonar is named by its mount, not taken for the level one at the same bearing
    assert [s["pitch"] for s in flying["sonar"]] == [0.0, 0.0, 0.0, 8.0], flying["sonar"]
    expect(page.locator("#readout-sonar")).to_contain_text(re.compile(r" · 0° up 8°: (clear|\d+\.\d m)$"))

    # the artificial horizon: sky above, ground below, once the copter flies near level (it leans to turn)
    seen = []

    def horizon() -> bool:
        sky, ground = pixel(page, "#attitude", 0.5, 0.15), pixel(page, "#attitude", 0.5, 0.8)
        seen.append((sky, ground))
        return sky[2] > 150 and sky[2] > sky[0] + 60 and ground[0] > ground[2] + 40
    try:
        wait_wall(horizon, 30, "sky above and ground below", sleep=lambda: page.wait_for_timeout(200))
    except AssertionError as error:
        raise AssertionError(f"{error}; (sky, ground) pixels seen: {seen[-4:]}") from None
    # the compass: the vehicle's colour in the middle
    colour = int(flying["colour"][1:], 16)
    middle = pixel(page, "#compass", 0.5, 0.5)
    assert abs(middle[0] - (colour >> 16)) < 30 and abs(middle[1] - ((colour >> 8) & 255)) < 30, middle
    # the proximity view: sectors in the distance colours (green clear, yellow-orange-red near)
    colours = canvas_colours(page, "#proximity")
    sectors = {c for c in colours if c[1] >= 8 and c[0] <= 8 or c[0] >= 14 and c[2] <= 5}
    assert sectors, colours
    # the ring's range is the ladder's step (5, 10, 20, 40 m) just above the farthest echo, not the sonars' 40 m:
    # the copter waiting on the ground hears walls 8 to 18 m away, so its ring is 20 m
    ladder = [5, 10, 20, 40]
    page.locator(f'#fleet-list .fleet-item[data-sysid="{IDLE}"]').click()
    expect(page.locator("#instruments-vehicle")).to_have_text(f"{IDLE} copter")

    def ring_fits() -> bool:
        sonar = station.http.vehicles()[IDLE]["sonar"]
        echoes = [s["distance"] for s in sonar if s["distance"] is not None and s["distance"] < s["max_range"]]
        wanted = next((step for step in ladder if step > max(echoes, default=0.0)), ladder[-1])
        shown = page.eval_on_selector("#proximity", "c => Number(c.dataset.range)")
        seen.append((echoes, shown))
        return shown == wanted < ladder[-1]
    seen.clear()
    try:
        wait_wall(ring_fits, 30, "the proximity ring at the ladder's step above the echoes",
                  sleep=lambda: page.wait_for_timeout(300))
    except AssertionError as error:
        raise AssertionError(f"{error}; (echoes, range shown): {seen[-4:]}") from None


def test_the_instruments_grow_with_the_panel_and_stay_sharp(page, station):
    """On a wide screen the panel is wider and the instruments with it; each canvas has as many pixels as it
    shows (drawn for its size, not a 150 px picture stretched), and the compass letters stay readable."""
    expect(page.locator("#instruments")).to_be_visible()
    shown = {}
    try:
        for width in (1400, 1920):
            page.set_viewport_size({"width": width, "height": 900})

            def drawn_at_its_size(width: int = width) -> bool:
                size = page.eval_on_selector("#compass", "c => [c.clientWidth, c.width, window.devicePixelRatio]")
                shown[width] = size
                return size[0] > 0 and size[1] == round(size[0] * size[2])
            wait_wall(drawn_at_its_size, 10, f"the compass drawn at its size at {width} px",
                      sleep=lambda: page.wait_for_timeout(200))
    finally:
        page.set_viewport_size({"width": 1400, "height": 900})
    assert shown[1920][0] > 1.3 * shown[1400][0], shown
    # the compass face in the vehicle's colour at its middle at either size (drawn whole, not a corner of it)
    assert pixel(page, "#compass", 0.5, 0.5)[3] == 255


# ---- 4. honest state: warnings shown whole, prominently ---------------------------------------------------
def test_warnings_are_a_banner_shown_whole(page, station):
    text = ("RTL: obstacle 1.2 m ahead at (10.5, -3.0); climbing to 15 m before flying home past the building "
            "that stands between here and home")
    assert len(text) > 100  # three STATUSTEXT chunks
    # another part of the vehicle (the autopilot's own name is heard only from where its heartbeat comes)
    sender = mavutil.mavlink_connection(station.vehicle_url(), source_system=FLYER,
                                        source_component=mavlink.MAV_COMP_ID_OBSTACLE_AVOIDANCE)
    try:
        for message in statustexts(text, mavlink.MAV_SEVERITY_WARNING, 77):
            sender.mav.send(message)
        sender.mav.send(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"just saying", 0, 0))
    finally:
        sender.close()
    banner = page.locator("#warning-banner")
    expect(banner).to_be_visible()
    item = banner.locator("li", has_text="RTL: obstacle")
    expect(item).to_have_text(re.compile(rf"^{FLYER} copter:{re.escape(text)}Dismiss$"))
    expect(banner).not_to_contain_text("just saying")  # INFO is not a warning
    # beside the autopilot's mode, the onboard mission's state
    card = page.locator(f'.vehicle-card[data-sysid="{FLYER}"]')
    expect(card.locator(".mode")).to_have_text(re.compile(r"^[A-Z_]+$"))
    expect(card.locator(".agent-state")).to_have_text(re.compile(r"^(RUNNING|PAUSED|FINISHED|STOPPED|IDLE)"))
    item.locator("button").click()
    expect(banner.locator("li", has_text="RTL: obstacle")).to_have_count(0)


# ---- 3. the 2D map -----------------------------------------------------------------------------------------
def test_the_2d_map_shows_the_scene_vehicles_maps_and_measures(page, station):
    wait_sim(station, FLYER, lambda v: (v["map"]["occupied"] or 0) > 0, 120, "the flyer maps obstacles")
    scene = station.http.get("/api/map2d/scene").json()
    assert scene["image"].startswith("data:image/png;base64,") and len(scene["bounds"]) == 4
    own = station.http.get(f"/api/map2d/maps/{FLYER}").json()
    merged = station.http.get("/api/map2d/maps/merged").json()
    assert set(own["legend"]) == {"unknown", "free", "occupied"}
    assert merged["vehicles"] == [FLYER] or set(merged["vehicles"]) >= {FLYER}
    for bad in ("../1", "999999", "-1", "merged2"):
        assert station.http.get(f"/api/map2d/maps/{bad}").status_code in (404, 422)
    trails = station.http.get("/api/map2d/trails").json()
    assert len(trails[str(FLYER)]) > 2

    canvas = page.locator("#map2d")
    expect(canvas).to_be_visible()
    expect(canvas).to_have_attribute("data-overlay", str(FLYER))  # the selected vehicle's map
    wait_wall(lambda: len(canvas_colours(page, "#map2d")) > 20, 30, "the map draws the scene")
    expect(canvas).to_have_attribute("data-scale", re.compile(r"^\d+(\.\d+)?$"))  # a scale bar
    page.select_option("#map2d-layer", "merged")
    expect(canvas).to_have_attribute("data-overlay", "merged")
    expect(page.locator(".map-legend")).to_have_text(re.compile("free.*occupied.*unknown", re.S))

    box = canvas.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    view = page.evaluate("window.map2d.view")
    expect(page.locator("#map2d-cursor")).to_have_text(f"x {view['cx']:.1f} m, y {view['cy']:.1f} m".replace(
        "-0.0", "0.0"))

    page.click("#map2d-measure")
    expect(page.locator("#map2d-distance")).to_have_text("click the first point")
    page.mouse.click(box["x"] + 40, box["y"] + 60)
    page.mouse.click(box["x"] + 40 + 120, box["y"] + 60 + 90)
    expected = 150 / page.evaluate("window.map2d.view.scale")
    expect(page.locator("#map2d-distance")).to_have_text(f"distance {expected:.1f} m")
    assert abs(page.evaluate("window.map2d.distance") - expected) < 1e-6


# ---- 5. plots and events, live and on the replay's timeline ----------------------------------------------
def test_plots_live_and_in_replay_with_events_that_seek(page, station):
    wait_sim(station, FLYER, lambda v: v["time_boot_s"] >= 40, 90, "some flight to plot")
    history = station.http.get(f"/api/vehicles/{FLYER}/history", params={"limit": 50}).json()
    assert len(history["t"]) <= 50 and "altitude" in history["series"]
    assert any(e["kind"] == "mode" for e in history["events"])
    for bad in ({"limit": 0}, {"limit": 10**6}, {"since": "nan"}, {"since": -1}):
        assert station.http.get(f"/api/vehicles/{FLYER}/history", params=bad).status_code == 422
    assert station.http.get("/api/vehicles/99/history").status_code == 404

    expect(page.locator("#plots")).to_be_visible()
    field = page.locator("#plot-field")
    expect(field.locator("option[value='altitude']")).to_have_count(1)
    expect(field.locator("option[value='sonar 0']")).to_have_count(1)
    page.select_option("#plot-field", "altitude")
    expect(page.locator("#plot-value")).to_have_text(re.compile(r"^-?\d+\.\d m$"))
    expect(page.locator("#plot-events .event-marker").first).to_be_attached()
    wait_wall(lambda: len(canvas_colours(page, "#plot")) > 3, 20, "the plot draws a line")

    # a command the station sends, and the vehicle's ACK, are events of that vehicle (once each)
    assert station.http.result(IDLE, action="set_mode", mode="GUIDED") == "accepted"
    events = station.http.get(f"/api/vehicles/{IDLE}/history").json()["events"]
    assert [e["text"] for e in events if e["kind"] == "command"][-1:] == ["sent DO_SET_MODE GUIDED"], events
    assert [e["text"] for e in events if e["kind"] == "ack"][-1:] == ["DO_SET_MODE: accepted"], events
    assert len([e for e in events if e["kind"] == "command"]) == 1, events
    # the recording is flushed every second: once it has grown after the ACK, the ACK is on disk
    on_disk = station.station.recorder.path.stat().st_size
    wait_wall(lambda: station.station.recorder.path.stat().st_size > on_disk, 10, "the recording flushed")

    recording = next(r for r in station.http.get("/api/recordings").json() if r["recording"])
    started = station.http.post("/api/replay", json={"name": recording["name"]}, headers=station.http.operator)
    assert started.status_code == 200, started.text
    try:
        station.http.post("/api/replay/control", json={"play": False}, headers=station.http.operator)
        wait_wall(lambda: station.http.get("/api/replay/timeline").json()["ready"], 60, "the log's timeline")
        timeline = station.http.get("/api/replay/timeline").json()
        assert timeline["error"] is None and set(timeline["vehicles"]) == {str(FLYER), str(IDLE)}
        one = station.http.get("/api/replay/timeline", params={"sysid": IDLE, "limit": 10}).json()
        assert list(one["vehicles"]) == [str(IDLE)] and len(one["vehicles"][str(IDLE)]["t"]) <= 10
        for bad in ({"sysid": 0}, {"sysid": 256}, {"limit": 0}, {"limit": 3001}, {"sysid": "x"}):
            assert station.http.get("/api/replay/timeline", params=bad).status_code == 422
        duration = timeline["duration"]
        station.http.post("/api/replay/control", json={"seek": duration / 2}, headers=station.http.operator)
        expect(page.locator("#plot-hint")).to_have_text("Click the plot or a marker to go there in the replay",
                                                         timeout=30_000)
        wait_wall(lambda: abs(page.evaluate("window.plots.span[1]") - duration) < 0.01, 20, "the log's axis")
        markers = page.locator("#plot-events .event-marker")
        expect(markers.first).to_be_attached()
        # events on the whole log's axis: a command the station sent, and the vehicle's ACK, are among them
        kinds = {e["kind"] for e in timeline["vehicles"][str(FLYER)]["events"]}
        assert {"mode", "message", "agent"} <= kinds, kinds
        idle = [(e["kind"], e["text"]) for e in timeline["vehicles"][str(IDLE)]["events"]]
        assert ("command", "sent DO_SET_MODE GUIDED") in idle and ("ack", "DO_SET_MODE: accepted") in idle, idle
        last = markers.last
        at = float(last.get_attribute("data-t"))
        last.dispatch_event("click")
        wait_wall(lambda: abs(station.http.get("/api/replay").json()["replay"]["time"] - min(at, duration)) < 0.2,
                  20, f"the replay went to the marker at {at:.1f} s")
        # a click on the plot seeks to the time under it
        page.locator("#plot").scroll_into_view_if_needed()
        box = page.locator("#plot").bounding_box()
        page.mouse.click(box["x"] + box["width"] * 0.25, box["y"] + box["height"] / 2)
        wait_wall(lambda: abs(station.http.get("/api/replay").json()["replay"]["time"] - duration * 0.25) <
                  duration * 0.02 + 0.2, 20, "the replay went to a quarter of the log")
        page.set_viewport_size({"width": 1400, "height": 1300})
        page.locator("#plots").scroll_into_view_if_needed()
        page.wait_for_timeout(2500)  # a plot poll after the resize
        page.locator("#panel").screenshot(path=str(SCREENSHOTS / "operator-replay.png"))
    finally:
        station.http.post("/api/replay/stop", headers=station.http.operator)
    assert station.http.get("/api/replay/timeline").status_code == 409


# ---- 6. the recordings list, live ------------------------------------------------------------------------
def test_the_recordings_list_stays_live(page, station):
    recording = next(r for r in station.http.get("/api/recordings").json() if r["recording"])
    item = page.locator(f'#recordings-list li[data-name="{recording["name"]}"]')
    meta = item.locator(".recording-meta")
    expect(meta).to_have_text(re.compile(r"^recording · "))
    first = meta.inner_text()
    wait_wall(lambda: meta.inner_text() != first, 30, "the recording's size and duration grow in the list")
    # a new session appears without a reload (or a click on Refresh)
    folder = station.station.record_dir
    copied = folder / "session-copied-for-the-list.tlog"
    shutil.copyfile(folder / recording["name"], copied)
    expect(page.locator(f'#recordings-list li[data-name="{copied.name}"]')).to_be_visible()
    copied.unlink()
    expect(page.locator(f'#recordings-list li[data-name="{copied.name}"]')).to_have_count(0)


# ---- 7. screenshots for the README -------------------------------------------------------------------------
def test_screenshots_of_the_operator_view(page, station):
    wait_sim(station, FLYER, lambda v: (v["map"]["occupied"] or 0) > 20, 180, "a map worth showing")
    canvas = page.locator("#map2d")
    wait_wall(lambda: len(canvas_colours(page, "#map2d")) > 20, 30, "the map draws the scene")
    page.click(f'.fleet-item[data-sysid="{FLYER}"]')
    page.select_option("#map2d-layer", "merged")
    expect(canvas).to_have_attribute("data-overlay", "merged")
    page.click("#map2d-measure")
    box = canvas.bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.35)
    page.mouse.click(box["x"] + box["width"] * 0.7, box["y"] + box["height"] * 0.6)
    page.mouse.move(box["x"] + box["width"] * 0.55, box["y"] + box["height"] * 0.3)
    expect(page.locator("#map2d-distance")).to_have_text(re.compile(r"^distance \d+\.\d m$"))
    time.sleep(0.5)
    page.locator("#map2d-pane").screenshot(path=str(SCREENSHOTS / "operator-map2d.png"))
    instruments = page.locator("#instruments")
    instruments.scroll_into_view_if_needed()
    instruments.screenshot(path=str(SCREENSHOTS / "operator-instruments.png"))
    assert json.loads(json.dumps(page.evaluate("window.map2d.view")))["scale"] > 0


# ---- 8. the battery ------------------------------------------------------------------------------------------
def test_a_low_battery_is_marked_on_its_card_and_its_warning_is_a_banner(browser, tmp_path):
    """A vehicle at 15 %, as an ArduPilot reports it (SYS_STATUS) and warns (STATUSTEXT): on a station of its
    own, so that the other tests' pictures show no low battery."""
    from mavlink_peer import Peer, position, vehicle_heartbeat

    with RunningStation(None, tmp_path, TOKEN) as running, \
            Peer(("127.0.0.1", running.mavlink_port), sysid=9) as vehicle:
        def report(remaining: int) -> None:
            vehicle.send(vehicle_heartbeat(), position(),
                         mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 14500, 1400, remaining, 0, 0, 0, 0, 0, 0))

        report(45)
        wait_wall(lambda: running.http.get("/api/vehicles/9").status_code == 200, 10, "the vehicle heard")
        context = browser.new_context(viewport={"width": 1400, "height": 900})
        try:
            page = context.new_page()
            page.route("**/viz/**", lambda route: route.fulfill(body="<!doctype html>", content_type="text/html"))
            page.goto(f"{running.base}/#token={TOKEN}")
            battery = page.locator('.vehicle-card[data-sysid="9"] .battery')
            expect(battery).to_have_text("14.5 V, 45 %")
            expect(battery).not_to_have_class(re.compile(r"\blow\b"))
            report(15)
            vehicle.send(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_CRITICAL,
                                                            b"Battery 1 is low: 14.5 V, 15% left", 0, 0))
            expect(battery).to_have_text("14.5 V, 15 %")
            expect(battery).to_have_class(re.compile(r"\blow\b"))
            expect(page.locator("#warning-banner li", has_text="Battery 1 is low: 14.5 V, 15% left")).to_be_visible()
            report(60)  # charged again (a swapped battery)
            expect(battery).not_to_have_class(re.compile(r"\blow\b"))
        finally:
            context.close()
