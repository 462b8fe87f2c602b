"""Session recordings: what the ground station accepts and sends, in .tlog files that a night of flooding cannot
grow without end.

Files are standard telemetry logs (see ``vehicle.protocol.tlog``), flushed at
least once a second so that a server that is killed loses at most the last
second. Each names the scene the station shows (``vehicle.protocol.scene_note``)
at its start and every minute, so that its replay finds that scene again.

What is kept (``Limits``): everything from systems the station knows (its
vehicles) and everything it sends; of any other sender, the first
``stranger_messages`` a minute (the rest are counted, not written). A recording
that reaches ``max_bytes`` or lasts ``max_seconds`` is closed and the next one
begun, a new .tlog in the same folder. No recording is begun while the disk
has less than ``min_free_bytes`` free: the station says why (``refused``) and
looks again every minute.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vehicle.protocol.scene_note import SceneNotes
from vehicle.protocol.tlog import TlogWriter

FLUSH_EVERY = 1.0  # s
LOOK_AGAIN_EVERY = 60.0  # s between looks at the disk while a recording is refused
RECORD_HEADER = 8  # bytes of a .tlog record's timestamp
log = logging.getLogger("groundstation")


@dataclass(frozen=True)
class Limits:
    """How much a station records (the defaults keep a week of sessions well within a small disk)."""

    max_bytes: int = 256 * 10**6  # a recording this long is closed, the next begun
    max_seconds: float = 3600.0  # likewise, a recording that lasts this long
    min_free_bytes: int = 10**9  # no recording is begun on a disk with less free
    stranger_messages: int = 100  # kept per minute from each sender the station does not know


class Recorder:
    def __init__(self, directory: str | Path, scene_note: str | None = None, limits: Limits = Limits(),
                 known: Callable[[int], bool] = lambda sysid: True):
        """``scene_note``: the note naming the station's scene (``scene_note.note_text``), None for none;
        ``known``: whether a system id is one of the station's vehicles."""
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.limits, self._known, self._scene_note = limits, known, scene_note
        self._lock = threading.RLock()
        self._flushed = time.monotonic()
        self._strangers: dict[int, tuple[int, int]] = {}  # system id -> (its minute, messages kept in it)
        self.strangers_dropped = 0  # messages of senders the station does not know, past their quota
        self.not_kept = 0  # messages heard or sent while no recording could be begun
        self.refused = ""  # why nothing is recorded now ("" while recording)
        self.path: Path | None = None
        self._writer: TlogWriter | None = None
        self._writer_was = True  # whether the last look at the disk found room (a refusal is logged once)
        self.messages = 0
        self._begin(time.time())

    # ---- files --------------------------------------------------------------------------------------
    def _begin(self, now: float) -> None:
        """A new recording, unless the disk is nearly full (then ``refused`` says so)."""
        self._looked = time.monotonic()
        free = shutil.disk_usage(self.directory).free
        if free < self.limits.min_free_bytes:
            self.path, self._writer = None, None
            self.refused = (f"not recording: the disk of {self.directory} has {free / 1e6:,.0f} MB free, less than "
                            f"the {self.limits.min_free_bytes / 1e6:,.0f} MB kept free")
            if self._writer_was:
                log.warning("%s", self.refused)
            self._writer_was = False
            return
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = self.directory / f"session-{stamp}.tlog"
        suffix = 1
        while path.exists():
            suffix += 1
            path = self.directory / f"session-{stamp}-{suffix}.tlog"
        self._writer, self.path, self.refused = TlogWriter(path), path, ""
        self._writer_was = True
        self.bytes = 0
        self.messages = 0  # in this recording that the station sent or heard (the scene's notes not counted)
        self._first: float | None = None
        self._last: float | None = None
        self._notes = SceneNotes(self._scene_note) if self._scene_note else None
        self._write_note(now)

    def _rotate(self, now: float) -> None:
        old = self.path
        self._writer.close()
        self._begin(now)
        log.info("recording %s closed at its limit; recording to %s", old.name, self.path.name if self.path else
                 "nothing")

    # ---- writing ------------------------------------------------------------------------------------
    def write(self, packet: bytes, timestamp: float, sender: int | None = None) -> None:
        """A message the station sent (``sender`` None) or heard from system ``sender``."""
        if sender is not None and not self._known(sender) and not self._admit(sender, timestamp):
            self.strangers_dropped += 1
            return
        self._record(packet, timestamp, message=True)

    def _admit(self, sender: int, now: float) -> bool:
        """Whether a message of a sender the station does not know is still within its quota this minute."""
        minute = int(now // 60)
        counted, kept = self._strangers.get(sender, (minute, 0))
        kept = kept if counted == minute else 0
        self._strangers[sender] = (minute, kept + 1)  # system ids are 8-bit: at most 256 entries
        return kept < self.limits.stranger_messages

    def _record(self, packet: bytes, timestamp: float, message: bool = False) -> None:
        with self._lock:
            if self._writer is None:
                self.not_kept += message
                return
            size = RECORD_HEADER + len(packet)
            if self.messages and (self.bytes + size > self.limits.max_bytes
                                  or timestamp - self._first >= self.limits.max_seconds):
                self._rotate(timestamp)
                if self._writer is None:
                    self.not_kept += message
                    return
            self._writer.write(packet, timestamp)
            self.bytes += size
            self.messages += message
            if self._first is None:
                self._first = timestamp
            self._last = timestamp

    @property
    def duration(self) -> float | None:
        """Seconds recorded so far in this recording."""
        return None if self._writer is None or self._first is None else round(self._last - self._first, 1)

    def _write_note(self, now: float) -> None:
        if self._writer is not None and self._notes is not None:
            for packet in self._notes.take(now):
                self._record(packet, now)

    def tick(self, now: float | None = None) -> None:
        """Write the scene's note when due, flush if a second has passed since the last flush, and look at the
        disk again while refused (called by the link's loop)."""
        now = time.time() if now is None else now
        with self._lock:
            if self._writer is None:
                if time.monotonic() - self._looked >= LOOK_AGAIN_EVERY:
                    self._begin(now)
                return
            self._write_note(now)
            if time.monotonic() - self._flushed >= FLUSH_EVERY:
                self._writer.flush()
                self._flushed = time.monotonic()

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.close()
