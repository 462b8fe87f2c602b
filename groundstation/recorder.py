"""Session recordings: every MAVLink packet the ground station hears or sends, in one .tlog per session.

Files are standard telemetry logs (see ``vehicle.protocol.tlog``), flushed at
least once a second so that a server that is killed loses at most the last
second. Each names the scene the station shows (``vehicle.protocol.scene_note``)
at its start and every minute, so that its replay finds that scene again.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from vehicle.protocol.scene_note import SceneNotes
from vehicle.protocol.tlog import TlogWriter

FLUSH_EVERY = 1.0  # s


class Recorder:
    def __init__(self, directory: str | Path, scene_note: str | None = None):
        """``scene_note``: the note naming the station's scene (``scene_note.note_text``), None for none."""
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = self.directory / f"session-{stamp}.tlog"
        suffix = 1
        while path.exists():
            suffix += 1
            path = self.directory / f"session-{stamp}-{suffix}.tlog"
        self.path = path
        self._writer = TlogWriter(path)
        self._lock = threading.Lock()
        self._flushed = time.monotonic()
        self.messages = 0  # that the station sent or heard (the scene's notes not counted)
        self._first: float | None = None
        self._last: float | None = None
        self._notes = SceneNotes(scene_note) if scene_note else None
        self._write_note(time.time())

    def write(self, packet: bytes, timestamp: float) -> None:
        """A message the station sent or heard."""
        self._record(packet, timestamp, message=True)

    def _record(self, packet: bytes, timestamp: float, message: bool = False) -> None:
        with self._lock:
            self._writer.write(packet, timestamp)
            self.messages += message
            if self._first is None:
                self._first = timestamp
            self._last = timestamp

    @property
    def duration(self) -> float | None:
        """Seconds recorded so far."""
        return None if self._first is None else round(self._last - self._first, 1)

    def _write_note(self, now: float) -> None:
        if self._notes is not None:
            for packet in self._notes.take(now):
                self._record(packet, now)

    def tick(self, now: float | None = None) -> None:
        """Write the scene's note when due and flush if a second has passed since the last flush (called by
        the link's loop)."""
        self._write_note(time.time() if now is None else now)
        if time.monotonic() - self._flushed >= FLUSH_EVERY:
            with self._lock:
                self._writer.flush()
            self._flushed = time.monotonic()

    def close(self) -> None:
        with self._lock:
            self._writer.close()
