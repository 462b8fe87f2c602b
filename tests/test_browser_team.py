"""Browser test of a team on the page: a near miss between two vehicles is on both cards and in the event log and
on the event strip, naming both (two vehicles' own MAVLink bytes to a real station, a real Chromium)."""

from __future__ import annotations

import pytest
from harness import RunningStation, operator_page, skip_module_without_chromium, wait_wall
from mavlink_peer import Peer, fly_pair

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist


def test_a_near_miss_is_on_both_cards_and_in_the_event_log(browser):
    with RunningStation(None, None) as station, Peer(("127.0.0.1", station.mavlink_port), 1) as one, \
            Peer(("127.0.0.1", station.mavlink_port), 2) as two:
        api = station.api()

        def fly(north_of_one: list[float]) -> None:
            fly_pair(one, two, north_of_one)

        fly([10.0] * 5)
        wait_wall(lambda: all(api.vehicle(s) and api.vehicle(s)["position"] for s in (1, 2)), 10, "both placed")
        with operator_page(browser, station.base, station.token) as page:
            cards = {s: page.locator(f'.vehicle-card[data-sysid="{s}"]') for s in (1, 2)}
            for card in cards.values():
                expect(card.locator(".near-misses")).to_have_text("none")
            fly([6.0, 4.0, 2.0, 1.5, 1.5])  # within 2 m and both bodies' radii
            for card in cards.values():
                expect(card.locator(".near-misses")).to_have_text("1 (see the event log)")
                expect(card.locator(".near-misses")).to_have_class("near-misses warning")
            log = page.locator("#event-log li", has_text="near miss: vehicles 1 and 2")
            expect(log).to_have_count(1)
            expect(log).to_have_attribute("data-source", "station")
            expect(page.locator(".event-marker.near-miss")).to_have_count(1)
