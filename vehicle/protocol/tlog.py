"""Telemetry logs (.tlog): each record is an 8-byte big-endian microsecond timestamp and a raw MAVLink packet.

That is the format mavlogdump.py, MAVExplorer, MAVProxy and QGroundControl
read. Writing it takes two lines, so it is done here rather than through
pymavlink's mavlogfile (which adds nothing to them). A headless experiment's
log carries the same messages ``vehicle sim`` sends, stamped with simulated
time counted from ``LOG_EPOCH``, so the same run always writes the same file.
"""

from __future__ import annotations

import struct
from pathlib import Path

from vehicle.protocol.mav import mavlink, pack

LOG_EPOCH = 1767225600.0  # 2026-01-01T00:00:00Z
_STAMP = struct.Struct(">Q")


class TlogWriter:
    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed by close()

    def write(self, packet: bytes, timestamp: float) -> None:
        """Append one packet received or sent at ``timestamp`` (seconds since the Unix epoch)."""
        self._file.write(_STAMP.pack(int(timestamp * 1e6)) + packet)

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class ExperimentLog:
    """Records a headless run as the vehicle's telemetry; pass it as ``on_step`` to ``run_experiment``."""

    def __init__(self, path: str | Path, sysid: int = 1):
        self.writer = TlogWriter(path)
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.sysid = sysid
        self.telemetry = None
        self.messages = 0

    def __call__(self, world, agent, readings) -> None:
        from vehicle.sim.telemetry import Telemetry

        if self.telemetry is None:
            self.telemetry = Telemetry(world, agent, start=0.0, sysid=self.sysid)
        now = world.time
        messages = self.telemetry.tick(now)
        messages += [self.telemetry.distance_sensor(r, now) for r in readings]
        self._write(messages, now)

    def _write(self, messages, now: float) -> None:
        stamp = LOG_EPOCH + now
        for message in messages:
            self.writer.write(pack(message, self.packer), stamp)
        self.messages += len(messages)

    def close(self) -> None:
        """Finish with a heartbeat and a full map snapshot, so the log ends on the final state."""
        telemetry = self.telemetry
        if telemetry is not None:
            now = telemetry.world.time
            final = [telemetry.heartbeat(now), telemetry.global_position(now)] + telemetry.events(now)
            if telemetry.streamer is not None:
                final += [telemetry._tunnel(kind, payload) for kind, payload in telemetry.streamer.snapshot()]
            self._write(final, now)
        self.writer.close()
