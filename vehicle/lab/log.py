"""A headless run recorded as a telemetry log: what ``vehicle sim`` would have sent, on simulated time.

The log carries the autopilot's messages (component 1) and the agent's
(component 191: its heartbeat, map, path, state and messages), stamped with
simulated time counted from ``LOG_EPOCH``, so the same run always writes the
same file and ``groundstation replay`` plays it like a live recording.
"""

from __future__ import annotations

from pathlib import Path

from vehicle.agent.companion import COMPONENT, Companion
from vehicle.lab.stepper import Stepper
from vehicle.protocol.mav import mavlink, pack
from vehicle.protocol.rangefinder import Reading
from vehicle.protocol.tlog import LOG_EPOCH, TlogWriter
from vehicle.sim.telemetry import Telemetry

AUTOPILOT = mavlink.MAV_COMP_ID_AUTOPILOT1


class ExperimentLog:
    """Pass it as ``on_step`` to ``run_experiment``; ``close`` writes the final state."""

    def __init__(self, path: str | Path, sysid: int = 1):
        self.writer = TlogWriter(path)
        self.sysid = sysid
        self.packers = {c: mavlink.MAVLink(None, srcSystem=sysid, srcComponent=c) for c in (AUTOPILOT, COMPONENT)}
        self.telemetry: Telemetry | None = None
        self.companion: Companion | None = None
        self.time = 0.0
        self.messages = 0

    def __call__(self, stepper: Stepper, readings: list[Reading]) -> None:
        if self.telemetry is None:
            self.telemetry = Telemetry(stepper.simulation, start=0.0, sysid=self.sysid)
            if stepper.agent is not None:
                self.companion = Companion(stepper.agent, self.sysid, start=0.0)
        now = self.time = stepper.simulation.time
        telemetry = self.telemetry
        self._write(telemetry.tick(now) + [telemetry.distance_sensor(r, now) for r in readings], now, AUTOPILOT)
        if self.companion is not None:
            self._write(self.companion.tick(now), now, COMPONENT)

    def _write(self, messages: list, now: float, component: int) -> None:
        stamp = LOG_EPOCH + now
        packer = self.packers[component]
        for message in messages:
            self.writer.write(pack(message, packer), stamp)
        self.messages += len(messages)

    def close(self) -> None:
        """Finish with heartbeats and a full map snapshot, so the log ends on the final state."""
        telemetry, now = self.telemetry, self.time
        if telemetry is not None:
            self._write([telemetry.heartbeat(now), telemetry.global_position(now)] + telemetry.events(now), now,
                        AUTOPILOT)
        if self.companion is not None:
            self._write(self.companion.final(), now, COMPONENT)
        self.writer.close()
