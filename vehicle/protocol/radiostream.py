"""Radio link records over MAVLink TUNNEL messages: both ends of the stream, and the station's log of them.

A vehicle's radio hears packets from the other radios (vehicles and fixed nodes); each one it hears is a link
record: ``t, tx, rx, tx_x, tx_y, rx_x, rx_y, rssi, channel`` (the columns of ``vehicle.tomography.links``: the
vehicle's clock in seconds, the sender's and receiver's ids (system ids, or a fixed node's id), both positions in
metres east and north of home, the RSS in dBm, the radio channel, 0 when unknown). The agent sends them in
batches, one TUNNEL payload type of ours beside the map stream's (``mapstream``; all integers little-endian):

* ``RADIO_LINKS`` (32805): ``<BIdB`` = format version (1), batch sequence number, base time (s), record count n
  (at most 4), then n records ``<HHHffffhB``: sender id, receiver id, time after the base time in ms, sender x,
  y, receiver x, y (float32 metres), RSS in hundredths of a dBm, channel.

Every payload stands alone, so a lost one loses only its records. The receiver remembers the last ``REMEMBER``
batches it took (their bytes, sequence number included): a duplicate (a payload sent twice, or recorded twice)
adds nothing, a late one (reordered) still counts, and a sender that starts again from 1 is heard again (its
batches differ). A payload that is not one (too short, an unknown version, a count its length does not hold) is dropped
and counted in ``damaged``; a record with a non-finite or absurd value (a position over ``MAX_REACH`` from home,
an RSS outside -150..30 dBm, a radio heard by itself) is dropped and counted in ``dropped``.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

from vehicle.protocol.map_bounds import MAX_REACH

RADIO_LINKS = 32805  # 32803 and 32804 are the agent's status and progress (agent_status)
PAYLOAD = 128
FORMAT_VERSION = 1
HEADER = struct.Struct("<BIdB")
RECORD = struct.Struct("<HHHffffhB")
PER_PAYLOAD = (PAYLOAD - HEADER.size) // RECORD.size
MAX_SPAN = 65.535  # s: a batch's records lie within this of its base time (ms in a uint16)
RSS_RANGE = (-150.0, 30.0)  # dBm a record may claim
REMEMBER = 4096  # batches a receiver remembers (a duplicate older than this counts again)


@dataclass(frozen=True)
class LinkRecord:
    """One packet heard: who sent it, who heard it, from where to where, how strong."""

    t: float
    tx: int
    rx: int
    tx_x: float
    tx_y: float
    rx_x: float
    rx_y: float
    rssi: float
    channel: int = 0


def plausible(record: LinkRecord) -> bool:
    """Finite, within reach of home, an RSS a radio can report, two different radios."""
    numbers = (record.t, record.tx_x, record.tx_y, record.rx_x, record.rx_y, record.rssi)
    return (all(math.isfinite(v) for v in numbers) and record.tx != record.rx
            and all(abs(v) <= MAX_REACH for v in numbers[1:5]) and RSS_RANGE[0] <= record.rssi <= RSS_RANGE[1])


class LinkSender:
    """Packs link records into TUNNEL payloads of type ``RADIO_LINKS``, numbering the batches."""

    def __init__(self):
        self.seq = 0

    def payloads(self, records: Iterable[LinkRecord]) -> list[bytes]:
        """The payloads that carry ``records`` (implausible ones, which no receiver would keep, are left out)."""
        batch: list[LinkRecord] = []
        out: list[bytes] = []
        for record in records:
            if not plausible(record) or not (0 <= record.tx <= 0xFFFF and 0 <= record.rx <= 0xFFFF):
                continue
            if batch and (len(batch) == PER_PAYLOAD or not 0 <= record.t - batch[0].t < MAX_SPAN):
                out.append(self._pack(batch))
                batch = []
            batch.append(record)
        if batch:
            out.append(self._pack(batch))
        return out

    def _pack(self, batch: list[LinkRecord]) -> bytes:
        self.seq = (self.seq + 1) & 0xFFFFFFFF
        base = batch[0].t
        body = b"".join(RECORD.pack(r.tx, r.rx, round((r.t - base) * 1000), r.tx_x, r.tx_y, r.rx_x, r.rx_y,
                                    max(-32768, min(32767, round(r.rssi * 100))), r.channel & 0xFF) for r in batch)
        return HEADER.pack(FORMAT_VERSION, self.seq, base, len(batch)) + body


@dataclass
class LinkReceiver:
    """Unpacks one vehicle's ``RADIO_LINKS`` payloads into new link records, whatever the link did to them."""

    payloads: int = 0  # taken, including duplicates and damaged ones
    duplicates: int = 0
    damaged: int = 0  # payloads that are not one
    dropped: int = 0  # records with absurd values
    records: int = 0  # new records returned
    _seen: set[int] = field(default_factory=set)
    _order: deque = field(default_factory=deque)

    def feed(self, payload: bytes, sysid: int = 0) -> list[LinkRecord]:
        """The records in ``payload`` not seen before; [] for a duplicate or a damaged payload (counted). With
        ``sysid`` (the vehicle that sent it), a record some other radio heard is dropped: a vehicle reports its own."""
        self.payloads += 1
        try:
            version, seq, base, count = HEADER.unpack_from(payload)
        except struct.error:
            self.damaged += 1
            return []
        if version != FORMAT_VERSION or count > PER_PAYLOAD or len(payload) < HEADER.size + count * RECORD.size \
                or not math.isfinite(base):
            self.damaged += 1
            return []
        key = hash(payload[:HEADER.size + count * RECORD.size])  # the batch itself: a restarted sender's differ
        if key in self._seen:
            self.duplicates += 1
            return []
        self._remember(key)
        out = []
        for index in range(count):
            tx, rx, ms, tx_x, tx_y, rx_x, rx_y, centi, channel = RECORD.unpack_from(
                payload, HEADER.size + index * RECORD.size)
            record = LinkRecord(base + ms / 1000, tx, rx, tx_x, tx_y, rx_x, rx_y, centi / 100, channel)
            if plausible(record) and (not sysid or rx == sysid):
                out.append(record)
            else:
                self.dropped += 1
        self.records += len(out)
        return out

    def _remember(self, key: int) -> None:
        self._seen.add(key)
        self._order.append(key)
        while len(self._order) > REMEMBER:
            self._seen.discard(self._order.popleft())


class LinkLog:
    """Every vehicle's link records at the station, oldest dropped past ``capacity``; safe across threads."""

    def __init__(self, capacity: int = 1_000_000):
        self._records: deque[LinkRecord] = deque(maxlen=capacity)
        self._lock = threading.Lock()
        self.version = 0  # grows with every append (a live image knows when to redraw)

    def append(self, records: Iterable[LinkRecord]) -> None:
        records = list(records)
        if not records:
            return
        with self._lock:
            self._records.extend(records)
            self.version += 1

    def clear(self) -> None:
        with self._lock:
            self._records.clear()
            self.version += 1

    def __len__(self) -> int:
        return len(self._records)

    def snapshot(self, since: float | None = None, until: float | None = None) -> list[LinkRecord]:
        """The records with ``since <= t < until`` (either open), in arrival order."""
        with self._lock:
            records = list(self._records)
        return [r for r in records if (since is None or r.t >= since) and (until is None or r.t < until)]
