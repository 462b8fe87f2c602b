"""A rover's ground sonars on the operator page, in headless Chromium: listed by their mounts, and kept out of the
proximity ring, where their echoes off the ground a metre or two ahead would look like an obstacle close ahead."""

from __future__ import annotations

import re

import pytest
from harness import canvas_colours, operator_page, skip_module_without_chromium, start_sim, wait_wall

from vehicle.agent.settings import Settings

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "rover-view-test-token"
ROVER = 3
RED, ORANGE = (0xF, 0x4, 0x3), (0xF, 0x8, 0x2)  # the ring's colours for echoes nearer than 1.5 and 3 m (#f0403a,
# #f08a24), 4 bits a channel


@pytest.fixture(scope="module")
def rover(scene, station):
    sim = start_sim(station, scene, ROVER, "rover", "browse", False, None, Settings()).start()
    wait_wall(lambda: station.http.vehicle(ROVER), 20, "the rover is heard")
    yield sim
    sim.stop()


def test_a_rovers_ground_sonars_are_listed_by_their_mounts_and_kept_out_of_the_proximity_ring(browser, station,
                                                                                               rover):
    def ground_echoes() -> bool:
        sonar = station.http.vehicle(ROVER)["sonar"] or []
        near = [s for s in sonar if s["pitch"] < -5 and s["distance"] is not None and s["distance"] < 3]
        level = [s for s in sonar if s["pitch"] > -5]
        return len(near) == 4 and level and all(s["distance"] is None or s["distance"] > 6 for s in level)
    wait_wall(ground_echoes, 30, "the four ground sonars echo off the ground, the level ones see nothing near")
    with operator_page(browser, station.base, TOKEN) as page:
        page.locator(f'#fleet-list .fleet-item[data-sysid="{ROVER}"]').click()
        expect(page.locator("#instruments-vehicle")).to_have_text(f"{ROVER} rover")
        readout = page.locator("#readout-sonar")
        expect(readout).to_contain_text(re.compile(r"0° down 10°: 1\.\d m"))
        expect(readout).to_contain_text(re.compile(r" 0° down 30°: 0\.\d m"))
        expect(readout).to_contain_text(re.compile(r"330° down 30°: 0\.\d m"))
        expect(page.locator("#proximity")).to_have_attribute("data-sonars", "3")  # the level ones: not 7
        colours = canvas_colours(page, "#proximity")
        assert RED not in colours and ORANGE not in colours, sorted(colours)
