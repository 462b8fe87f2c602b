"""Commands that mean what they say, driven through the page's own buttons in a real headless Chromium, with
the vehicle's answer watched in /api/vehicles and on its card: Pause holds the copter and pauses its agent,
Continue resumes; Take control stops the agent until handed back (said on the card), and GUIDED while the agent
flies does the same and says so; AUTO / Resume while the mission runs is refused with a reason; Kill is pressed
and held (let go early: the card says nothing was sent), and its fall is a crash on the card and in the history,
whose log below the plot filters by severity and source.

One copter (system id 1) flies the search mission in the default scene. Waits on the vehicle are bounded in
its simulated time; waits on the page on the wall clock, generously.
"""

from __future__ import annotations

import math
import re

import pytest
from harness import operator_page, skip_module_without_chromium, start_sim, wait_wall

from vehicle.agent.settings import Settings

pytestmark = pytest.mark.browser

skip_module_without_chromium()

from playwright.sync_api import expect  # noqa: E402 - once Chromium is known to exist

TOKEN = "commands-test-token"
SPEEDUP = 5.0
COPTER = 1
UI_TIMEOUT = 20_000
BRAKING = 2.5  # s of simulated time a copter flying its search takes to stand after a hold

expect.set_options(timeout=UI_TIMEOUT)


@pytest.fixture(scope="module")
def copter(scene, station):
    running = start_sim(station, scene, COPTER, "copter", "search", True, None, Settings(), SPEEDUP).start()
    wait_wall(lambda: station.http.vehicle(COPTER), 20, "the copter is heard")
    yield running
    running.stop()


@pytest.fixture
def page(browser, station, copter):
    with operator_page(browser, station.base, TOKEN, timeout_ms=UI_TIMEOUT) as found:
        yield found


def agent_is(station, state: str, sim_timeout: float = 30.0) -> dict:
    return station.http.wait_vehicle(COPTER, lambda v: v["agent"] and v["agent"]["state"] == state, sim_timeout,
                                     SPEEDUP, f"the agent {state}")


def where(vehicle: dict) -> tuple[float, float]:
    return vehicle["position"]["x"], vehicle["position"]["y"]


def holds(station, at: dict, sim_seconds: float = 4.0) -> None:
    """The copter stands within BRAKING s of ``at`` (as the agent said it stopped), not going on to the agent's
    last target, and stays within half a metre for ``sim_seconds``."""
    first = station.http.wait_vehicle(COPTER, lambda v: v["speed"] < 0.2, 20, SPEEDUP, "the copter braked")
    assert first["time_boot_s"] - at["time_boot_s"] < BRAKING, f"{where(at)} to {where(first)}: still moving"
    later = station.http.wait_vehicle(COPTER, lambda v: v["time_boot_s"] >= first["time_boot_s"] + sim_seconds, 20,
                                      SPEEDUP, f"{sim_seconds} s more")
    moved = math.dist(where(first), where(later))
    assert moved < 0.5, f"moved {moved:.2f} m while it should hold"


