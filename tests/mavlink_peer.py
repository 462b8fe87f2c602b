"""A raw MAVLink peer for hostile-input tests: its own UDP socket, bytes exactly as the test builds them.

Unlike ``mavlink_gcs.Gcs`` (pymavlink's own connection, a well-behaved ground
station), a ``Peer`` sends whatever it is given (any system and component id,
non-finite numbers, floods of broken datagrams) to one address, and parses
what comes back per datagram. With a signing key it signs as a signed peer
would. ``FakeVehicle`` is the one fake vehicle on a socket: a Peer that beats
and answers as a test tells it; ``Delivered`` is a fake vehicle without one,
for a test that feeds a ``Fleet`` (or what reads it) directly.
"""

from __future__ import annotations

import math
import socket
import threading
import time

from harness import during

from vehicle.protocol import signing
from vehicle.protocol.mav import mavlink, pack

QUADROTOR = mavlink.MAV_TYPE_QUADROTOR
ARDUPILOT = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA


class Peer:
    def __init__(self, address: tuple[str, int] | None, sysid: int, compid: int = 1, key: bytes | None = None):
        self.address = address  # where it sends (None: set it once known)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.packer = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
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
        self.socket.settimeout(timeout)
        try:
            data = self.socket.recv(65535)
        except (TimeoutError, BlockingIOError):
            return []
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        got = parser.parse_buffer(data) or []
        self.texts += [message.text for message in got if message.get_type() == "STATUSTEXT"]
        return got

    def wait(self, condition, timeout: float = 5.0):
        """The first message received for which ``condition`` holds, or None after ``timeout`` wall s."""
        for left in during(timeout):
            for message in self.receive(min(0.1, left)):
                if condition(message):
                    return message
        return None


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
