"""The tests' MAVLink peers: a raw one, the one fake ground station and the one fake vehicle, on real UDP sockets.

A ``Peer`` sends whatever it is given (any system and component id,
non-finite numbers, floods of broken datagrams) to one address, and parses
what comes back per datagram; ``peer.mav`` is pymavlink's sender on its
socket (``peer.mav.heartbeat_send(...)``). With a signing key it signs as a
signed peer would. ``Gcs`` is the one fake ground station: a well-behaved
Peer that beats while it waits, retries its commands and waits in the
vehicle's simulated time (``harness.wait_sim``). ``FakeVehicle`` is the one
fake vehicle on a socket: a Peer that beats and answers as a test tells it;
``Delivered`` is a fake vehicle without one, for a test that feeds a
``Fleet`` (or what reads it) directly.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from harness import WaitTimeout, during, wait_sim

from vehicle.protocol import signing
from vehicle.protocol.mav import AUTOPILOT, mavlink, pack

QUADROTOR = mavlink.MAV_TYPE_QUADROTOR
ARDUPILOT = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA


class _Socket:
    """What pymavlink's ``MAVLink.send`` writes to: the peer's socket."""

    def __init__(self, peer: Peer):
        self.peer = peer

    def write(self, data: bytes) -> None:
        self.peer.raw(data)


class Peer:
    def __init__(self, address: tuple[str, int] | None, sysid: int, compid: int = 1, key: bytes | None = None,
                 port: int = 0):
        """``address`` None: it sends to whoever it first hears from (on ``port``), as pymavlink's udpin does."""
        self.address = address
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", port))
        self.packer = self.mav = mavlink.MAVLink(_Socket(self), srcSystem=sysid, srcComponent=compid)
        if key is not None:
            signing.sign_outgoing(self.packer, key)
        self.texts: list[str] = []

    def __enter__(self) -> Peer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.socket.close()

    @property
    def url(self) -> str:
        """Where a vehicle sends to reach this peer."""
        return f"udpout:127.0.0.1:{self.socket.getsockname()[1]}"

    def send(self, *messages) -> None:
        for message in messages:
            self.raw(pack(message, self.packer))

    def raw(self, data: bytes) -> None:
        if self.address is not None:  # nobody heard yet: dropped, as pymavlink's udpin drops it
            self.socket.sendto(bytes(data), self.address)

    def as_system(self, sysid: int, compid: int = 1) -> Peer:
        """Send the next messages as another system (what a spoofer, or a flood of fake vehicles, does)."""
        self.packer.srcSystem, self.packer.srcComponent = sysid, compid
        return self

    def receive(self, timeout: float = 0.5) -> list:
        """Every message that came within ``timeout`` s, parsed per datagram."""
        got = []
        for left in during(timeout):
            got += self.datagram(min(left, 0.05))
        return got

    def datagram(self, timeout: float) -> list:
        """The messages of the next datagram that comes within ``timeout`` s (none: ``[]``)."""
        got = self._read(timeout)
        self.texts += [message.text for message in got if message.get_type() == "STATUSTEXT"]
        return got

    def _read(self, timeout: float) -> list:
        self.socket.settimeout(timeout)
        try:
            data, sender = self.socket.recvfrom(65535)
        except (TimeoutError, BlockingIOError):
            return []
        if self.address is None:
            self.address = sender
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser.parse_buffer(data) or []

    def wait(self, condition, timeout: float = 5.0):
        """The first message received for which ``condition`` holds, or None after ``timeout`` wall s."""
        for left in during(timeout):
            for message in self.receive(min(0.1, left)):
                if condition(message):
                    return message
        return None


