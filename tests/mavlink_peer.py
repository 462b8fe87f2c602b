"""A raw MAVLink peer for hostile-input tests: its own UDP socket, bytes exactly as the test builds them.

Unlike ``mavlink_gcs.Gcs`` (pymavlink's own connection, a well-behaved ground
station), a ``Peer`` sends whatever it is given (any system and component id,
non-finite numbers, floods of broken datagrams) to one address, and parses
what comes back per datagram. With a signing key it signs as a signed peer
would.
"""

from __future__ import annotations

import math
import socket
import time

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
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            self.socket.settimeout(min(left, 0.05))
            try:
                data = self.socket.recv(65535)
            except (TimeoutError, BlockingIOError):
                continue
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            for message in parser.parse_buffer(data) or []:
                if message.get_type() == "STATUSTEXT":
                    self.texts.append(message.text)
                got.append(message)
        return got

    def wait(self, condition, timeout: float = 5.0):
        """The first message received for which ``condition`` holds, or None after ``timeout`` wall s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for message in self.receive(0.1):
                if condition(message):
                    return message
        return None


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
