"""The card shows each vehicle's own battery failsafe levels, read from its autopilot, in a real headless Chromium:
our simulated copter's and rover's (low 20 % of their capacity: a warning; critical 10 %: Land, Hold), and "not
read yet" for an autopilot that does not answer (a fake ArduPilot on real UDP that streams its battery only).

Waits on the page are on the wall clock, generously: the station asks at once when it hears a vehicle.
"""

from __future__ import annotations

import re

import pytest
from harness import operator_page, skip_module_without_chromium, small_scene, start_sim, wait_wall
from mavlink_peer import FakeVehicle
from test_battery_failsafe import battery_status

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "battery-failsafe-token"
COPTER, ROVER, SILENT = 1, 2, 3
UI_TIMEOUT = 30_000

expect.set_options(timeout=UI_TIMEOUT)


@pytest.fixture(scope="module")
def scene():
    return small_scene()


@pytest.fixture(scope="module")
def vehicles(scene, station):
    """The harness's vehicles carry 50 Ah (``make_vehicle``): low at 10000 mAh, critical at 5000 mAh."""
    copter = start_sim(station, scene, COPTER, "copter").start()
    rover = start_sim(station, scene, ROVER, "rover", start=(4.0, 0.0)).start()
    silent = FakeVehicle(("127.0.0.1", station.mavlink_port), SILENT,
                         answer=lambda vehicle, message: vehicle.send(battery_status()), beat=0.3)
    try:
        for sysid in (COPTER, ROVER, SILENT):
            wait_wall(lambda sysid=sysid: (station.http.vehicle(sysid) or {}).get("battery"), 30,
                      f"vehicle {sysid}'s battery")
        yield
    finally:
        silent.close()
        rover.stop()
        copter.stop()


def ends(text: str) -> re.Pattern:
    """The battery line's tooltip: what the card says of the current drawn, then this."""
    return re.compile(re.escape(text) + "$")


def test_the_card_shows_the_vehicles_own_failsafe_levels(browser, station, vehicles):
    copter = station.http.wait_vehicle(COPTER, lambda v: v["battery"]["failsafe"], what="the copter's levels")
    assert copter["battery"]["failsafe"] == {
        "capacity_mah": 50000.0, "low": {"volt": 0.0, "mah": 10000.0, "percent": 20.0, "action": "None"},
        "critical": {"volt": 0.0, "mah": 5000.0, "percent": 10.0, "action": "Land"}}
    with operator_page(browser, station.base, TOKEN, timeout_ms=UI_TIMEOUT) as page:
        line = page.locator(f'.vehicle-card[data-sysid="{COPTER}"] .battery-failsafe')
        expect(line).to_have_text("low 20 % (10000 mAh) → warn; critical 10 % (5000 mAh) → Land")
        expect(line).to_be_visible()
        expect(page.locator(f'.vehicle-card[data-sysid="{COPTER}"] .failsafe-label')).to_have_text("Failsafe")
        expect(page.locator(f'.vehicle-card[data-sysid="{COPTER}"] .battery')).to_have_attribute(
            "title", ends("The vehicle's own battery failsafe (its BATT_LOW_*, BATT_CRT_* and BATT_FS_*_ACT "
            "parameters, capacity 50000 mAh): low 20 % (10000 mAh) → warn; critical 10 % (5000 mAh) → Land. "
            "\"warn\" is a warning only; \"?\" not answered yet."))
        expect(page.locator(f'.vehicle-card[data-sysid="{ROVER}"] .battery-failsafe')).to_have_text(
            "low 20 % (10000 mAh) → warn; critical 10 % (5000 mAh) → Hold")
        silent = page.locator(f'.vehicle-card[data-sysid="{SILENT}"] .battery')
        expect(page.locator(f'.vehicle-card[data-sysid="{SILENT}"] .battery-failsafe')).to_have_text("not read yet")
        expect(silent).to_have_attribute("title", ends("Failsafe levels not read yet: the station asks the autopilot "
                                         "for its BATT_LOW_* and BATT_CRT_* parameters when it hears it (an "
                                         "autopilot that never answers has none shown). Marked low at 20 % meanwhile."))
        expect(silent).to_have_text("15.8 V, 80 %")  # the battery line itself as before
