"""Against ArduCopter's own firmware (SITL, ``../shared/sitl``): the station reads its battery failsafe parameters
and the card shows them, in a real headless Chromium.

The station alone holds SERIAL0 (the simulation starts once it has a client). ArduCopter's defaults for the
levels (with autotest's copter.parm): a low voltage of 10.5 V, everything else 0 (off; a warning only). Waits are
in the autopilot's time, with the harness's wall-clock backstop.
"""

from __future__ import annotations

import pytest
from harness import RunningStation, load_default_scene, operator_page, skip_module_without_chromium
from test_sitl import SPEEDUP, sitl

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "battery-failsafe-sitl-token"
INSTANCE = 11  # TCP 5870: apart from test_sitl's instances


def test_arducopter_answers_and_the_card_shows_its_levels(browser, tmp_path):
    with sitl("copter", INSTANCE, tmp_path) as (first, _), \
            RunningStation(load_default_scene(), tmp_path / "recordings", TOKEN,
                           urls=[f"tcp:127.0.0.1:{first}"]) as station, station.api() as api:
        copter = api.wait_vehicle(1, lambda v: v["battery"] and v["battery"]["failsafe"]
                                  and v["battery"]["failsafe"]["critical"]["action"] is not None
                                  and v["battery"]["failsafe"]["low"]["action"] is not None
                                  and v["battery"]["failsafe"]["capacity_mah"] is not None, 60, SPEEDUP,
                                  "ArduCopter's failsafe levels")
        failsafe = copter["battery"]["failsafe"]
        assert failsafe["low"] == {"volt": 10.5, "mah": 0.0, "percent": None, "action": "None"}
        assert failsafe["critical"] == {"volt": 0.0, "mah": 0.0, "percent": None, "action": "None"}
        assert failsafe["capacity_mah"] > 0
        assert copter["battery"]["params_ignored"] == 0
        with operator_page(browser, station.base, TOKEN) as page:
            expect(page.locator('.vehicle-card[data-sysid="1"] .battery-failsafe')).to_have_text(
                "low 10.5 V → warn; critical off → warn", timeout=30_000)
