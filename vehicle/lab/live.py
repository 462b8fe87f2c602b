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

A team (``SimTeam``, ``vehicle sim --vehicles N``) is one world and one loop
serving N vehicles, each with its own links, system id and telemetry, as N
SITL instances are: one process, because the vehicles must share one world on
one deterministic clock (sonars that echo off each other, a collision check
between bodies), and one loop stepping them costs no more than one per vehicle.
Each autopilot tells its links where the others are as ADSB_VEHICLE.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from vehicle.agent.companion import COMPONENT, Companion
from vehicle.lab.experiment import warm_up
from vehicle.lab.stepper import Stepper, TeamStepper
from vehicle.protocol.links import LinkWatch
from vehicle.protocol.mav import mavlink
from vehicle.protocol.radiostream import PAYLOAD, RADIO_LINKS, LinkSender
from vehicle.protocol.tlog import TlogWriter
from vehicle.sim.endpoint import Endpoint
from vehicle.sim.radios import Radios
from vehicle.sim.team import Team
from vehicle.sim.telemetry import Telemetry, adsb_vehicle

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
    def __init__(self, stepper: Stepper, options: SimOptions, say: Callable[[str], None] = _to_stderr,
                 radios: Radios | None = None):
        """``say`` tells the user what goes wrong on the way (a link down); ``radios``: the world's radios, whose
        records each agent sends."""
        self.stepper = stepper
        self.radios = radios
        self.world = stepper.simulation
        self.agent = stepper.agent
        self.options = options
        self.say = say
        self.log = TlogWriter(options.log) if options.log else None
        self.wires = [_Wire(self.world, self.agent, options, self.log)]
        self.telemetry, self.companion = self.wires[0].telemetry, self.wires[0].companion
        self.endpoint, self.links = self.wires[0].endpoint, self.wires[0].links
        self.stop_event = threading.Event()
        self.lagging = 0.0  # simulated seconds dropped because the machine could not keep up

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
                for wire in self.wires:
                    wire.endpoint.poll(now)
                    for line in wire.links.changes():
                        self.say(line)
                target = sim_start + (wall - started) * self.options.speedup - self.lagging
                outgoing = self._advance(target, now, deadline=wall + MAX_LAG)
                if self.world.time < target - MAX_LAG * self.options.speedup:
                    self.lagging += target - self.world.time  # too slow: let simulated time slip
                if not self.options.sim_clock:
                    for wire, messages in zip(self.wires, outgoing, strict=True):
                        messages += wire.telemetry.tick(now)
                    self._add_traffic(outgoing, now)
                for wire, messages in zip(self.wires, outgoing, strict=True):
                    wire.endpoint.send(messages, now)
                    if wire.companion is not None:
                        wire.endpoint.send(wire.companion.tick(now), now, COMPONENT)
                if self.log is not None and wall - last_flush >= 1.0:
                    self.log.flush()
                    last_flush = wall
                time.sleep(max(0.0, TICK - (time.monotonic() - wall)))
        finally:
            for wire in self.wires:
                wire.endpoint.close()
            if self.log is not None:
                self.log.close()

    def _advance(self, target: float, now: float, deadline: float) -> list[list]:
        """Step the world up to simulated time ``target``; returns each vehicle's DISTANCE_SENSOR messages of
        its readings (and, on simulated time, its telemetry)."""
        world = self.world
        messages: list[list] = [[] for _ in self.wires]
        while world.time + world.dt / 2 <= target and time.monotonic() < deadline:
            for wire, readings, out in zip(self.wires, self._step(), messages, strict=True):
                out += [wire.telemetry.distance_sensor(r, world.time) for r in readings]
                if self.options.sim_clock:
                    out += wire.telemetry.tick(world.time)
                wire.say_crash()
            if self.radios is not None:
                self._radio(messages)
            if self.options.sim_clock:
                self._add_traffic(messages, world.time)
        return messages

    def _step(self) -> list[list]:
        """One step of the world: each vehicle's readings."""
        return [self.stepper.step()]

    def _radio(self, messages: list[list]) -> None:
        """Each agent gets what its vehicle's radio heard in the step: in this process, or, for an agent in
        another, forwarded by the flight controller in TUNNEL RADIO_LINKS addressed to it."""
        positions = {wire.telemetry.sysid: tuple(wire.world.body.pose.xyz()) for wire in self.wires}
        heard = self.radios.step(self.world.time, positions)
        for wire, out in zip(self.wires, messages, strict=True):
            records = heard.get(wire.telemetry.sysid)
            if not records:
                continue
            if wire.companion is not None:
                wire.companion.hear(records)
            else:
                out += [mavlink.MAVLink_tunnel_message(wire.telemetry.sysid, COMPONENT, RADIO_LINKS, len(payload),
                                                       list(payload.ljust(PAYLOAD, b"\0")))
                        for payload in wire.radio.payloads(records)]

    def _add_traffic(self, messages: list[list], now: float) -> None:
        """A lone vehicle has no team-mates to report."""

    def stop(self) -> None:
        self.stop_event.set()


