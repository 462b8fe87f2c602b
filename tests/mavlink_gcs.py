"""A minimal independent ground station for tests: pymavlink's mavlink_connection on a real UDP socket.

Waits are bounded in the vehicle's simulated time (the ``time_boot_ms`` it
reports, as ArduPilot's autotest waits on SITL time), with a generous wall
clock backstop so a broken vehicle fails a test instead of hanging it.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

from vehicle.lab.live import SimOptions, SimVehicle
from vehicle.protocol.mav import mavlink, mavutil

AUTOPILOT = mavlink.MAV_COMP_ID_AUTOPILOT1
COMPANION = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER


class WaitTimeout(AssertionError):
    """A condition did not come true within its simulated-time budget."""


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class Gcs:
    def __init__(self, url: str, sysid: int = 255, target: int = 1, speedup: float = 1.0):
        self.conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=190)
        self.target = target
        self.speedup = speedup
        self.sim_time = 0.0  # latest time_boot_ms seen, seconds
        self.seen: dict[str, object] = {}
        self.texts: list[str] = []  # every STATUSTEXT, so a test can look back

    def close(self) -> None:
        self.conn.close()

    def heartbeat(self) -> None:
        self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def recv(self, timeout: float = 0.2, component: int | None = AUTOPILOT):
        """The next message from the vehicle's ``component`` (None: any), or None if none came in ``timeout``.
        Every STATUSTEXT of the vehicle, whichever component sent it, goes to ``texts``."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            message = self.conn.recv_match(blocking=True, timeout=left)
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
        ``condition`` holds, within ``sim_timeout`` simulated s."""
        start_sim = None
        wall_deadline = time.monotonic() + sim_timeout / self.speedup * 4 + 15
        last_beat = 0.0
        while time.monotonic() < wall_deadline:
            if heartbeats and time.monotonic() - last_beat > 0.3:
                self.heartbeat()
                last_beat = time.monotonic()
            message = self.recv(component=component)
            if start_sim is None and self.sim_time > 0:
                start_sim = self.sim_time
            if start_sim is not None and self.sim_time - start_sim > sim_timeout:
                break
            if message is not None and (kind is None or message.get_type() == kind) and condition(message):
                return message
        raise WaitTimeout(f"no {kind} matching the condition within {sim_timeout} s of simulated time")

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
            self.conn.mav.command_long_send(self.target, 1, command, confirmation, *values)
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


class RunningSim:
    """A SimVehicle on its own thread, talking over real UDP sockets."""

    def __init__(self, stepper, urls: list[str], speedup: float = 10.0, **options):
        self.sim = SimVehicle(stepper, SimOptions(urls, speedup=speedup, **options))
        self.thread = threading.Thread(target=self.sim.run, daemon=True)

    def __enter__(self) -> SimVehicle:
        self.thread.start()
        return self.sim

    def __exit__(self, *exc) -> None:
        self.sim.stop()
        self.thread.join(timeout=5)
