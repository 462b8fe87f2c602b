"""A recording with a hostile message in it replays to its end, and its timeline is whole.

Anyone on a link may send a command whose numbers make no sense (a
DO_SET_MODE whose mode is NaN, to a vehicle the station knows); the recorder
saves it before the Fleet sees it. Its replay used to stop there: the
player's thread died with a traceback on stderr while ``/api/replay`` kept
saying "playing" at the time it stopped, and the timeline scan gave up with
the error and no vehicle at all. Now the Fleet takes such numbers, and a
record it cannot take (a bug yet to be found) is counted in the replay's
status and passed over, by playing and by the timeline scan alike.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest
from harness import RunningStation, wait_wall

from groundstation.replay import Player, Replay
from groundstation.state import Fleet
from groundstation.timeline import Timeline
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.tlog import TlogWriter

START = 1714564800.0  # 2024-05-01T12:00:00Z
POSES = 200  # a rover's, one every 0.1 s: the log lasts 19.9 s
POISON_AT = 100  # the pose the hostile commands come after (10 s in)


def poison_log(path: Path) -> Path:
    """Rover 1 drives east 1 m per LOCAL_POSITION_NED (its pose number is its x), a heartbeat every 10 poses; at
    10 s another station (77) sends it a DO_SET_MODE with a NaN mode, this station (255) a COMMAND_INT one with
    an infinite mode, and the rover then says "after the poison"."""
    rover = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    other = mavlink.MAVLink(None, srcSystem=77, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
    ours = mavlink.MAVLink(None, srcSystem=255, srcComponent=mavlink.MAV_COMP_ID_MISSIONPLANNER)
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    log = TlogWriter(path)
    for k in range(POSES):
        now = START + k / 10
        if k % 10 == 0:
            log.write(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GROUND_ROVER,
                                                        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 10,
                                                        mavlink.MAV_STATE_ACTIVE, 3).pack(rover), now)
        log.write(mavlink.MAVLink_local_position_ned_message(k * 100, 0.0, float(k), 0.0, 0.0, 1.0, 0.0).pack(rover),
                  now)
        if k == POISON_AT:
            log.write(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, custom, math.nan,
                                                           0, 0, 0, 0, 0).pack(other), now)
            log.write(mavlink.MAVLink_command_int_message(1, 1, 0, mavlink.MAV_CMD_DO_SET_MODE, 0, 0, custom,
                                                          math.inf, 0, 0, 0, 0, 0).pack(ours), now)
            log.write(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"after the poison", 0, 0)
                      .pack(rover), now)
    log.close()
    return path


@pytest.fixture
def poisoned(tmp_path) -> Path:
    return poison_log(tmp_path / "poison.tlog")


@pytest.fixture
def unfit(monkeypatch):
    """A Fleet that raises on any command it hears (standing in for a bug a hostile field may yet find)."""
    def refuse(self, m, now):
        raise ValueError(f"cannot take {m.get_type()}")

    monkeypatch.setattr(Fleet, "_command_sent", refuse)


def play_to_the_end(replay: Replay) -> None:
    """The replay played by its own Player thread, at 50x, until it stops at its end."""
    replay.speed, replay.playing = 50.0, True
    player = Player(replay).start()
    try:
        wait_wall(lambda: not replay.playing, 10, "the replay to reach its end")
    finally:
        player.stop()


def test_a_replay_plays_past_a_command_with_a_nan_mode_to_its_end(poisoned):
    replay = Replay.open(poisoned, Fleet(Datum()))
    play_to_the_end(replay)
    rover = replay.fleet.get(1)
    assert replay.clock == replay.duration == pytest.approx((POSES - 1) * 0.1)
    assert rover.x == POSES - 1 and rover.status == "after the poison"
    history = replay.fleet.history.of(1)
    events = [e.text for e in (*history.kept, *history.events) if e.kind == "command"]  # commands are kept
    assert events == ["sent DO_SET_MODE nan", "sent DO_SET_MODE inf"]
    assert replay.status()["errors"] == 0 and replay.status()["last_error"] is None


def test_the_timeline_of_a_log_with_a_nan_mode_command_has_the_vehicle_and_the_command(poisoned):
    timeline = Timeline(Replay.open(poisoned, Fleet(Datum())))
    assert timeline.wait(30)
    assert timeline.error is None and timeline.skipped == 0 and list(timeline.history.vehicles) == [1]
    shown = timeline.history.of(1).as_json(None, 100)
    assert [e["text"] for e in shown["events"] if e["kind"] == "command"] == ["sent DO_SET_MODE nan",
                                                                              "sent DO_SET_MODE inf"]
    assert shown["t"][-1] > START + 19  # sampled to the end, not up to the poison


def test_a_record_the_fleet_cannot_take_is_counted_and_passed_over(poisoned, unfit):
    replay = Replay.open(poisoned, Fleet(Datum()))
    timeline = Timeline(replay)
    play_to_the_end(replay)
    assert replay.clock == replay.duration and replay.fleet.get(1).x == POSES - 1
    assert replay.fleet.get(1).status == "after the poison"  # the record after them was applied
    status = replay.status()
    assert status["errors"] == 2
    assert status["last_error"] == "ValueError: cannot take COMMAND_INT (COMMAND_INT at 10.000 s)"
    assert timeline.wait(30) and timeline.error is None and timeline.skipped == 2
    assert list(timeline.history.vehicles) == [1] and timeline.history.of(1).as_json(None, 100)["t"][-1] > START + 19


def test_a_player_whose_tick_fails_pauses_says_why_and_plays_on_when_told(poisoned, monkeypatch):
    """Beyond the records: anything else that fails in a tick must not end the thread while the status says it
    plays (it used to go on saying "playing" at the time the thread died)."""
    replay = Replay.open(poisoned, Fleet(Datum()))
    advance = replay.advance
    monkeypatch.setattr(replay, "advance", lambda seconds: 1 / 0)
    replay.speed, replay.playing = 50.0, True
    player = Player(replay).start()
    try:
        wait_wall(lambda: replay.errors, 10, "the failed tick to be counted")
        status = replay.status()
        assert status["playing"] is False and status["last_error"].startswith("ZeroDivisionError")
        monkeypatch.setattr(replay, "advance", advance)
        replay.control(play=True)
        wait_wall(lambda: not replay.playing, 10, "the replay to reach its end")
        assert replay.clock == replay.duration and replay.errors == 1
    finally:
        player.stop()


def test_the_api_replays_a_poisoned_recording_to_its_end_and_reports_what_it_passed_over(tmp_path, unfit):
    """As the operator saw it: ``/api/replay`` stood at the poison's time saying "playing", even after a seek,
    and ``/api/replay/timeline`` had an error and no vehicle."""
    with RunningStation(None, tmp_path / "recordings") as running, running.api() as api:
        shutil.copy(poison_log(tmp_path / "poison.tlog"), running.station.record_dir / "poison.tlog")
        started = api.post("/api/replay", json={"name": "poison.tlog"}, headers=api.operator)
        assert started.status_code == 200, started.text
        sought = api.post("/api/replay/control", json={"seek": 5.0, "speed": 20.0, "play": True},
                          headers=api.operator).json()
        assert sought["time"] == pytest.approx(5.0, abs=0.1)
        wait_wall(lambda: not api.get("/api/replay").json()["replay"]["playing"], 20, "the replay to end")
        status = api.get("/api/replay").json()["replay"]
        assert status["time"] == pytest.approx((POSES - 1) * 0.1) and status["errors"] == 2
        assert "ValueError: cannot take COMMAND_INT" in status["last_error"]
        health = api.get("/api/health").json()  # counted where the station's health is asked, too
        assert health["replay"] == {"name": "poison.tlog", "errors": 2, "last_error": status["last_error"]}
        assert api.vehicle(1)["position"]["x"] == pytest.approx(POSES - 1)
        wait_wall(lambda: api.get("/api/replay/timeline").json()["ready"], 30, "the timeline")
        timeline = api.get("/api/replay/timeline").json()
        assert timeline["error"] is None and timeline["skipped"] == 2 and list(timeline["vehicles"]) == ["1"]
        again = api.post("/api/replay/control", json={"seek": 1.0, "play": True}, headers=api.operator).json()
        assert again["time"] == 1.0  # and the player's thread, alive, plays on from there
        wait_wall(lambda: api.get("/api/replay").json()["replay"]["time"] > 2.0, 10, "the replay to play on")
