"""A minimal independent ground station for tests: pymavlink's mavlink_connection on a real UDP socket.

Its waits are the harness's (``harness.wait_sim``), bounded in the vehicle's
simulated time: the ``time_boot_ms`` it reports.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from harness import WaitTimeout, during, wait_sim

from vehicle.protocol.mav import AUTOPILOT, mavlink, mavutil


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
        for left in during(timeout):
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