def test_pause_continue_take_control_guided_and_a_refused_resume(page, station):
    station.http.wait_vehicle(COPTER, lambda v: v["agent"] and v["agent"]["phase"] == "mission"
                              and v["position"]["alt"] > 1.0, 90, SPEEDUP, "the search under way")
    card = page.locator(f'.vehicle-card[data-sysid="{COPTER}"]')
    ack, badge, banner = card.locator(".ack"), card.locator(".agent-state"), card.locator(".control-banner")
    expect(card.locator(".agent")).to_contain_text(re.compile(r"search running .* · \d+ min left of its time budget"))

    card.locator('[data-action="pause"]').click()
    expect(ack).to_contain_text("Pause: accepted: the vehicle holds where it is")
    before = vehicle = agent_is(station, "paused")
    assert vehicle["agent"]["operator"] == "pause" and "paused by the operator" in vehicle["agent"]["reason"]
    expect(badge).to_have_text("PAUSED")
    expect(banner).to_have_text("Paused by you: the vehicle holds here until Continue.")
    holds(station, before)

    card.locator('[data-action="continue"]').click()
    expect(ack).to_contain_text("Continue: accepted")
    agent_is(station, "running")
    expect(banner).to_be_hidden()

    card.locator('[data-action="resume"]').click()  # the mission runs: a resume cannot mean anything
    expect(ack).to_contain_text("AUTO / Resume: refused: the agent's mission is already running")
    assert station.http.vehicle(COPTER)["agent"]["state"] == "running"

    station.http.wait_vehicle(COPTER, lambda v: v["speed"] > 0.5, 30, SPEEDUP, "the search moving again")
    card.locator('[data-action="take_control"]').click()
    expect(ack).to_contain_text("Take control: accepted: the agent holds the vehicle")
    before = agent_is(station, "operator")
    expect(banner).to_have_text(re.compile("^You have control"))
    expect(card.locator('[data-action="continue"]')).to_have_text("Hand back")
    holds(station, before)
    card.locator('[data-action="continue"]').click()
    agent_is(station, "running")

    card.locator('[data-action="guided"]').click()  # in GUIDED already: before, "accepted" and nothing changed
    expect(ack).to_contain_text("GUIDED: accepted: the agent stopped and handed you control")
    assert agent_is(station, "operator")["mode"] == "GUIDED"
    card.locator('[data-action="continue"]').click()
    agent_is(station, "running")


def test_kill_is_held_its_fall_is_a_crash_and_the_log_filters(page, station):
    station.http.wait_vehicle(COPTER, lambda v: v["armed"] and v["position"]["alt"] > 2.0, 90, SPEEDUP,
                              "the copter flying above 2 m")
    card = page.locator(f'.vehicle-card[data-sysid="{COPTER}"]')
    ack, kill = card.locator(".ack"), card.locator('[data-action="kill"]')

    kill.hover()
    page.mouse.down()
    page.wait_for_timeout(300)
    page.mouse.up()  # let go too soon: nothing is sent, and the card says so
    expect(ack).to_contain_text(re.compile(r"Kill: not sent: released after 0\.\d s; hold 1\.5 s to kill"))
    expect(kill).to_have_text("Kill")
    assert station.http.vehicle(COPTER)["armed"]

    kill.hover()
    page.mouse.down()
    expect(kill).to_have_text("Keep holding to kill…")
    page.wait_for_timeout(2000)
    page.mouse.up()
    expect(ack).to_contain_text("Kill: accepted")
    fallen = station.http.wait_vehicle(COPTER, lambda v: v["crash"] and v["crash"]["text"].startswith("crashed"),
                                       30, SPEEDUP, "the fall reported as a crash")
    assert not fallen["armed"]
    expect(card.locator(".crash-banner")).to_contain_text("CRASH: crashed: fell")

    events = station.http.get(f"/api/vehicles/{COPTER}/history").json()["events"]
    crashes = [e for e in events if e["kind"] == "crash"]
    assert [e["source"] for e in crashes] == ["station", "station"] and crashes[0]["severity"] == 2
    assert any(e["text"] == "sent kill" and e["source"] == "operator" for e in events)

    log = page.locator("#event-log li")
    for source in ("autopilot", "agent", "station"):
        page.locator(f'.event-source[value="{source}"]').uncheck()
    expect(log.filter(has_text="sent kill")).to_have_count(1)
    assert set(log.evaluate_all("items => items.map((li) => li.dataset.source)")) == {"operator"}
    page.locator('.event-source[value="operator"]').uncheck()
    page.locator('.event-source[value="station"]').check()
    page.locator("#event-severity").select_option("3")  # errors and worse: the crash, nothing routine
    expect(log).to_have_count(2)
    expect(log.first).to_contain_text("crashed: fell")
    markers = page.locator("#plot-events .event-marker")
    expect(markers).to_have_count(2)
    expect(markers.first).to_have_class(re.compile(r"\bcrash\b"))
