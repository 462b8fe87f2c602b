"""``vehicle sim``: a simulated vehicle, live on MAVLink links, with its onboard agent or as a plain autopilot.

The all-in-one vehicle puts the autopilot (component 1) and its onboard agent
(component 191, ``vehicle.agent.companion``) on the same links, as a flight
controller and its companion computer are seen from a ground station. As a
plain autopilot (``--role autopilot``) it has no agent: an onboard agent in
another process flies it over MAVLink, and its telemetry runs on simulated
time, as ArduPilot's SITL does, so that agent sees the same rates at any speed-up.

Two clocks run side by side: the world advances on
simulated time, ``speedup`` times faster than the wall clock, while everything
a ground station observes (message rates, heartbeats, the GCS failsafe, log
timestamps) runs on the wall clock. ``time_boot_ms`` in the messages is the
vehicle's simulated time since boot, as in ArduPilot's SITL, so tests can wait
in simulated time.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from vehicle.agent.companion import COMPONENT, Companion
from vehicle.lab.experiment import warm_up
from vehicle.lab.stepper import Stepper
from vehicle.protocol.links import LinkWatch
from vehicle.protocol.mav import mavlink
from vehicle.protocol.tlog import TlogWriter
from vehicle.sim.endpoint import Endpoint
from vehicle.sim.telemetry import Telemetry

TICK = 0.01  # s of wall time between loop iterations
MAX_LAG = 0.5  # s of wall time the simulation may fall behind before it gives up catching up


@dataclass
class SimOptions:
    urls: list[str]
    sysid: int = 1
    speedup: float = 1.0
    failsafe_timeout: float = 5.0
    log: str | None = None
    sim_clock: bool = False  # telemetry rates in simulated time, as ArduPilot's SITL keeps them (a plain autopilot)
    signing_key: bytes | None = None  # MAVLink 2 signing: sign everything, refuse what is not signed


def _to_stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class SimVehicle:
    def __init__(self, stepper: Stepper, options: SimOptions, say: Callable[[str], None] = _to_stderr):
        """``say`` tells the user what goes wrong on the way (a link down)."""
        self.stepper = stepper
        self.world = stepper.simulation
        self.agent = stepper.agent
        self.options = options
        now = time.time()
        self.telemetry = Telemetry(self.world, start=self.world.time if options.sim_clock else now,
                                   sysid=options.sysid)
        self.companion = Companion(self.agent, options.sysid, start=now) if self.agent is not None else None
        self.log = TlogWriter(options.log) if options.log else None
        self.endpoint = Endpoint(options.urls, self.world, self.telemetry, options.sysid, options.failsafe_timeout,
                                 self.log, onboard=self.companion, signing_key=options.signing_key)
        self.links = LinkWatch(self.endpoint.links)
        self.say = say
        self.stop_event = threading.Event()
        self.lagging = 0.0  # simulated seconds dropped because the machine could not keep up
        self._crash_reported = False

    def run(self, duration: float | None = None) -> None:
        """Run until ``stop()`` (or for ``duration`` wall seconds)."""
        warm_up()  # before the clock starts: a loop compiled mid-flight would freeze the vehicle for seconds
        started = time.monotonic()
        sim_start = self.world.time
        last_flush = started
        try:
            while not self.stop_event.is_set():
                wall = time.monotonic()
                if duration is not None and wall - started >= duration:
                    break
                now = time.time()
                self.endpoint.poll(now)
                for line in self.links.changes():
                    self.say(line)
                target = sim_start + (wall - started) * self.options.speedup - self.lagging
                outgoing = self._advance(target, now, deadline=wall + MAX_LAG)
                if self.world.time < target - MAX_LAG * self.options.speedup:
                    self.lagging += target - self.world.time  # too slow: let simulated time slip
                if not self.options.sim_clock:
                    outgoing += self.telemetry.tick(now)
                self.endpoint.send(outgoing, now)
                if self.companion is not None:
                    self.endpoint.send(self.companion.tick(now), now, COMPONENT)
                if self.log is not None and wall - last_flush >= 1.0:
                    self.log.flush()
                    last_flush = wall
                time.sleep(max(0.0, TICK - (time.monotonic() - wall)))
        finally:
            self.endpoint.close()
            if self.log is not None:
                self.log.close()

    def _advance(self, target: float, now: float, deadline: float) -> list:
        """Step the world up to simulated time ``target``; returns the DISTANCE_SENSOR messages of its readings."""
        world, stepper = self.world, self.stepper
        messages = []
        while world.time + world.dt / 2 <= target and time.monotonic() < deadline:
            readings = stepper.step()
            messages += [self.telemetry.distance_sensor(r, world.time) for r in readings]
            if self.options.sim_clock:
                messages += self.telemetry.tick(world.time)
            if world.collision is not None and not self._crash_reported:
                self._crash_reported = True
                world.autopilot.say(f"Crash: {world.collision.describe()}", mavlink.MAV_SEVERITY_CRITICAL)
        return messages

    def stop(self) -> None:
        self.stop_event.set()