class _Wire:
    """One vehicle on the wire: its telemetry, its onboard agent's companion (if it carries one), its MAVLink
    endpoint and the watch on its links."""

    def __init__(self, world, agent, options: SimOptions, log: TlogWriter | None):
        now = time.time()
        self.world = world
        self.telemetry = Telemetry(world, start=world.time if options.sim_clock else now, sysid=options.sysid)
        self.companion = Companion(agent, options.sysid, start=now) if agent is not None else None
        self.endpoint = Endpoint(options.urls, world, self.telemetry, options.sysid, options.failsafe_timeout,
                                 log, onboard=self.companion, signing_key=options.signing_key)
        self.links = LinkWatch(self.endpoint.links)
        self._crash_reported = False
        self.radio = LinkSender()  # the vehicle's radio, forwarded to an agent in another process

    def say_crash(self) -> None:
        """The autopilot says once that the vehicle crashed, and into what."""
        world = self.world
        if world.collision is not None and not self._crash_reported:
            self._crash_reported = True
            world.autopilot.say(f"Crash: {world.collision.describe()}", mavlink.MAV_SEVERITY_CRITICAL)


ADSB_PERIOD = 0.25  # s between two ADSB_VEHICLE reports of each team-mate (4 Hz, on the telemetry's clock)


class Autopilots:
    """A team's plain autopilots in one world, no agent on board: each is flown from its own process."""

    def __init__(self, team: Team):
        self.team = team
        self.agents = [None] * len(team)

    def step(self) -> list[list]:
        return self.team.step()


class SimTeam(SimVehicle):
    """A team in one world (``vehicle.sim.team.Team``) on the one simulated clock, each vehicle on its own links
    with its own system id and its own telemetry, as N SITL instances are. Every vehicle's autopilot reports each
    team-mate as ADSB_VEHICLE every ADSB_PERIOD, as an ArduPilot with an ADS-B receiver forwards what it hears:
    that is how an agent in another process learns where the others are (``MavlinkController.traffic``)."""

    def __init__(self, stepper: Autopilots | TeamStepper, options: list[SimOptions],
                 say: Callable[[str], None] = _to_stderr, radios: Radios | None = None):
        """``options``: one per vehicle, in the team's order (the first's speed-up, clock and log serve all)."""
        self.stepper = stepper
        self.radios = radios
        self.team = stepper.team
        self.world = self.team.simulations[0]
        self.agent = None
        self.options = options[0]
        self.say = say
        self.log = TlogWriter(self.options.log) if self.options.log else None
        self.wires = [_Wire(world, agent, own, self.log)
                      for world, agent, own in zip(self.team.simulations, stepper.agents, options, strict=True)]
        self.endpoint = self.wires[0].endpoint
        self.stop_event = threading.Event()
        self.lagging = 0.0
        self._traffic_due = -math.inf

    def _step(self) -> list[list]:
        return self.stepper.step()

    def _add_traffic(self, messages: list[list], now: float) -> None:
        if len(self.wires) < 2 or now < self._traffic_due:
            return
        self._traffic_due = max(self._traffic_due + ADSB_PERIOD, now)
        reports = [adsb_vehicle(world, sysid) for world, sysid in zip(self.team.simulations, self.team.ids,
                                                                        strict=True)]
        for index, out in enumerate(messages):
            out += reports[:index] + reports[index + 1:]
