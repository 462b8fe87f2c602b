"""The ground station's MAVLink side: links, GCS heartbeats, telemetry requests, commands with ACKs, missions.

One thread reads every link (``vehicle.protocol.links``: any transport, UDP
parsed per datagram and per sender, TCP and serial reopened whenever they
drop), feeds each message to the Fleet and to whoever waits for it, sends a
GCS heartbeat every second (and the vehicles' positions to each other, as
``groundstation.traffic_relay`` says) and writes everything, both directions, to the
session recording. Like QGroundControl and Mission Planner it asks each
vehicle for the telemetry it shows (SET_MESSAGE_INTERVAL, and the older
REQUEST_DATA_STREAM for autopilots without it), again when the vehicle
reboots or comes back after its link was lost: ArduPilot sends position and
attitude only on links where someone asked. Commands are retried
(confirmation += 1) until the vehicle answers with COMMAND_ACK or the retries
run out, as MAVLink asks of a sender. Nothing a peer sends or the disk does
stops the thread: a failure is counted, kept for the health report, and the
loop goes on.

With a signing key the station signs everything it sends and shows, per
vehicle, whether its messages carry a valid signature; with
``require_signing`` it drops what is not signed with its key (such a vehicle
is never shown; its system id and the messages dropped are in the health
report). Without ``require_signing``, a component once heard signed stays signed
while its system is remembered (``FORGET_AFTER``): what comes unsigned (or wrongly
signed) in its name afterwards is refused too, or an unsigned heartbeat in an
autopilot's name, from anywhere, would take its route and its orders. Other
components of the system that never signed (a camera behind a router) still pass.

Signed or not, a vehicle's autopilot is heard, and orders go, where its
heartbeat comes from: what comes in its name from another place (another link,
or another address on one) while its heartbeat still comes is dropped and
counted (``from_elsewhere`` in the health report). Without that, anyone who
could send a datagram to the station moved a vehicle on the page with
positions in its name. A second link to the same vehicle (a radio beside
Wi-Fi) is heard once the first has been silent for LINK_LOST_AFTER (and its
copies counted there until then). Other components (the onboard agent, which
may be heard both through the autopilot and on its own link) are heard from
anywhere, and a reply is taken only from the component asked. Only signing
stops a sender that is heard before the vehicle, or outlasts its link, or
speaks as another component.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from groundstation import params
from groundstation.state import FORGET_AFTER, LINK_LOST_AFTER, Fleet
from groundstation.traffic_relay import RELAY_PERIOD, relay_reports
from vehicle.protocol import links, mission, signing
from vehicle.protocol.mav import AUTOPILOT, RESULT_WORDS, mavlink, pack
from vehicle.protocol.mission import MissionItem

log = logging.getLogger("groundstation.link")

GCS_SYSID = 255
GCS_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER
TELEMETRY = {  # message -> Hz asked of every vehicle
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 20, mavlink.MAVLINK_MSG_ID_ATTITUDE: 20,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4, mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1, mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1, mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: 10,
}
DATA_STREAMS = {mavlink.MAV_DATA_STREAM_POSITION: 10, mavlink.MAV_DATA_STREAM_EXTRA1: 10,
                mavlink.MAV_DATA_STREAM_EXTRA2: 4, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: 2}
STALLED_AFTER = 5.0  # s without a turn of the loop: the health report says the link thread is stuck
REPLY_LOOK = 0.05  # s at most between looks at the clock while a try waits for its reply


class LinkError(Exception):
    """A vehicle did not answer in time, or refused."""


class TransferBusy(Exception):
    """A mission transfer with the vehicle is already under way: the protocol carries one at a time."""


@dataclass
class _Waiter:
    sysid: int
    component: int  # the component asked, which alone may answer (0: any)
    accepts: Callable[[object], bool]
    replies: queue.Queue


class Link:
    def __init__(self, urls: list[str], fleet: Fleet, recorder=None, sysid: int = GCS_SYSID,
                 signing_key: bytes | None = None, require_signing: bool = False,
                 retry_clock: Callable[[], float] = time.monotonic):
        if require_signing and signing_key is None:
            raise ValueError("requiring signed vehicles needs a signing key")
        self.fleet = fleet
        fleet.own_sysid = sysid  # so that it tells this station's orders from another station's
        self.recorder = recorder
        self.urls = urls
        self.signing_key, self.require_signing = signing_key, require_signing
        self.ports = [links.connect(url, sysid, GCS_COMPID, signing_key, require_signing) for url in urls]
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=GCS_COMPID)
        if signing_key is not None:
            signing.sign_outgoing(self.packer, signing_key)
        # keyed by the 8-bit system id (so at most 255 entries), and pruned after FORGET_AFTER of silence:
        # sysid -> (the port its heartbeat comes on, its address there, when heard there, when its heartbeat was)
        self.route: dict[int, tuple] = {}
        self.from_elsewhere: Counter[int] = Counter()  # system id -> messages dropped as not from its place
        self._asked: dict[int, tuple[float, float]] = {}  # sysid -> (its last heartbeat, its boot time) when asked
        self._signers: set[tuple[int, int]] = set()  # (system, component) heard signed with the key
        self.params = params.Schedule()  # which battery failsafe parameters to ask whom for, on the retry clock
        self._pruned = 0.0
        self._waiters: list[_Waiter] = []
        self._transfers: set[int] = set()  # system ids a mission goes to or comes from now
        # sysid -> the last mission transfer's {"direction", "done", "total", "result"}, for the plan view's bar
        self.transfer_progress: dict[int, dict] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mavlink", daemon=True)
        self.stats: Counter[str] = Counter()
        self.last_error = ""
        self.recording_error = ""
        self.turned = time.monotonic()  # when the loop last went round
        self.retry_clock = retry_clock  # what a try's wait for its reply is timed on (a test's own, or monotonic)

    def start(self) -> Link:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.ident is not None:  # a station that never started has no thread to wait for
            self._thread.join(timeout=2)
        for port in self.ports:
            port.close()

    def health(self) -> dict:
        """How the link side is doing, for /api/health: the thread, each link, and the recording."""
        stalled = not self._thread.is_alive() or time.monotonic() - self.turned > STALLED_AFTER
        fleet, now = self.fleet, time.time()
        return {"thread": "stalled" if stalled else "ok", "errors": self.stats["errors"],
                "last_error": self.last_error or None, "recording_error": self.recording_error or None,
                "links": [{"url": port.url, "up": port.up, "error": port.error or None} for port in self.ports],
                "vehicles": {"held": len(fleet.vehicles), "limit": fleet.max_vehicles, "refused": fleet.refused,
                             "forgotten": fleet.forgotten},
                "signing": self._signing_health(),
                "from_elsewhere": [{"sysid": sysid, "messages": count}
                                   for sysid, count in sorted(self.from_elsewhere.items())],
                "other_stations": [{"sysid": sysid, "age": round(now - heard, 1)}
                                   for sysid, heard in list(fleet.stations.items())]}

    def _signing_health(self) -> dict:
        """Whether the station signs, whether it requires signed vehicles, and the systems whose messages it
        dropped for their signature (with how many)."""
        refused = sum((port.refused for port in self.ports), Counter())
        return {"key": self.signing_key is not None, "required": self.require_signing,
                "refused": [{"sysid": sysid, "messages": count} for sysid, count in sorted(refused.items())]}

    # ---- the loop ---------------------------------------------------------------------------------
    def _run(self) -> None:
        next_beat = next_relay = 0.0
        while not self._stop.is_set():
            self.turned = time.monotonic()
            try:
                now = time.time()
                if now >= next_beat:
                    self.send(_gcs_heartbeat())
                    next_beat = now + 1.0
                if now >= next_relay:
                    for report in relay_reports(self.fleet, now):
                        self.send(report)
                    next_relay = now + RELAY_PERIOD
                busy = self._read()
                self._ask_for_params()
                self._record_tick()
                self._prune(now)
            except Exception as error:  # noqa: BLE001 - nothing may stop reception; counted and reported
                self._failed(error)
                busy = False
            if not busy:
                time.sleep(0.002)

    def _read(self) -> bool:
        busy = False
        for port in self.ports:
            for _ in range(links.MAX_DATAGRAMS):
                message = port.recv_msg()
                if message is None:
                    break
                busy = True
                try:
                    self._receive(port, message, time.time())
                except Exception as error:  # noqa: BLE001 - one bad message must not take the others down
                    self._failed(error)
        return busy

    def _failed(self, error: BaseException) -> None:
        self.stats["errors"] += 1
        self.last_error = f"{type(error).__name__}: {error}"[:200]
        log.warning("link: %s", self.last_error)

    def _receive(self, port, message, now: float) -> None:
        if message.get_type() == "BAD_DATA":
            self.stats["bad"] += 1
            return
        sysid = message.get_srcSystem()
        if not self._signed_as_before(port, message, sysid):
            return
        peer, component = getattr(message, "_peer", None), message.get_srcComponent()
        if component == AUTOPILOT and not self._from_its_place(sysid, port, peer, now):
            self.from_elsewhere[sysid] += 1
            return
        self.stats["received"] += 1
        self._record(message.get_msgbuf(), now, sysid)
        beat = message.get_type() == "HEARTBEAT" and component == AUTOPILOT
        self._learn_route(sysid, port, peer, now, beat)
        self.fleet.apply(message, now)
        if message.get_type() == "PARAM_VALUE" and component == AUTOPILOT:
            self.params.answered(sysid, params.name_of(message))
        if beat and sysid in self.fleet.vehicles:  # a vehicle the fleet holds (a refused one gets no answer)
            self._ask_for_telemetry(sysid, now)
        if hasattr(message, "time_boot_ms") and component == AUTOPILOT and sysid in self._asked:
            heard, boot = self._asked[sysid]
            if message.time_boot_ms / 1000.0 + 5.0 < boot:  # it rebooted: ask again at its next heartbeat
                del self._asked[sysid]
            else:
                self._asked[sysid] = (heard, max(boot, message.time_boot_ms / 1000.0))
        with self._lock:
            waiters = list(self._waiters)
        for waiter in waiters:
            if waiter.sysid == sysid and waiter.component in (0, component) and waiter.accepts(message):
                waiter.replies.put(message)

    def _signed_as_before(self, port, message, sysid: int) -> bool:
        """False (and counted with what its link refused) for a message not signed in the name of a component
        heard signed before."""
        verified = getattr(message, "_verified", None)  # None: the link has no key
        sender = (sysid, message.get_srcComponent())
        if verified:
            self._signers.add(sender)
        elif verified is False and sender in self._signers and message.get_msgId() not in signing.UNSIGNED_ALLOWED:
            port.refused[sysid] += 1
            return False
        return True

    def _from_its_place(self, sysid: int, port, peer, now: float) -> bool:
        """Whether a message of a system's autopilot comes from where its heartbeat comes (or from anywhere while
        no heartbeat has come from there for LINK_LOST_AFTER: its link died, and it came back on another port
        or link; or before its first heartbeat)."""
        route = self.route.get(sysid)
        return route is None or route[:2] == (port, peer) or now - route[3] > LINK_LOST_AFTER

    def _learn_route(self, sysid: int, port, peer, now: float, beat: bool) -> None:
        """Where orders to a system go: where it was first heard, then where its autopilot's heartbeat comes
        from (``_from_its_place`` let that heartbeat in). Any other message only keeps its route fresh: a flood
        of another kind of message in its name (a map snapshot, say) from elsewhere took its route, as did a
        spoofed heartbeat while the vehicle's own still came, and its orders went to the sender, unanswered."""
        route = self.route.get(sysid)
        if route is not None and route[:2] == (port, peer):
            self.route[sysid] = (port, peer, now, now if beat else route[3])
        elif route is None or beat:
            self.route[sysid] = (port, peer, now, now if beat else -math.inf)

    def _prune(self, now: float) -> None:
        """Once a second: forget the routes to systems not heard for FORGET_AFTER (as the fleet forgets them), and
        that they signed."""
        if now - self._pruned < 1.0:
            return
        self._pruned = now
        for sysid in [s for s, (_, _, heard, _) in self.route.items() if now - heard > FORGET_AFTER]:
            del self.route[sysid]
            self._asked.pop(sysid, None)
            self.params.forget(sysid)
            self._signers = {sender for sender in self._signers if sender[0] != sysid}

    def _ask_for_telemetry(self, sysid: int, now: float) -> None:
        """Ask a vehicle heard for the first time, or again after its link was lost, for what the page shows."""
        heard, boot = self._asked.get(sysid, (None, 0.0))
        self._asked[sysid] = (now, boot)
        if heard is not None and now - heard <= LINK_LOST_AFTER:
            return
        self.send(_gcs_heartbeat(), sysid)  # first: a vehicle takes orders only from a ground station it heard
        self.params.start(sysid)
        for message_id, rate in TELEMETRY.items():
            self.send(mavlink.MAVLink_command_long_message(sysid, AUTOPILOT, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                           0, message_id, 1e6 / rate, 0, 0, 0, 0, 0), sysid)
        self.send(mavlink.MAVLink_command_long_message(sysid, AUTOPILOT, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                       mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0), sysid)
        for stream, rate in DATA_STREAMS.items():
            self.send(mavlink.MAVLink_request_data_stream_message(sysid, AUTOPILOT, stream, rate, 1), sysid)

    def _ask_for_params(self) -> None:
        """PARAM_REQUEST_READ for the battery failsafe parameters each autopilot has not told yet, as
        ``params.Schedule`` paces them."""
        for sysid, name in self.params.due(self.retry_clock()):
            self.send(mavlink.MAVLink_param_request_read_message(sysid, AUTOPILOT, name.encode(), -1), sysid)

    # ---- recording ----------------------------------------------------------------------------------
    def _record(self, packet: bytes, now: float, sender: int | None = None) -> None:
        """What the station sends (``sender`` None) or heard from system ``sender`` (the recorder keeps only so
        much of a sender the fleet does not know)."""
        if self.recorder is None:
            return
        try:
            self.recorder.write(packet, now, sender)
            self.recording_error = ""
        except OSError as error:  # a full or vanished disk: say so, go on tracking the vehicles
            self.stats["recording errors"] += 1
            self.recording_error = f"{type(error).__name__}: {error}"[:200]

    def _record_tick(self) -> None:
        if self.recorder is None:
            return
        try:
            self.recorder.tick(time.time())
        except OSError as error:
            self.stats["recording errors"] += 1
            self.recording_error = f"{type(error).__name__}: {error}"[:200]

    # ---- sending ------------------------------------------------------------------------------------
    def send(self, message, sysid: int | None = None) -> None:
        """Send to where the vehicle was heard (to every link and peer if it is unknown or None)."""
        with self._lock:
            packet = pack(message, self.packer)
        self.fleet.apply(message, time.time())  # this station's orders: not another's, and on the timeline
        route = self.route.get(sysid)  # (the link thread may forget it meanwhile)
        if route is not None:
            port, peer, _, _ = route
            port.write(packet, peer)
        else:
            for port in self.ports:
                port.write(packet)
        self.stats["sent"] += 1
        self._record(packet, time.time())

    def request(self, sysid: int, message, accepts: Callable[[object], bool], timeout: float = 1.0,
                retries: int = 3, resend: Callable[[int], object] | None = None):
        """Send ``message`` and wait for a reply that ``accepts``; resend up to ``retries`` times."""
        waiter = _Waiter(sysid, getattr(message, "target_component", 0), accepts, queue.Queue())
        with self._lock:
            self._waiters.append(waiter)
        try:
            for attempt in range(retries):
                deadline = self.retry_clock() + timeout  # read before the send: once the try is out, it may move
                self.send(resend(attempt) if resend is not None and attempt else message, sysid)
                reply = self._reply(waiter, deadline)
                if reply is not None:
                    return reply
            raise LinkError(f"vehicle {sysid} did not answer {message.get_type()} after {retries} tries")
        finally:
            with self._lock:
                self._waiters.remove(waiter)

    def _reply(self, waiter: _Waiter, deadline: float):
        """The reply that came by ``deadline`` on the retry clock, None if none did. The clock is looked at
        every REPLY_LOOK of wall time at least: a test's clock moves when the test moves it."""
        while (left := deadline - self.retry_clock()) > 0:
            try:
                return waiter.replies.get(timeout=min(left, REPLY_LOOK))
            except queue.Empty:
                continue
        return None

    def command(self, sysid: int, command: int, *params: float, timeout: float = 1.0, retries: int = 3,
                component: int = AUTOPILOT) -> str:
        """COMMAND_LONG to a component of a vehicle (its autopilot unless told), retried with confirmation += 1;
        the COMMAND_ACK result as a word."""
        values = (list(params) + [0.0] * 7)[:7]

        def build(confirmation: int):
            return mavlink.MAVLink_command_long_message(sysid, component, command, confirmation, *values)

        ack = self.request(sysid, build(0), lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                           timeout, retries, build)
        return RESULT_WORDS.get(ack.result, f"result {ack.result}")

    def command_int(self, sysid: int, command: int, frame: int, params: list[float], x: int, y: int, z: float,
                    timeout: float = 1.0, retries: int = 3, component: int = AUTOPILOT) -> str:
        def build(confirmation: int):
            # COMMAND_INT has no confirmation field: every try is the same message
            return mavlink.MAVLink_command_int_message(sysid, component, frame, command, 0, 0, *params, x, y, z)

        ack = self.request(sysid, build(0), lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                           timeout, retries, build)
        return RESULT_WORDS.get(ack.result, f"result {ack.result}")

    # ---- the mission protocol, ground station side ----------------------------------------------------
    def download_mission(self, sysid: int, timeout: float = 1.0) -> list[MissionItem]:
        with self._transfer(sysid, "download"):
            items = mission.download(self, sysid, timeout=timeout, progress=self._progress(sysid))
            self.transfer_progress[sysid]["result"] = "done"
            return items

    def upload_mission(self, sysid: int, items: list[MissionItem], timeout: float = 1.0) -> str:
        """Upload items (item 0 is home); returns the vehicle's MISSION_ACK result as a word."""
        with self._transfer(sysid, "upload"):
            try:
                result = mission.upload(self, sysid, items, timeout=timeout, progress=self._progress(sysid))
            except mission.MissionError as error:
                raise LinkError(str(error)) from None
            self.transfer_progress[sysid]["result"] = result
            return result

    def _progress(self, sysid: int) -> Callable[[int, int], None]:
        def told(done: int, total: int) -> None:
            self.transfer_progress[sysid].update(done=done, total=total)
        return told

    @contextlib.contextmanager
    def _transfer(self, sysid: int, direction: str):
        """One mission transfer per vehicle at a time (else TransferBusy): two would take each other's replies."""
        with self._lock:
            if sysid in self._transfers:
                raise TransferBusy(f"a mission transfer with vehicle {sysid} is under way; try again when it ends")
            self._transfers.add(sysid)
            self.transfer_progress[sysid] = {"direction": direction, "done": 0, "total": None, "result": None}
        try:
            yield
        except Exception as error:
            self.transfer_progress[sysid]["result"] = f"failed: {error}"
            raise
        finally:
            with self._lock:
                self._transfers.discard(sysid)


def _gcs_heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink.MAV_STATE_ACTIVE, 3)
