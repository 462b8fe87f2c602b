"""The MAVLink mission protocol, vehicle side: a ground station downloads or uploads the AUTO mission.

Download: MISSION_REQUEST_LIST -> MISSION_COUNT, then MISSION_REQUEST_INT (or
the legacy MISSION_REQUEST) n -> MISSION_ITEM_INT n, ended by the GCS's
MISSION_ACK. Upload: MISSION_COUNT -> we request each item in turn (again if it
does not come within a second, up to five times) and answer the last with
MISSION_ACK; the new mission replaces the old one only when complete.
MISSION_CLEAR_ALL empties it, MISSION_SET_CURRENT picks the next item. It
remembers whether the mission on board is one a ground station uploaded (not
the vehicle's own companion): MISSION_START then flies it, and does not start
an onboard agent's mission instead. Only
the main mission type is kept; fence and rally requests are answered with an
empty list.
"""

from __future__ import annotations

from vehicle.protocol.mav import COMPANION, mavlink
from vehicle.protocol.mission import MISSION, MissionItem, item_from, item_message, item_problem
from vehicle.sim.autopilot import Autopilot

RETRY = 1.0  # s before an item is requested again
RETRIES = 5


class MissionServer:
    """Keeps the state of one upload at a time; ``handle`` returns the messages to send back."""

    def __init__(self, autopilot: Autopilot):
        self.autopilot = autopilot
        self._upload: list[MissionItem | None] | None = None
        self._peer: tuple[int, int] = (0, 0)
        self._asked_at = 0.0
        self._asks = 0
        self.uploads = 0
        self._from_station: list[MissionItem] | None = None  # the autopilot's mission, if a station uploaded it

    @property
    def holds_station_mission(self) -> bool:
        """The autopilot flies a mission a ground station uploaded (replaced by no one since)."""
        return self._from_station is not None and self.autopilot.mission is self._from_station

    def handle(self, message, now: float) -> list:
        kind = message.get_type()
        peer = (message.get_srcSystem(), message.get_srcComponent())
        mission_type = getattr(message, "mission_type", MISSION)
        if kind == "MISSION_REQUEST_LIST":
            count = len(self.autopilot.mission) if mission_type == MISSION else 0
            return [mavlink.MAVLink_mission_count_message(peer[0], peer[1], count, mission_type)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._send_item(message.seq, peer, mission_type)
        if kind == "MISSION_COUNT":
            return self._start_upload(message.count, peer, mission_type, now)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._receive_item(message, peer, now)
        if kind == "MISSION_CLEAR_ALL":
            if mission_type == MISSION:
                self.autopilot.set_mission([])
            return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mission_type)]
        if kind == "MISSION_SET_CURRENT":
            if self.autopilot.set_current(message.seq):
                return []  # the autopilot's MISSION_CURRENT event answers
            return [mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING,
                                                       f"Mission: no item {message.seq}".encode())]
        return []

    def poll(self, now: float) -> list:
        """Ask again for an upload item that did not come; give the upload up after some tries."""
        if self._upload is None or now - self._asked_at < RETRY:
            return []
        if self._asks >= RETRIES:
            self._upload = None
            return [self._ack(self._peer, mavlink.MAV_MISSION_OPERATION_CANCELLED, MISSION)]
        return self._request_next(now)

    def _send_item(self, seq: int, peer, mission_type: int) -> list:
        mission = self.autopilot.mission
        if mission_type != MISSION or not 0 <= seq < len(mission):
            return [self._ack(peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, mission_type)]
        return [item_message(mission[seq], seq, peer, seq == self.autopilot.current)]

    def _start_upload(self, count: int, peer, mission_type: int, now: float) -> list:
        if mission_type != MISSION:
            return [self._ack(peer, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
        if count == 0:
            self.autopilot.set_mission([])
            return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, mission_type)]
        if count > 700:
            return [self._ack(peer, mavlink.MAV_MISSION_NO_SPACE, mission_type)]
        self._upload = [None] * count
        self._peer = peer
        self._asks = 0
        return self._request_next(now)

    def _request_next(self, now: float) -> list:
        seq = self._upload.index(None)
        self._asked_at = now
        self._asks += 1
        return [mavlink.MAVLink_mission_request_int_message(self._peer[0], self._peer[1], seq, MISSION)]

    def _receive_item(self, message, peer, now: float) -> list:
        if self._upload is None or peer != self._peer:
            return []
        seq = message.seq
        if not 0 <= seq < len(self._upload) or (seq > 0 and self._upload[seq - 1] is None):
            return [self._ack(peer, mavlink.MAV_MISSION_INVALID_SEQUENCE, MISSION)]
        item = item_from(message)
        problem = item_problem(item) if seq > 0 else None  # item 0 is home: the autopilot keeps its own
        if problem is not None:  # as ArduPilot: the upload ends, the mission on board stays as it was
            self._upload = None
            return [self._ack(peer, problem, MISSION)]
        self._upload[seq] = item
        self._asks = 0
        if None in self._upload:
            return self._request_next(now)
        items, self._upload = self._upload, None
        self.autopilot.set_mission(items)
        self._from_station = self.autopilot.mission if peer[1] != COMPANION else None
        self.uploads += 1
        return [self._ack(peer, mavlink.MAV_MISSION_ACCEPTED, MISSION)]

    @staticmethod
    def _ack(peer, result: int, mission_type: int):
        return mavlink.MAVLink_mission_ack_message(peer[0], peer[1], result, mission_type)