class Gcs(Peer):
    """A well-behaved ground station at ``url``: ``udpin:127.0.0.1:PORT`` listens there and answers whoever
    it hears, ``udpout:HOST:PORT`` sends there. Its waits are bounded in the vehicle's simulated time (the
    ``time_boot_ms`` it reports) and say what they last saw."""

    def __init__(self, url: str, sysid: int = 255, target: int = 1, speedup: float = 1.0, key: bytes | None = None):
        kind, host, port = url.split(":")
        if kind not in ("udpin", "udpout"):
            raise ValueError(f"Gcs takes udpin:HOST:PORT or udpout:HOST:PORT, not {url!r}")
        listens = kind == "udpin"
        super().__init__(None if listens else (host, int(port)), sysid, 190, key, int(port) if listens else 0)
        self.target = target
        self.speedup = speedup
        self.sim_time = 0.0  # latest time_boot_ms seen, seconds
        self.seen: dict[str, object] = {}
        self._queue: deque = deque()  # messages of a datagram not read yet

    def heartbeat(self) -> None:
        self.send(gcs_heartbeat())

    def recv(self, timeout: float = 0.2, component: int | None = AUTOPILOT):
        """The next message from the vehicle's ``component`` (None: any), or None if none came in ``timeout``.
        Every STATUSTEXT of the vehicle, whichever component sent it, goes to ``texts``."""
        for left in during(timeout):
            if not self._queue:
                self._queue.extend(self._read(min(left, 0.05)))
            message = self._queue.popleft() if self._queue else None
            if message is None or message.get_type() == "BAD_DATA" or message.get_srcSystem() != self.target:
                continue
            if message.get_type() == "STATUSTEXT":
                self.texts.append(message.text)
            if hasattr(message, "time_boot_ms"):  # the vehicle's clock, whoever is waited for
                self.sim_time = max(self.sim_time, message.time_boot_ms / 1000)
            if component is not None and message.get_srcComponent() != component:
                continue
            self.seen[message.get_type()] = message
            return message
        return None

    def wait(self, kind: str | None, condition: Callable = lambda m: True, sim_timeout: float = 30.0,
             heartbeats: bool = True, component: int | None = AUTOPILOT):
        """The first message of ``kind`` from ``component`` (the autopilot unless told; None: any) for which
        ``condition`` holds, within ``sim_timeout`` simulated s. Sends its own heartbeat meanwhile."""
        last_beat = 0.0

        def read():
            nonlocal last_beat
            if heartbeats and time.monotonic() - last_beat > 0.3:
                self.heartbeat()
                last_beat = time.monotonic()
            message = self.recv(component=component)
            matches = message is not None and (kind is None or message.get_type() == kind)
            return (message if matches else None), (self.sim_time or None)

        return wait_sim(read, condition, sim_timeout, self.speedup, f"{kind or 'a message'} matching the condition")

    def wait_text(self, fragment: str, since: int = 0, sim_timeout: float = 30.0, heartbeats: bool = True) -> str:
        """A STATUSTEXT containing ``fragment``, among those received from index ``since`` on."""
        def found() -> str | None:
            return next((t for t in self.texts[since:] if fragment in t), None)
        if (text := found()) is not None:
            return text
        self.wait(None, lambda m: found() is not None, sim_timeout, heartbeats, component=None)
        return found()

    def command(self, command: int, *params: float, retries: int = 5) -> int:
        """COMMAND_LONG with retries (confirmation += 1); returns the ACK's result."""
        values = (list(params) + [0.0] * 7)[:7]
        for confirmation in range(retries):
            self.heartbeat()  # a vehicle obeys ground stations it heard from lately
            self.mav.command_long_send(self.target, 1, command, confirmation, *values)
            try:
                ack = self.wait("COMMAND_ACK", lambda m: m.command == command, sim_timeout=1.0 * self.speedup)
            except WaitTimeout:
                continue
            return ack.result
        raise WaitTimeout(f"no COMMAND_ACK for command {command}")

    def set_mode(self, number: int) -> int:
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)

    def wait_mode(self, number: int, sim_timeout: float = 10.0):
        """A HEARTBEAT in that mode. Heartbeats come once a wall second, so the wait covers at least
        three of them however fast the simulation runs."""
        return self.wait("HEARTBEAT", lambda m: m.custom_mode == number, max(sim_timeout, 3.0 * self.speedup))


