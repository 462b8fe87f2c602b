"""The ground station's MAVLink side: connections, GCS heartbeats, commands with ACKs, the mission protocol.

One thread reads every connection (pymavlink's ``mavlink_connection``, any
transport), feeds each message to the Fleet and to whoever waits for it, sends
a GCS heartbeat every second and writes everything, both directions, to the
session recording. Commands are retried (confirmation += 1) until the vehicle
answers with COMMAND_ACK or the retries run out, as MAVLink asks of a sender.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from groundstation.state import Fleet
from vehicle.protocol import mission
from vehicle.protocol.mav import mavlink, mavutil, pack
from vehicle.protocol.mission import MissionItem

GCS_SYSID = 255
GCS_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER
RESULTS = {
    mavlink.MAV_RESULT_ACCEPTED: "accepted", mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink.MAV_RESULT_DENIED: "denied", mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed", mavlink.MAV_RESULT_IN_PROGRESS: "in progress",
}


class LinkError(Exception):
    """A vehicle did not answer in time, or refused."""


@dataclass
class _Waiter:
    sysid: int
    accepts: Callable[[object], bool]
    replies: queue.Queue


class Link:
    def __init__(self, urls: list[str], fleet: Fleet, recorder=None, sysid: int = GCS_SYSID):
        self.fleet = fleet
        self.recorder = recorder
        self.urls = urls
        self.connections = [mavutil.mavlink_connection(url, source_system=sysid, source_component=GCS_COMPID,
                                                       autoreconnect=True) for url in urls]
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=GCS_COMPID)
        self.route: dict[int, object] = {}  # sysid -> the connection it was last heard on
        self._waiters: list[_Waiter] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink", daemon=True)
        self.stats = {"received": 0, "sent": 0, "bad": 0}

    def start(self) -> Link:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        for connection in self.connections:
            connection.close()

    # ---- the loop ---------------------------------------------------------------------------------
    def _run(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            now = time.time()
            if now >= next_beat:
                self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                                            0, 0, mavlink.MAV_STATE_ACTIVE, 3))
                next_beat = now + 1.0
            busy = False
            for connection in self.connections:
                while True:
                    try:
                        message = connection.recv_msg()
                    except (OSError, ConnectionError):
                        break
                    if message is None:
                        break
                    busy = True
                    self._receive(connection, message, time.time())
            if self.recorder is not None:
                self.recorder.tick(time.time())
            if not busy:
                time.sleep(0.002)

    def _receive(self, connection, message, now: float) -> None:
        if message.get_type() == "BAD_DATA":
            self.stats["bad"] += 1
            return
        self.stats["received"] += 1
        if self.recorder is not None:
            self.recorder.write(message.get_msgbuf(), now)
        sysid = message.get_srcSystem()
        self.route[sysid] = connection
        self.fleet.apply(message, now)
        with self._lock:
            waiters = list(self._waiters)
        for waiter in waiters:
            if waiter.sysid == sysid and waiter.accepts(message):
                waiter.replies.put(message)

    # ---- sending ------------------------------------------------------------------------------------
    def send(self, message, sysid: int | None = None) -> None:
        """Send to the connection the vehicle was heard on (all connections if unknown or None)."""
        with self._lock:
            packet = pack(message, self.packer)
        targets = [self.route[sysid]] if sysid in self.route else self.connections
        for connection in targets:
            try:
                connection.write(packet)
            except OSError:
                continue
        self.stats["sent"] += 1
        if self.recorder is not None:
            self.recorder.write(packet, time.time())

    def request(self, sysid: int, message, accepts: Callable[[object], bool], timeout: float = 1.0,
                retries: int = 3, resend: Callable[[int], object] | None = None):
        """Send ``message`` and wait for a reply that ``accepts``; resend up to ``retries`` times."""
        waiter = _Waiter(sysid, accepts, queue.Queue())
        with self._lock:
            self._waiters.append(waiter)
        try:
            for attempt in range(retries):
                self.send(resend(attempt) if resend is not None and attempt else message, sysid)
                try:
                    return waiter.replies.get(timeout=timeout)
                except queue.Empty:
                    continue
            raise LinkError(f"vehicle {sysid} did not answer {message.get_type()} after {retries} tries")
        finally:
            with self._lock:
                self._waiters.remove(waiter)

    def command(self, sysid: int, command: int, *params: float, timeout: float = 1.0, retries: int = 3) -> str:
        """COMMAND_LONG, retried with confirmation += 1; the COMMAND_ACK result as a word."""
        values = (list(params) + [0.0] * 7)[:7]

        def build(confirmation: int):
            return mavlink.MAVLink_command_long_message(sysid, 1, command, confirmation, *values)

        ack = self.request(sysid, build(0), lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                           timeout, retries, build)
        return RESULTS.get(ack.result, f"result {ack.result}")

    def command_int(self, sysid: int, command: int, frame: int, params: list[float], x: int, y: int, z: float,
                    timeout: float = 1.0, retries: int = 3) -> str:
        def build(confirmation: int):
            # COMMAND_INT has no confirmation field: every try is the same message
            return mavlink.MAVLink_command_int_message(sysid, 1, frame, command, 0, 0, *params, x, y, z)

        ack = self.request(sysid, build(0), lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                           timeout, retries, build)
        return RESULTS.get(ack.result, f"result {ack.result}")

    # ---- the mission protocol, ground station side ----------------------------------------------------
    def download_mission(self, sysid: int, timeout: float = 1.0) -> list[MissionItem]:
        return mission.download(self, sysid, timeout=timeout)

    def upload_mission(self, sysid: int, items: list[MissionItem], timeout: float = 1.0) -> str:
        """Upload items (item 0 is home); returns the vehicle's MISSION_ACK result as a word."""
        try:
            return mission.upload(self, sysid, items, timeout=timeout)
        except mission.MissionError as error:
            raise LinkError(str(error)) from None
