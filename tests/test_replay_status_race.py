"""Replay: the status (page stream and /api/vehicles) must read the replay clock and the fleet as of one
moment; a seek or a playback tick in between used to give heartbeat ages that were off by the jump
(negative, or a false LINK LOST for a frame after a seek backwards)."""

from __future__ import annotations

import threading
import time

from harness import idle_station

from vehicle.cli import main as vehicle_main


def test_heartbeat_ages_stay_sane_while_seeking(tmp_path):
    log = tmp_path / "browse.tlog"
    assert vehicle_main(["experiment", "--mission", "browse", "--time-limit", "120", "--log", str(log)]) == 0
    with idle_station(record_dir=tmp_path) as station:
        replay = station.replays.start(log)
        replay.playing = False
        assert replay.duration > 10
        ages: list[float] = []

        def seek_back_and_forth() -> None:
            for k in range(40):
                replay.seek(2.0 if k % 2 else replay.duration - 2.0)
                time.sleep(0.01)

        seeker = threading.Thread(target=seek_back_and_forth)
        seeker.start()
        while seeker.is_alive():
            ages += [v["link"]["heartbeat_age"] for v in station.status()["vehicles"]]
        seeker.join()
        ages = [a for a in ages if a is not None]
        assert ages
        # heartbeats come at 1 Hz: at any replay time the last one is 0-1.5 s old
        wrong = [a for a in ages if not 0 <= a <= 1.5]
        assert not wrong, f"{len(wrong)} of {len(ages)} ages out of 0..1.5 s, e.g. {sorted(wrong)[:3]}"
