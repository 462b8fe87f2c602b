"""Which scene a log was made in: a note ``scene NAME sha256 HEX`` inside the log itself.

A replay must show the scene the flight happened in, and a log travels
without the command line that made it. So every log names its scene's file
and the first 16 hex digits of the SHA-256 of its bytes (as ``sha256sum``
prints them), at its start and again every ``NOTE_PERIOD``, so that a log cut
or trimmed anywhere still says it within a minute.

The note is a STATUSTEXT, chunked when long (``statustext``), because that is
the one standard message for free text that every tool shows: mavlogdump.py
prints it, MAVExplorer and QGroundControl list it with the other messages,
and a ground station that does not know it shows it as a harmless line. It
comes from the ground station's system id (255) and the logging component
(MAV_COMP_ID_LOG, 155): vehicles never receive it (it is written to the log,
not sent), a replay does not take it for a vehicle, and the station's own
component keeps its sequence numbers unbroken. No other standard message
carries a file name; a PARAM or NAMED_VALUE would need a private convention
just the same, and fewer tools show them.

A log is hostile input: ``read_note`` accepts only a bare file name (letters,
digits, ``._+-``, no leading dot, a VRML suffix) and a 16-digit hex digest, so
whatever a log says can only name a file in a folder the station chose.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.statustext import statustexts

NOTE_PERIOD = 60.0  # s between notes (the log's clock: wall time live, simulated time in an experiment)
GCS_SYSTEM = 255  # the ground station's system id, as MAVProxy's and QGroundControl's
LOG_COMPONENT = mavlink.MAV_COMP_ID_LOG
DIGEST_LENGTH = 16  # hex digits of the SHA-256 kept: 64 bits, enough to tell versions of a file apart
SUFFIXES = (".wrl", ".wrl.gz", ".wrz", ".vrml", ".vrml.gz")
MAX_NAME = 100
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*")
_NOTE = re.compile(rf"scene (?P<name>\S+) sha256 (?P<digest>[0-9a-f]{{{DIGEST_LENGTH}}})")


def is_scene_name(name: str) -> bool:
    """A bare file name of a VRML scene that a note may carry (and a station may look up)."""
    return (len(name) <= MAX_NAME and _NAME.fullmatch(name) is not None and ".." not in name
            and name.lower().endswith(SUFFIXES))


def scene_digest(path: str | Path) -> str:
    """The first DIGEST_LENGTH hex digits of the SHA-256 of the file's bytes (``sha256sum`` agrees)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()[:DIGEST_LENGTH]


def note_text(path: str | Path) -> str | None:
    """The note for the scene file at ``path``; None when its name cannot be carried (say, it has a space)."""
    name = Path(path).name
    if not is_scene_name(name):
        return None
    return f"scene {name} sha256 {scene_digest(path)}"


def read_note(text: str) -> tuple[str, str] | None:
    """(file name, digest) of a note, or None if the text is no valid note."""
    match = _NOTE.fullmatch(text.strip())
    if match is None or not is_scene_name(match["name"]):
        return None
    return match["name"], match["digest"]


class SceneNotes:
    """The packets of one scene's note, due at the start of a log and every ``period`` after, on its clock."""

    def __init__(self, text: str, period: float = NOTE_PERIOD):
        self.text = text
        self.period = period
        self.packer = mavlink.MAVLink(None, srcSystem=GCS_SYSTEM, srcComponent=LOG_COMPONENT)
        self.due = float("-inf")
        self.written = 0

    def take(self, now: float) -> list[bytes]:
        """The note's packets if it is due at ``now`` (then next due a period later), else nothing."""
        if now < self.due:
            return []
        self.due = now + self.period
        self.written += 1
        messages = statustexts(self.text, mavlink.MAV_SEVERITY_INFO, self.written)
        return [pack(message, self.packer) for message in messages]
