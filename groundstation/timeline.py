"""A replayed log's whole timeline: every vehicle's telemetry and events from its start to its end.

The page plots a replay on the replay's own timeline (click to seek), so it
needs the whole log's history at once, not what has been played so far. A log
of an hour holds some 300,000 messages, which pymavlink would take twenty
seconds to decode; the scan reads the index instead and decodes only what
the history needs: every message that makes an event (heartbeats, texts,
commands and their ACKs, the agent's state, homes), every map snapshot (for
the occupied-cell count; the deltas between are skipped), and of the
telemetry (poses, attitude, battery, sonar) only the first few of each
stretch of ``every`` seconds. These go through a Fleet of their own, as a live
link's would, in a background thread: the replay plays meanwhile. A record
the Fleet cannot take (it raises) is skipped and counted (``skipped``), as
playing passes it over: one bad message must not cost the whole timeline.
"""

from __future__ import annotations

import threading

import numpy as np

from groundstation.history import History
from groundstation.replay import Replay
from groundstation.state import Fleet
from vehicle.protocol.agent_status import AGENT_STATUS
from vehicle.protocol.mapstream import MAP_SNAPSHOT
from vehicle.protocol.mav import mavlink

SAMPLES = 3000  # history samples per vehicle over the whole log, at most
SNAPSHOTS = 300  # map snapshots per vehicle, at most
EVENTFUL = (mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_STATUSTEXT, mavlink.MAVLINK_MSG_ID_COMMAND_LONG,
            mavlink.MAVLINK_MSG_ID_COMMAND_INT, mavlink.MAVLINK_MSG_ID_COMMAND_ACK,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION)
SAMPLED = (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
           mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_VFR_HUD, mavlink.MAVLINK_MSG_ID_SYS_STATUS,
           mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR)
TUNNEL = mavlink.MAVLINK_MSG_ID_TUNNEL
DISTANCE_SENSOR = mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR


class Timeline:
    """The history of a whole replayed log, built once in the background (``history`` is None until then)."""

    def __init__(self, replay: Replay):
        self.replay = replay
        self.every = max(0.5, replay.duration / SAMPLES)
        self.history: History | None = None
        self.error: str | None = None
        self.skipped = 0  # records that raised in the scan's Fleet, left out (playing counts them in the status)
        self._cancelled = False
        self._thread = threading.Thread(target=self._build, name="timeline", daemon=True)
        self._thread.start()

    @property
    def ready(self) -> bool:
        return self.history is not None or self.error is not None

    def cancel(self) -> None:
        """Stop scanning (the replay ended): an hour of log need not be read for nobody."""
        self._cancelled = True

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return self.ready

    def _build(self) -> None:
        try:
            replay = self.replay
            history = History(self.every, capacity=SAMPLES + 10)
            fleet = Fleet(replay.fleet.datum, replay.fleet.ground_height, forget_after=None, own_maps=False,
                          own_sysid=replay.fleet.own_sysid,
                          history=history)
            decoder = replay.decoder()
            for i in records(replay, self.every):
                if self._cancelled:
                    self.error = "cancelled"
                    return
                message = replay.message(int(i), decoder)
                if message is None:
                    continue
                try:
                    fleet.apply(message, float(replay.index.times[i]))
                except Exception:  # noqa: BLE001 - one bad record must not cost the whole log's history
                    self.skipped += 1
            self.history = history
        except Exception as error:  # noqa: BLE001 - a log we cannot scan still replays; the page says why
            self.error = f"{type(error).__name__}: {error}"


def records(replay: Replay, every: float) -> np.ndarray:
    """Indices, in log order, of the records the scan decodes (see the module docstring)."""
    index = replay.index
    msgids, sysids = index.msgids, index.sysids
    chosen = [np.flatnonzero(np.isin(msgids, EVENTFUL)),
              np.flatnonzero((msgids == TUNNEL) & (index.tunnel_types == AGENT_STATUS))]
    buckets = ((index.times - index.start) / every).astype(np.int64)
    for msgid in SAMPLED:
        found = np.flatnonzero(msgids == msgid)
        if not len(found):
            continue
        sensor = np.array([replay.sensor_id(int(i)) for i in found]) if msgid == DISTANCE_SENSOR else 0
        key = (sysids[found].astype(np.int64) * 256 + sensor) * (int(buckets[-1]) + 1) + buckets[found]
        _, first = np.unique(key, return_index=True)  # the first of each stretch, per vehicle (and sensor)
        chosen.append(found[first])
    chosen.append(_snapshots(replay))
    return np.unique(np.concatenate(chosen))


def _snapshots(replay: Replay) -> np.ndarray:
    """The chunks of at most SNAPSHOTS whole map snapshots per vehicle, evenly spread over the log."""
    index = replay.index
    chunks = np.flatnonzero((index.msgids == TUNNEL) & (index.tunnel_types == MAP_SNAPSHOT))
    picked: list[np.ndarray] = []
    for sysid in np.unique(index.sysids[chunks]):
        mine = chunks[index.sysids[chunks] == sysid]
        groups: list[list[int]] = []  # runs of chunks of one snapshot id
        last = None
        for i in mine:
            ident = replay.chunk_header(int(i))[0]
            if ident != last:
                groups.append([])
                last = ident
            groups[-1].append(int(i))
        keep = np.linspace(0, len(groups) - 1, min(len(groups), SNAPSHOTS)).round().astype(int)
        picked.extend(np.array(groups[k], dtype=np.int64) for k in np.unique(keep))
    return np.concatenate(picked) if picked else np.zeros(0, dtype=np.int64)
