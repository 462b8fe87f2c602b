"""STATUSTEXT both ways: texts longer than one message travel in chunks and are put together again.

A STATUSTEXT holds 50 bytes of text. MAVLink 2 adds ``id`` and ``chunk_seq``:
a longer text goes out as several messages with the same non-zero ``id`` and
``chunk_seq`` 0, 1, ...; the last chunk is shorter than 50 bytes (an empty
one follows a text that fills its last chunk exactly). ArduPilot sends long
texts this way and QGroundControl puts them together; so do we. A receiver
that misses a chunk shows what it got once the rest is overdue.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vehicle.protocol.mav import mavlink

ROOM = 50  # bytes of text per message
MAX_CHUNKS = 20  # a text longer than this many chunks is cut
OVERDUE = 2.0  # s after its last chunk an unfinished text is shown as it is


def statustexts(text: str, severity: int, ident: int) -> list:
    """The STATUSTEXT messages of ``text``: one if it fits, else chunks tagged with ``ident`` (1..65535)."""
    data = text.encode("utf-8")
    if len(data) <= ROOM:
        return [mavlink.MAVLink_statustext_message(severity, data, 0, 0)]
    chunks = []
    while data and len(chunks) < MAX_CHUNKS:
        cut = ROOM
        while cut < len(data) and (data[cut] & 0xC0) == 0x80:  # never split a character
            cut -= 1
        chunks.append(data[:cut])
        data = data[cut:]
    if len(chunks[-1]) == ROOM and len(chunks) < MAX_CHUNKS:
        chunks.append(b"")  # the end, where the last chunk was full
    ident = (ident - 1) % 65535 + 1
    return [mavlink.MAVLink_statustext_message(severity, chunk, ident, seq) for seq, chunk in enumerate(chunks)]


def text_of(message) -> str:
    text = message.text
    return (text.decode("utf-8", "replace") if isinstance(text, bytes) else text).rstrip("\0")


@dataclass
class _Partial:
    severity: int
    parts: dict[int, str] = field(default_factory=dict)
    updated: float = 0.0


class Reassembler:
    """Whole texts from STATUSTEXT messages of any number of senders; feed every one, in order of arrival."""

    def __init__(self, limit: int = 64):
        self.limit = limit  # unfinished texts kept at most (from senders that never finish them)
        self._partial: dict[tuple, _Partial] = {}

    def feed(self, message, now: float) -> list[tuple[int, str]]:
        """(severity, text) of the texts completed by this message, and of any that became overdue."""
        done = self.overdue(now)
        ident = getattr(message, "id", 0) or 0
        text = text_of(message)
        if not ident:
            return done + [(message.severity, text)]
        key = (message.get_srcSystem(), message.get_srcComponent(), ident)
        partial = self._partial.setdefault(key, _Partial(message.severity))
        partial.parts[getattr(message, "chunk_seq", 0)] = text
        partial.updated = now
        if len(text.encode("utf-8")) < ROOM or len(partial.parts) >= MAX_CHUNKS:
            del self._partial[key]
            done.append((partial.severity, self._join(partial)))
        while len(self._partial) > self.limit:
            oldest = min(self._partial, key=lambda k: self._partial[k].updated)
            done.append((self._partial[oldest].severity, self._join(self._partial.pop(oldest))))
        return done

    def overdue(self, now: float) -> list[tuple[int, str]]:
        late = [key for key, partial in self._partial.items() if now - partial.updated > OVERDUE]
        return [(self._partial[k].severity, self._join(self._partial.pop(k))) for k in late]

    @staticmethod
    def _join(partial: _Partial) -> str:
        seqs = sorted(partial.parts)
        text = "".join(partial.parts[s] for s in seqs)
        complete = seqs == list(range(len(seqs)))
        return text if complete else text + " [...]"
