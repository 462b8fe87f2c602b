"""The standalone export carries the radio tomography: a recording with the agent's RADIO_LINKS gives a file
whose 3D scene has the image on the ground and the peaks, as the live station showed them."""

from __future__ import annotations

import base64
import math
import re

import numpy as np
import zstandard
from mavlink_peer import Delivered, vehicle_heartbeat
from test_rti_live import TARGET, sweep_rows

from groundstation.export import export_html
from groundstation.replay import Replay
from groundstation.rti_live import LiveImager, frame_at
from groundstation.state import Fleet
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.radiostream import PAYLOAD, RADIO_LINKS, LinkLog, LinkSender
from vehicle.protocol.tlog import LOG_EPOCH, TlogWriter
from vehicle.tomography.links import records_of


def radio_recording(path, rows: list) -> None:
    """A recording of vehicle 1 (at the datum) whose agent sends ``rows`` in RADIO_LINKS, a second at a time."""
    datum = Datum()
    autopilot, agent = Delivered(1, 1), Delivered(1, 191)
    log = TlogWriter(path)
    lat, lon = datum.to_global(0.0, 0.0)
    sender = LinkSender()
    for second in range(math.ceil(max(r.t for r in rows)) + 1):
        stamp = LOG_EPOCH + second
        log.write(autopilot(vehicle_heartbeat()).get_msgbuf(), stamp)
        position = mavlink.MAVLink_global_position_int_message(second * 1000, int(lat * 1e7), int(lon * 1e7), 0, 0,
                                                               0, 0, 0, 0)
        log.write(autopilot(position).get_msgbuf(), stamp)
        for payload in sender.payloads([r for r in rows if second <= r.t < second + 1]):
            body = list(payload.ljust(PAYLOAD, b"\0"))
            tunnel = mavlink.MAVLink_tunnel_message(0, 0, RADIO_LINKS, len(payload), body)
            log.write(agent(tunnel).get_msgbuf(), stamp + 0.5)
    log.close()


def test_the_export_carries_the_image_and_its_peaks(tmp_path):
    path = tmp_path / "radio.tlog"
    radio_recording(path, sweep_rows(0.0, 12.0, person_from=6.0))
    html = export_html(path, None, Datum())
    packed = max(re.findall(r"[A-Za-z0-9+/=]{1000,}", html), key=len)  # viser's recording: zstd, base64
    raw = base64.b64decode(packed)
    scene = zstandard.ZstdDecompressor().decompressobj().decompress(raw[raw.index(b"\x28\xb5\x2f\xfd"):])
    assert b"/layers/rti/image" in scene and b"/layers/rti/peaks" in scene and b"/layers/rti/peak0" in scene


def test_a_replay_seek_shows_the_frame_the_live_station_showed(tmp_path):
    path = tmp_path / "radio.tlog"
    rows = sweep_rows(0.0, 30.0)
    radio_recording(path, rows)
    replay = Replay.open(path, Fleet(Datum(), forget_after=None))
    imager = LiveImager(lambda: replay.fleet.radio)
    replay.seek(replay.duration)
    imager.step()
    assert imager.latest().t == 29.0  # the last record is at 29.75 s
    live = LinkLog()  # what the live station held at 25.5 s of the radios' clock (the records as the fleet got them)
    live.append([r for r in replay.fleet.radio.snapshot() if r.t < 25.5])
    shown = frame_at(records_of(live.snapshot()), 25.0)
    assert math.dist((shown.peaks[0]["x"], shown.peaks[0]["y"]), TARGET) < 0.5
    replay.seek(25.6)  # back: the log is rebuilt from the records up to then (sent at 25.5 s of the log)
    imager.step()
    frame = imager.latest()
    assert frame.t == 25.0 and frame.peaks == shown.peaks and frame.links == shown.links
    np.testing.assert_array_equal(frame.image, shown.image)
