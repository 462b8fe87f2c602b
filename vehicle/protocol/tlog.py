"""Telemetry logs (.tlog): each record is an 8-byte big-endian microsecond timestamp and a raw MAVLink packet.

That is the format mavlogdump.py, MAVExplorer, MAVProxy and QGroundControl
read. Writing it takes two lines, so it is done here rather than through
pymavlink's mavlogfile (which adds nothing to them). Logs of headless runs
are stamped with simulated time counted from ``LOG_EPOCH``.
"""

from __future__ import annotations

import struct
from pathlib import Path

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

    def write_records(self, records: bytes) -> None:
        """Append records already in the format (each a timestamp and a packet), as many as given."""
        self._file.write(records)

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()