class FakeVehicle(Peer):
    """A vehicle's autopilot on a thread of its own: every ``beat`` s it sends a HEARTBEAT (and a
    GLOBAL_POSITION_INT with ``pose``), and it answers each message it gets as ``answer(self, message)`` says
    (sending what it likes, or nothing). ``received`` holds every message it got.
    A context manager (or ``close()``): it beats from the start."""

    def __init__(self, address: tuple[str, int], sysid: int, answer=None, beat: float = 0.5, pose: bool = True):
        super().__init__(address, sysid)
        self.answer = answer or (lambda vehicle, message: None)
        self.beat, self.pose = beat, pose
        self.received: list = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        beaten = -math.inf
        while not self._stop.is_set():
            if time.monotonic() - beaten >= self.beat:
                beaten = time.monotonic()
                self.send(vehicle_heartbeat(), *([position()] if self.pose else []))
            for message in self.datagram(0.02):
                self.handle(message)

    def handle(self, message) -> None:
        """Keep the message, then answer it (kept first: once the station hears the answer, a test sees it)."""
        self.received.append(message)
        self.answer(self, message)

    def of_type(self, kind: str, command: int | None = None) -> list:
        return [m for m in list(self.received)
                if m.get_type() == kind and (command is None or m.command == command)]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        super().close()


class Delivered:
    """Packs messages as one component of a system and decodes them, as a link delivers them to a ``Fleet``: a
    fake vehicle for a test that feeds the fleet (or the view that draws it) directly, with no socket between."""

    def __init__(self, sysid: int, component: int = 1):
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=component)
        self.parser = mavlink.MAVLink(None)

    def __call__(self, message):
        return self.parser.decode(bytearray(message.pack(self.packer)))


def command(command: int, *params: float, target: int = 1, component: int = 1):
    return mavlink.MAVLink_command_long_message(target, component, command, 0, *(list(params) + [0.0] * 7)[:7])


def acked(peer: Peer, number: int, timeout: float = 5.0):
    """The COMMAND_ACK of command ``number`` the peer gets, or None."""
    return peer.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == number, timeout)


# ---- messages a fake vehicle sends ----------------------------------------------------------------------
def vehicle_heartbeat(mode: int = 4, mav_type: int = QUADROTOR):
    return mavlink.MAVLink_heartbeat_message(mav_type, ARDUPILOT, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode,
                                             mavlink.MAV_STATE_ACTIVE, 3)


def gcs_heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink.MAV_STATE_ACTIVE, 3)


def position(lat: float = -35.363261, lon: float = 149.165230, alt: float = 4.0, time_ms: int = 1000):
    return mavlink.MAVLink_global_position_int_message(time_ms, int(lat * 1e7), int(lon * 1e7), 0, int(alt * 1000),
                                                       0, 0, 0, 0)


def fly_pair(one: Peer, two: Peer, north_of_one: list[float]) -> None:
    """Two vehicles' heartbeats and positions, 20 ms apart: ``one`` at the datum, ``two`` each of the given
    distances (m) north of it in turn."""
    metre = 1 / 111_320  # degrees of latitude
    for step, north in enumerate(north_of_one):
        one.send(vehicle_heartbeat(), position(time_ms=1000 + step))
        two.send(vehicle_heartbeat(), position(lat=-35.363261 + north * metre, time_ms=1000 + step))
        time.sleep(0.02)


def non_finite_messages(time_ms: int = 2000) -> list:
    """One of every message the station reads floats from, each with NaN or an infinity where a number goes."""
    nan, inf = math.nan, math.inf
    return [
        mavlink.MAVLink_attitude_message(time_ms, nan, nan, inf, nan, nan, nan),
        mavlink.MAVLink_vfr_hud_message(nan, inf, 0, 0, -inf, nan),
        mavlink.MAVLink_local_position_ned_message(time_ms, nan, inf, -inf, nan, nan, nan),
        mavlink.MAVLink_home_position_message(int(-35.363261e7), int(149.16523e7), 584000, nan, nan, inf,
                                              [nan] * 4, nan, nan, nan),
        mavlink.MAVLink_distance_sensor_message(time_ms, 2, 4000, 500, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND, 0,
                                                mavlink.MAV_SENSOR_ROTATION_CUSTOM, 0, nan, inf, [nan] * 4, 0),
        mavlink.MAVLink_distance_sensor_message(time_ms, 2, 4000, 500, mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND, 1,
                                                0, 0, nan, nan, [0.0] * 4, 0),
        mavlink.MAVLink_global_position_int_message(time_ms, 2**31 - 1, -(2**31), 0, 4000, 0, 0, 0, 0),
    ]
