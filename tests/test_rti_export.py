"""The standalone export carries the radio tomography: a recording with the agent's RADIO_LINKS gives a file
whose 3D scene has the image on the ground and the peaks, as the live station showed them."""

from __future__ import annotations

import base64
import re

import zstandard
from mavlink_peer import Delivered, vehicle_heartbeat
from test_rti_live import sweep_rows

from groundstation.export import export_html
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.radiostream import PAYLOAD, RADIO_LINKS, LinkSender
from vehicle.protocol.tlog import LOG_EPOCH, TlogWriter


def test_the_export_carries_the_image_and_its_peaks(tmp_path):
    datum = Datum()
    autopilot, agent = Delivered(1, 1), Delivered(1, 191)
    path = tmp_path / "radio.tlog"
    log = TlogWriter(path)
    lat, lon = datum.to_global(0.0, 0.0)
    rows = sweep_rows(0.0, 12.0, person_from=6.0)
    sender = LinkSender()
    for second in range(12):
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
    html = export_html(path, None, datum)
    packed = max(re.findall(r"[A-Za-z0-9+/=]{1000,}", html), key=len)  # viser's recording: zstd, base64
    raw = base64.b64decode(packed)
    scene = zstandard.ZstdDecompressor().decompressobj().decompress(raw[raw.index(b"\x28\xb5\x2f\xfd"):])
    assert b"/layers/rti/image" in scene and b"/layers/rti/peaks" in scene and b"/layers/rti/peak0" in scene
