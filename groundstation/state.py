"""What the ground station knows about each vehicle, rebuilt from the MAVLink messages it hears.

``Fleet.apply(message, now)`` is the one entry point, for live links and for
replayed logs alike. Any ArduPilot vehicle (rover, copter, plane; MAVLink 1 or
2) is understood from its standard messages; our own vehicles add the memory
map and the planned path in TUNNEL messages. A vehicle that streams no map
still gets one: the ground station builds it from DISTANCE_SENSOR and the pose,
with the same memory-map code the vehicle uses. An onboard agent on a companion
computer (component 191 of the vehicle's system) is part of its vehicle: its
map, path, state and messages show on the vehicle of the same system id.
Positions are kept in the scene frame (metres east and north of the datum,
height above the vehicle's home). As it goes the Fleet keeps each vehicle's
history (``groundstation.history``): sampled telemetry and the events the
page marks on its timeline, including the commands a ground station sent
(the link hands its own messages in too, and a recording holds them).

Anyone on a link can claim to be a vehicle, so the fleet holds at most
``MAX_VEHICLES`` (a new system id is refused, and counted, until one is
forgotten) and forgets a vehicle not heard for ``FORGET_AFTER`` seconds of the
receiver's clock; a replayed log forgets nothing (``forget_after=None``). A
peer's non-finite numbers are ignored (the last good value stays).

Another ground station in command shows on the vehicle (``other_gcs``): the
fleet notes the other stations it hears (GCS heartbeats from system ids but
ours), a COMMAND_ACK or MISSION_ACK of the vehicle addressed to another system
than ours or its own, and a mode change this station did not order while
another station is heard. This station's own messages (``apply`` gets them
too: the link's and a replayed recording's) tell which orders were ours.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import numpy as np

from groundstation.history import History
from groundstation.mission_left import Route, left
from groundstation.params import failsafe, value
from vehicle.mapping.memory_map import OCCUPIED_AT, MemoryMap
from vehicle.protocol import agent_status
from vehicle.protocol.frames import Pose
from vehicle.protocol.geodesy import Datum, on_earth
from vehicle.protocol.mapstream import MapReceiver
from vehicle.protocol.mav import AUTOPILOT, COMPANION, RESULT_WORDS, mavlink
from vehicle.protocol.modes import FORCE_DISARM, commanded_mode, heartbeat_mode, name_of
from vehicle.protocol.radiostream import RADIO_LINKS, LinkLog, LinkReceiver, LinkRecord
from vehicle.protocol.rangefinder import reading_from
from vehicle.protocol.statustext import Reassembler
from vehicle.world.suites import LOOKS_UP

LINK_LOST_AFTER = 3.0  # s without a heartbeat
TRAIL_POINTS = 2000
TRAIL_SPACING = 0.3  # m between recorded trail points
HITS_KEPT = 600
MESSAGES_KEPT = 50
OWN_MAP_SPACE = 100.0  # m around home, for maps built from DISTANCE_SENSOR
OWN_MAP_RESOLUTION = 5.0  # cells/m
OWN_MAP_AFTER = 2.0  # s a vehicle is heard without a map stream or a companion before the station builds a map
# one colour per vehicle, by system id, the same in the 3D view, the 2D map and the panel (distinct on a dark
# background, and none of them the map's red or the path's yellow)
COLOURS = [(64, 156, 255), (255, 140, 40), (80, 210, 110), (230, 90, 220), (70, 220, 225), (250, 110, 130),
           (180, 150, 255), (200, 220, 60), (255, 190, 150), (150, 200, 255)]
# commands a station sends on its own account (telemetry requests): not events worth marking
QUIET_COMMANDS = {mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_REQUEST_MESSAGE}
SEVERE = mavlink.MAV_SEVERITY_WARNING  # this severity or worse is shown as a banner on the page
OWN_SYSID = 255  # this station's system id (the link's)
FALL_FROM = 1.0  # m above home: a copter disarmed higher falls (a kill's fall is a crash)
LANDED_BELOW = 0.3  # m above home: a falling copter is down
MAX_UNPLACED = 10_000  # link records a vehicle whose home is not known yet may hold
STILL = 0.2  # m/s of descent: a falling copter slower than this has come to rest
DRAIN_WINDOW = 120.0  # s of history over which the battery's drain is measured
DRAIN_AT_LEAST = 20.0  # s of history the drain needs before a flight time is estimated from it
ORDERED_WITHIN = 5.0  # s after this station's order (or the companion's) a mode change is taken as its doing
# (a mode other than the one it named is not)
MAX_STATIONS = 16  # other ground stations remembered
MODE_ORDERS = {mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_NAV_LAND,
               mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_MISSION_START, mavlink.MAV_CMD_DO_REPOSITION,
               mavlink.MAV_CMD_COMPONENT_ARM_DISARM}  # commands after which a vehicle may change its mode
MAX_VEHICLES = 64  # vehicles held at once; each may hold a map of up to 16 MB
FORGET_AFTER = 600.0  # s of the receiver's clock without a message before a vehicle is forgotten
# a vehicle's own state, taken only from its autopilot (component AUTOPILOT, whose heartbeat alone makes a
# vehicle): another part of the system, or a sender that took another component's name, does not move it
POSES = frozenset({"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE"})  # what moves a vehicle in a view
AUTOPILOTS_OWN = frozenset({"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD", "SYS_STATUS",
                            "HOME_POSITION", "MISSION_CURRENT", "MISSION_ITEM_REACHED", "PARAM_VALUE"})

TYPES = {
    mavlink.MAV_TYPE_GROUND_ROVER: "rover", mavlink.MAV_TYPE_SURFACE_BOAT: "boat",
    mavlink.MAV_TYPE_QUADROTOR: "copter", mavlink.MAV_TYPE_HEXAROTOR: "copter",
    mavlink.MAV_TYPE_OCTOROTOR: "copter", mavlink.MAV_TYPE_TRICOPTER: "copter",
    mavlink.MAV_TYPE_HELICOPTER: "copter", mavlink.MAV_TYPE_COAXIAL: "copter",
    mavlink.MAV_TYPE_DODECAROTOR: "copter",
    mavlink.MAV_TYPE_FIXED_WING: "plane", mavlink.MAV_TYPE_VTOL_DUOROTOR: "plane",
    mavlink.MAV_TYPE_VTOL_QUADROTOR: "plane", mavlink.MAV_TYPE_VTOL_TILTROTOR: "plane",
}
VEHICLE_TYPES = set(TYPES) | {mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_TYPE_AIRSHIP}
NOT_VEHICLES = {mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_TYPE_GIMBAL,
                mavlink.MAV_TYPE_ADSB, mavlink.MAV_TYPE_CAMERA, mavlink.MAV_TYPE_ANTENNA_TRACKER}


def makes_a_vehicle(mav_type: int, autopilot: int, component: int) -> bool:
    """Whether a heartbeat of this type, autopilot and sending component makes a vehicle: an autopilot's
    (QGroundControl's rule too; a replay's seek asks it of the raw bytes, to leave out what a system sent
    before it was one, as playing does)."""
    return component == AUTOPILOT and mav_type not in NOT_VEHICLES and autopilot != mavlink.MAV_AUTOPILOT_INVALID


def colour_of(sysid: int) -> tuple[int, int, int]:
    return COLOURS[(sysid - 1) % len(COLOURS)]


def hex_colour(rgb: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


@dataclass
class Sonar:
    distance: float | None  # m, None: no echo
    origin: tuple[float, float, float]
    direction: tuple[float, float, float]
    max_range: float
    time: float
    yaw_offset: float = 0.0  # degrees clockwise of the nose
    beam: float = 0.0  # degrees, half-angle of the cone (0: not said)
    pitch: float = 0.0  # degrees up of the mount (a copter's overhead sonar, a rover's ground one)


@dataclass
class VehicleState:
    sysid: int
    mav_type: int = 0
    autopilot: int = 0
    mode: str = "UNKNOWN"
    custom_mode: int = -1
    armed: bool = False
    mavlink_version: int = 2
    signed: bool | None = None  # its heartbeat carried a valid signature (None: this station has no key)
    lat: float | None = None
    lon: float | None = None
    alt: float | None = None  # m above home
    alt_msl: float | None = None  # m above sea level
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s east, north, up
    positioned: float | None = None  # receiver clock of its last GLOBAL_POSITION_INT with a fix
    x: float | None = None  # scene metres east
    y: float | None = None  # scene metres north
    roll: float = 0.0  # rad
    pitch: float = 0.0
    yaw: float = 0.0  # compass, rad
    speed: float = 0.0
    climb: float = 0.0
    voltage: float | None = None
    remaining: float | None = None
    current: float | None = None
    home: tuple[float, float] | None = None  # scene x, y
    home_latlon: tuple[float, float] | None = None
    last_heartbeat: float | None = None  # receiver clock
    last_message: float | None = None
    messages_received: int = 0
    time_boot_s: float | None = None
    mission_current: int | None = None
    mission_total: int | None = None
    mission_reached: int | None = None
    status: str = ""  # the latest STATUSTEXT
    messages: deque = field(default_factory=lambda: deque(maxlen=MESSAGES_KEPT))
    trail: deque = field(default_factory=lambda: deque(maxlen=TRAIL_POINTS))
    sonar: dict[int, Sonar] = field(default_factory=dict)
    hits: deque = field(default_factory=lambda: deque(maxlen=HITS_KEPT))
    map_stream: MapReceiver = field(default_factory=MapReceiver)
    radio_stream: LinkReceiver = field(default_factory=LinkReceiver)  # its agent's TUNNEL RADIO_LINKS
    radio_unplaced: list = field(default_factory=list)  # link records heard before its home was known
    companion_heartbeat: float | None = None  # when its onboard agent (component 191) was last heard
    agent: agent_status.AgentStatus | None = None  # the onboard agent's own state
    agent_progress: agent_status.AgentProgress | None = None  # its waypoints done and time left
    own_map: MemoryMap | None = None  # built here when the vehicle streams none
    unmapped: deque = field(default_factory=lambda: deque(maxlen=HITS_KEPT))  # readings waiting for own_map
    first_heard: float = 0.0  # receiver clock
    waypoints: list[tuple[float, float]] = field(default_factory=list)  # the AUTO mission, scene x, y
    route: Route | None = None  # the same, with item numbers, loiter times and speeds (``mission_left``)
    other_gcs: tuple[int, str, float] | None = None  # another station in command: its sysid, what showed it, when
    ordered: tuple[float, int | None] = (-math.inf, None)  # when this station or the companion last ordered a
    # mode change, and the mode (custom_mode) if the order named one
    version: int = 0  # bumps on every change, for views that redraw
    aloft: tuple[float, float] = (0.0, 0.0)  # height at the last armed heartbeat (m), fastest descent since (m/s)
    falling: tuple[float, float] | None = None  # a fall after a disarm in the air: from (m), fastest descent (m/s)
    crash: tuple[float, str] | None = None  # the last crash or fall: when (receiver clock), what
    params: dict[str, float] = field(default_factory=dict)  # its battery failsafe parameters (``params.WANTED``)
    params_ignored: int = 0  # values of those that were not finite or absurd

    @property
    def kind(self) -> str:
        return TYPES.get(self.mav_type, "other")

    @property
    def streams_map(self) -> bool:
        """The vehicle's own agent sends its map (or speaks for it): the station builds none of its own."""
        return self.map_stream.payloads > 0 or self.companion_heartbeat is not None

    def has_companion(self, now: float) -> bool:
        """An onboard agent on a companion computer speaks for this vehicle (heard within the link timeout)."""
        return self.companion_heartbeat is not None and now - self.companion_heartbeat <= LINK_LOST_AFTER

    def link_state(self, now: float) -> str:
        if self.last_heartbeat is None or now - self.last_heartbeat > LINK_LOST_AFTER:
            return "lost"
        return "ok"

    @property
    def map_source(self) -> str | None:
        if self.map_stream.grid is not None:
            return "vehicle"
        return "groundstation" if self.own_map is not None else None

    def map_grid(self) -> tuple[np.ndarray, float, tuple[float, float]] | None:
        """The memory map as (log-odds grid, resolution, south-west corner in scene metres), or None."""
        stream = self.map_stream
        if stream.grid is not None and stream.geometry is not None and self.home is not None:
            geometry = stream.geometry
            return stream.grid, geometry.resolution, (self.home[0] + geometry.origin[0],
                                                      self.home[1] + geometry.origin[1])
        if self.own_map is not None:
            return self.own_map.grid, self.own_map.resolution, self.own_map.origin
        return None

    def planned_path(self) -> list[tuple[float, float]]:
        if self.home is None:
            return []
        return [(self.home[0] + dx, self.home[1] + dy) for dx, dy in self.map_stream.path]


class Fleet:
    """Every vehicle heard, by system id. Thread-safe: the link writes, views read snapshots."""

    def __init__(self, datum: Datum | None = None, ground_height=None, forget_after: float | None = FORGET_AFTER,
                 max_vehicles: int = MAX_VEHICLES, own_sysid: int = OWN_SYSID, own_maps: bool = True,
                 history: History | None = None):
        """``own_maps``: build a map from DISTANCE_SENSOR for a vehicle that streams none (a replay's quick scan
        of its whole log, which skips most readings, does not)."""
        self.datum = datum  # None: the first home heard becomes the scene origin
        self.ground_height = ground_height or (lambda x, y: 0.0)
        self.own_maps = own_maps
        self.vehicles: dict[int, VehicleState] = {}
        self.lock = threading.RLock()
        self.version = 0
        self.texts = Reassembler()
        self.history = history or History()
        self.radio = LinkLog()  # every vehicle's link records, positions in the scene frame
        self._occupied: dict[int, tuple[tuple, int]] = {}  # sysid -> (map version, occupied cells)
        self.forget_after = forget_after  # None: never (a replayed log)
        self.max_vehicles = max_vehicles
        self.refused = 0  # heartbeats of new vehicles turned away while the fleet was full
        self.forgotten = 0
        self._swept = -math.inf  # when silent vehicles were last looked for
        self.own_sysid = own_sysid
        self.stations: OrderedDict[int, float] = OrderedDict()  # other ground stations: sysid -> last heartbeat
        self.reported: dict[int, float] = {}  # sysid -> when a vehicle last reported it as traffic (ADSB_VEHICLE)
        self.moved: set[int] = set()  # vehicles whose pose changed since a view last took them (``take_moved``)
        self.pose_news = threading.Event()  # set when one did: a view waits on it to draw a pose as it comes

    def clear(self) -> None:
        with self.lock:
            self.vehicles.clear()
            self.stations.clear()
            self.reported.clear()
            self.texts = Reassembler()
            self.history.clear()
            self._occupied.clear()
            self.radio.clear()
            self.version += 1

    def take_moved(self) -> set[int]:
        """The vehicles whose pose changed since the last call (a burst of poses is one entry each)."""
        with self.lock:
            moved, self.moved = self.moved, set()
            self.pose_news.clear()
            return moved

    def get(self, sysid: int) -> VehicleState | None:
        return self.vehicles.get(sysid)

    def ids(self) -> list[int]:
        with self.lock:
            return sorted(self.vehicles)

    # ---- messages ---------------------------------------------------------------------------------
    def apply(self, message, now: float) -> None:
        kind = message.get_type()
        if kind == "BAD_DATA":
            return
        sysid = message.get_srcSystem()
        with self.lock:
            if now - self._swept >= 1.0:
                self._forget_silent(now)
            if sysid == self.own_sysid:
                self._ours(message, now)
                return
            if kind == "HEARTBEAT" and message.type == mavlink.MAV_TYPE_GCS:
                self._station_heard(sysid, now)
            vehicle = self.vehicles.get(sysid)
            if vehicle is None and kind in ("COMMAND_LONG", "COMMAND_INT"):
                self._command_sent(message, now)  # a ground station's (ours, or another's) to a vehicle
                return
            if vehicle is None:
                if kind != "HEARTBEAT" or sysid == 0 or not makes_a_vehicle(message.type, message.autopilot,
                                                                            message.get_srcComponent()):
                    return  # only a vehicle's heartbeat makes a vehicle; 0 is MAVLink's broadcast, no one's id
                if len(self.vehicles) >= self.max_vehicles:
                    self.refused += 1
                    return
                vehicle = self.vehicles[sysid] = VehicleState(sysid, first_heard=now)
            handler = getattr(self, f"_{kind.lower()}", None)
            vehicle.last_message = now
            vehicle.messages_received += 1
            if kind in AUTOPILOTS_OWN and message.get_srcComponent() != AUTOPILOT:
                return
            if handler is not None:
                handler(vehicle, message, now)
                vehicle.version += 1
                self.version += 1
                if kind in POSES:
                    self.moved.add(sysid)
                    self.pose_news.set()
                if kind == "GLOBAL_POSITION_INT" and len(self.vehicles) > 1:
                    self.history.near_misses.check(sysid, {s: (o.x, o.y, self.height(o)) for s, o in
                                                           self.vehicles.items() if o.x is not None}, now, self.history)
            if self.history.due(sysid, now) and vehicle.last_heartbeat is not None:
                self.history.sample(sysid, now, self._sample(vehicle))

    def _sample(self, v: VehicleState) -> dict[str, float | None]:
        """The vehicle's numbers as the history keeps them."""
        values = {"altitude": v.alt, "speed": v.speed, "climb": v.climb, "heading": math.degrees(v.yaw) % 360,
                  "roll": math.degrees(v.roll), "pitch": math.degrees(v.pitch), "battery voltage": v.voltage,
                  "battery remaining": v.remaining, "battery current": v.current, "occupied cells": self.occupied(v)}
        for ident, sonar in sorted(v.sonar.items()):
            values[f"sonar {ident}"] = sonar.distance
        return values

    def _forget_silent(self, now: float) -> None:
        """Drop the vehicles not heard for ``forget_after`` seconds (never while a log replays)."""
        self._swept = now
        if self.forget_after is None:
            return
        silent = [sysid for sysid, v in self.vehicles.items() if now - (v.last_message or v.first_heard) >
                  self.forget_after]
        for sysid in silent:
            del self.vehicles[sysid]
            self.reported.pop(sysid, None)
        if silent:
            self.forgotten += len(silent)
            self.version += 1

    # ---- ground stations -------------------------------------------------------------------------
    def _ours(self, message, now: float) -> None:
        """A message this station sent: an order that may change a vehicle's mode is ours, not another's; a
        command is an event on the vehicle's timeline."""
        kind = message.get_type()
        vehicle = self.vehicles.get(getattr(message, "target_system", 0))
        if vehicle is None:
            return
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command_sent(message, now)
        if kind == "SET_MODE":
            vehicle.ordered = (now, message.custom_mode)
        elif kind in ("COMMAND_LONG", "COMMAND_INT") and message.command in MODE_ORDERS:
            named = message.command == mavlink.MAV_CMD_DO_SET_MODE
            vehicle.ordered = (now, commanded_mode(message.param2) if named else None)

    def _station_heard(self, sysid: int, now: float) -> None:
        self.stations.pop(sysid, None)
        self.stations[sysid] = now
        while len(self.stations) > MAX_STATIONS:
            self.stations.popitem(last=False)

    def _command_ack(self, vehicle, m, now) -> None:
        result = RESULT_WORDS.get(m.result, f"result {m.result}")
        target = getattr(m, "target_system", 0)
        text = f"{_command_name(m.command)}: {result}"
        source = "agent" if m.get_srcComponent() == COMPANION else "autopilot"
        if m.command in QUIET_COMMANDS:
            pass
        elif target == vehicle.sysid and m.result == mavlink.MAV_RESULT_ACCEPTED:  # the agent's routine order
            self.history.count(vehicle.sysid, now, "agent", text)
        else:
            refused = m.result != mavlink.MAV_RESULT_ACCEPTED
            self.history.event(vehicle.sysid, now, "ack", text, 4 if refused else 6,
                               "agent" if target == vehicle.sysid else source)
        if target == vehicle.sysid:  # the companion's order
            vehicle.ordered = (now, None)
        elif target not in (0, self.own_sysid):
            name = mavlink.enums["MAV_CMD"][m.command].name if m.command in mavlink.enums["MAV_CMD"] else m.command
            vehicle.other_gcs = (target, f"COMMAND_ACK {name} {result}", now)

    def _mission_ack(self, vehicle, m, now) -> None:
        if m.target_system not in (0, self.own_sysid, vehicle.sysid):
            name = mavlink.enums["MAV_MISSION_RESULT"][m.type].name if m.type in \
                mavlink.enums["MAV_MISSION_RESULT"] else m.type
            vehicle.other_gcs = (m.target_system, f"MISSION_ACK {name}", now)

    def _mode_changed(self, vehicle, mode: str, now: float) -> None:
        """Neither this station nor the companion ordered it: another station heard lately may have."""
        when, wanted = vehicle.ordered
        if now - when <= ORDERED_WITHIN and wanted in (None, vehicle.custom_mode):
            return
        heard = [sysid for sysid, when in self.stations.items() if now - when <= LINK_LOST_AFTER]
        if heard:
            vehicle.other_gcs = (heard[-1], f"mode {mode}, not ordered by this station", now)

    def _boot(self, vehicle: VehicleState, message) -> None:
        if hasattr(message, "time_boot_ms"):
            vehicle.time_boot_s = message.time_boot_ms / 1000.0

    def _heartbeat(self, vehicle, m, now) -> None:
        if m.get_srcComponent() == COMPANION and m.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER:
            vehicle.companion_heartbeat = now
            return
        if not makes_a_vehicle(m.type, m.autopilot, m.get_srcComponent()):
            return  # another part of the system: its mode is not the vehicle's
        changed = vehicle.custom_mode not in (-1, m.custom_mode)
        vehicle.mav_type = m.type
        vehicle.autopilot = m.autopilot
        vehicle.custom_mode = m.custom_mode
        armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = heartbeat_mode(m)
        if vehicle.last_heartbeat is None:
            self.history.event(vehicle.sysid, now, "mode", f"first heard: {mode}{', armed' if armed else ''}", 6)
        else:
            if mode != vehicle.mode:
                self.history.event(vehicle.sysid, now, "mode", f"mode {vehicle.mode} → {mode}", 5)
            if armed != vehicle.armed:
                self.history.event(vehicle.sysid, now, "armed", "armed" if armed else "disarmed", 5)
            start, descent = vehicle.aloft
            if vehicle.armed and not armed and vehicle.kind == "copter" and start > FALL_FROM:
                vehicle.falling = (start, descent)
                self._crash(vehicle, now, f"disarmed in the air at {start:.1f} m above home: falling")
        if armed:
            vehicle.aloft = (vehicle.alt or 0.0, 0.0)
        vehicle.armed = armed
        vehicle.mode = mode
        if changed:
            self._mode_changed(vehicle, vehicle.mode, now)
        vehicle.mavlink_version = 2 if m.get_msgbuf()[:1] == b"\xfd" else 1
        vehicle.signed = getattr(m, "_verified", None)  # set by a link with a signing key
        vehicle.last_heartbeat = now

    def _ensure_datum(self, lat: float, lon: float) -> Datum:
        if self.datum is None:
            self.datum = Datum(lat, lon, 0.0)
        return self.datum

    def _global_position_int(self, vehicle, m, now) -> None:
        self._boot(vehicle, m)
        if m.lat == 0 and m.lon == 0 or not on_earth(m.lat * 1e-7, m.lon * 1e-7):
            return  # no fix, or no place on Earth
        lat, lon = m.lat * 1e-7, m.lon * 1e-7
        datum = self._ensure_datum(lat, lon)
        vehicle.lat, vehicle.lon, vehicle.alt = lat, lon, m.relative_alt / 1000.0
        vehicle.x, vehicle.y = datum.to_local(lat, lon)
        vehicle.alt_msl, vehicle.positioned = m.alt / 1000.0, now
        vehicle.velocity = (m.vy / 100.0, m.vx / 100.0, -m.vz / 100.0)
        vehicle.speed = math.hypot(m.vx, m.vy) / 100.0
        vehicle.climb = -m.vz / 100.0
        self._fall(vehicle, now)
        if m.hdg != 65535:
            vehicle.yaw = math.radians(m.hdg / 100.0)
        if vehicle.home is None:  # until HOME_POSITION comes, the first fix is home
            vehicle.home = (vehicle.x, vehicle.y)
        self._extend_trail(vehicle)

    def _adsb_vehicle(self, vehicle, m, now) -> None:
        """A vehicle tells of a team-mate it hears (our simulated world's autopilots do): that one needs no
        relay (``groundstation.traffic_relay``). Only vehicles held are noted, so a flood of addresses costs
        nothing."""
        if m.ICAO_address in self.vehicles and m.ICAO_address != vehicle.sysid:
            self.reported[m.ICAO_address] = now

    def _local_position_ned(self, vehicle, m, now) -> None:
        self._boot(vehicle, m)
        if vehicle.lat is not None or not _finite(m.x, m.y, m.z):
            return  # the global position is better; a broken one keeps the last good one
        home = vehicle.home or (0.0, 0.0)
        vehicle.home = home
        vehicle.x, vehicle.y, vehicle.alt = home[0] + m.y, home[1] + m.x, -m.z
        if _finite(m.vx, m.vy, m.vz):
            vehicle.speed = math.hypot(m.vx, m.vy)
            vehicle.climb = -m.vz
        self._extend_trail(vehicle)

    def _fall(self, vehicle, now: float) -> None:
        """A copter that fell after a disarm in the air (heard at the next heartbeat, a second later, when it
        may be down already): its impact, once it stops falling, is an event too."""
        if vehicle.armed:
            start, descent = vehicle.aloft
            vehicle.aloft = (start, max(descent, -vehicle.climb))
        if vehicle.falling is None:
            return
        start, fastest = vehicle.falling
        fastest = max(fastest, -vehicle.climb)
        vehicle.falling = (start, fastest)
        if vehicle.climb > -STILL or vehicle.alt <= LANDED_BELOW:
            vehicle.falling = None
            self._crash(vehicle, now, f"crashed: fell {start - vehicle.alt:.1f} m, hitting the ground at "
                                      f"{fastest:.1f} m/s")

    def _crash(self, vehicle, now: float, text: str) -> None:
        vehicle.crash = (now, text)
        self.history.event(vehicle.sysid, now, "crash", text, mavlink.MAV_SEVERITY_CRITICAL, "station")

    def _extend_trail(self, vehicle) -> None:
        point = (vehicle.x, vehicle.y, self.height(vehicle))
        if not vehicle.trail or math.dist(vehicle.trail[-1], point) >= TRAIL_SPACING:
            vehicle.trail.append(point)

    def height(self, vehicle: VehicleState) -> float:
        """Scene z of the vehicle: its home's ground plus its height above home."""
        home = vehicle.home or (vehicle.x or 0.0, vehicle.y or 0.0)
        return self.ground_height(*home) + (vehicle.alt or 0.0)

    def _attitude(self, vehicle, m, now) -> None:
        self._boot(vehicle, m)
        if _finite(m.roll, m.pitch, m.yaw):  # a broken estimate keeps the last good attitude
            vehicle.roll, vehicle.pitch = m.roll, m.pitch
            vehicle.yaw = m.yaw % (2 * math.pi)

    def _vfr_hud(self, vehicle, m, now) -> None:
        if _finite(m.groundspeed, m.climb):
            vehicle.speed = m.groundspeed
            vehicle.climb = m.climb

    def _sys_status(self, vehicle, m, now) -> None:
        vehicle.voltage = m.voltage_battery / 1000.0 if m.voltage_battery not in (0, 65535) else None
        vehicle.current = m.current_battery / 100.0 if m.current_battery >= 0 else None
        vehicle.remaining = m.battery_remaining if m.battery_remaining >= 0 else None

    def _home_position(self, vehicle, m, now) -> None:
        if not on_earth(m.latitude * 1e-7, m.longitude * 1e-7):
            return
        lat, lon = m.latitude * 1e-7, m.longitude * 1e-7
        datum = self._ensure_datum(lat, lon)
        vehicle.home_latlon = (lat, lon)
        vehicle.home = datum.to_local(lat, lon)

    def _statustext(self, vehicle, m, now) -> None:
        for severity, text in self.texts.feed(m, now):  # whole texts, put together from their chunks
            vehicle.status = text
            vehicle.messages.append({"time": now, "severity": severity, "text": text})
            source = "agent" if m.get_srcComponent() == COMPANION else "autopilot"
            self.history.event(vehicle.sysid, now, "message", text, severity, source, routine=True)
            if "crash" in text.lower() and severity <= mavlink.MAV_SEVERITY_CRITICAL:  # ArduPilot's "Crash: Disarming"
                vehicle.crash = (now, text)

    def _command_sent(self, m, now: float) -> None:
        """A command from a ground station to a vehicle we know: an event on the vehicle's timeline (a retry,
        with its confirmation count up, is the same command)."""
        vehicle = self.vehicles.get(m.target_system)
        if vehicle is None or m.command in QUIET_COMMANDS or getattr(m, "confirmation", 0):
            return
        self.history.event(vehicle.sysid, now, "command", f"sent {_command_text(vehicle, m)}", 5, "operator")

    def _param_value(self, vehicle, m, now) -> None:
        """One of the battery failsafe parameters the link asks for (any other is not the station's business)."""
        known = value(m)
        if known is None:
            return
        name, number = known
        if number is None:
            vehicle.params_ignored += 1
        else:
            vehicle.params[name] = number

    def _mission_current(self, vehicle, m, now) -> None:
        vehicle.mission_current = m.seq
        total = getattr(m, "total", 0)
        vehicle.mission_total = total if total and total != 65535 else vehicle.mission_total

    def _mission_item_reached(self, vehicle, m, now) -> None:
        vehicle.mission_reached = m.seq

    def _tunnel(self, vehicle, m, now) -> None:
        payload = bytes(m.payload[:m.payload_length])
        if m.payload_type == agent_status.AGENT_STATUS:
            status = agent_status.decode(payload)
            if status is not None and status != vehicle.agent:
                worry = status.paused or status.outcome == "stopped"
                self.history.event(vehicle.sysid, now, "agent", _agent_text(status), 4 if worry else 6, "agent")
            vehicle.agent = status or vehicle.agent
        elif m.payload_type == agent_status.AGENT_PROGRESS:
            vehicle.agent_progress = agent_status.decode_progress(payload) or vehicle.agent_progress
        elif m.payload_type == RADIO_LINKS:  # the agent's (a simulator's autopilot forwards them to it)
            if m.get_srcComponent() == COMPANION:
                self._radio_links(vehicle, vehicle.radio_stream.feed(payload, vehicle.sysid))
        else:
            vehicle.map_stream.feed(m.payload_type, payload)

    def _radio_links(self, vehicle, records: list[LinkRecord]) -> None:
        """Link records (relative to the vehicle's home) into the fleet's log, in the scene frame; those heard
        before the home is known wait for it."""
        if vehicle.home is None:
            vehicle.radio_unplaced = (vehicle.radio_unplaced + records)[-MAX_UNPLACED:]
            return
        records, vehicle.radio_unplaced = vehicle.radio_unplaced + records, []
        hx, hy = vehicle.home
        self.radio.append(LinkRecord(r.t, r.tx, r.rx, r.tx_x + hx, r.tx_y + hy, r.rx_x + hx, r.rx_y + hy, r.rssi,
                                     r.channel) for r in records)

    def _distance_sensor(self, vehicle, m, now) -> None:
        self._boot(vehicle, m)
        if vehicle.x is None:
            return
        pose = Pose(vehicle.x, vehicle.y, self.height(vehicle), vehicle.yaw, vehicle.pitch, vehicle.roll)
        reading = reading_from(m, pose, now)
        if reading is None:
            return
        vehicle.sonar[m.id] = Sonar(reading.distance, pose.xyz(), tuple(reading.direction.tolist()),
                                    reading.max_range, now, reading.yaw_offset, reading.beam_angle, reading.pitch)
        if reading.distance is not None:
            vehicle.hits.append(tuple(reading.hit.tolist()))
        if vehicle.streams_map or vehicle.home is None or not self.own_maps:
            vehicle.unmapped.clear()
            return
        vehicle.unmapped.append(reading)
        if vehicle.own_map is None and now - vehicle.first_heard < OWN_MAP_AFTER:
            return  # a vehicle whose agent streams its map says so within a second or two: wait for it
        if vehicle.own_map is None:
            vehicle.own_map = MemoryMap(vehicle.home, OWN_MAP_SPACE, OWN_MAP_RESOLUTION)
        while vehicle.unmapped:
            done = vehicle.unmapped.popleft()
            # an overhead sensor's beam rises over the walls the level ones see: its echo marks, its beam never clears
            vehicle.own_map.add_reading(done.origin, done.direction, done.distance, done.max_range,
                                        free=done.pitch < LOOKS_UP)

    # ---- views --------------------------------------------------------------------------------
    def describe(self, v: VehicleState, now: float) -> dict:
        """The vehicle as the REST API and the page's stream show it."""
        age = None if v.last_heartbeat is None else round(now - v.last_heartbeat, 2)
        position = None
        if v.x is not None:
            position = {"lat": _round(v.lat, 7), "lon": _round(v.lon, 7), "alt": _round(v.alt), "x": _round(v.x),
                        "y": _round(v.y), "z": _round(self.height(v))}
        return {
            "sysid": v.sysid, "type": v.kind, "colour": hex_colour(colour_of(v.sysid)), "mode": v.mode,
            "armed": v.armed, "position": position,
            "attitude": {"roll": _round(math.degrees(v.roll)), "pitch": _round(math.degrees(v.pitch)),
                         "yaw": _round(math.degrees(v.yaw))},
            "heading": _round(math.degrees(v.yaw) % 360), "speed": _round(v.speed), "climb": _round(v.climb),
            "battery": None if v.voltage is None else {"voltage": _round(v.voltage), "remaining": v.remaining,
                                                       "current": _round(v.current),
                                                       "flight_left_s": _round(self.flight_left(v), 0),
                                                       "failsafe": failsafe(v.params, v.kind),
                                                       "params_ignored": v.params_ignored},
            "link": {"state": v.link_state(now), "heartbeat_age": age, "messages": v.messages_received,
                     "mavlink": v.mavlink_version, "signed": v.signed},
            "mission": {"current": v.mission_current, "total": v.mission_total, "reached": v.mission_reached,
                        "left": left(v.route, v.mission_current, (v.x, v.y), v.speed)},
            "status": v.status,
            "status_age": _round(now - v.messages[-1]["time"], 1) if v.messages else None,
            "agent": None if v.agent is None else {
                "state": v.agent.state, "phase": v.agent.phase, "paused": v.agent.paused, "outcome": v.agent.outcome,
                "mission": v.agent.mission, "reason": v.agent.reason, "companion": v.has_companion(now),
                "operator": v.agent.operator, "progress": _progress(v.agent_progress)},
            "home": None if v.home is None else {"x": _round(v.home[0]), "y": _round(v.home[1])},
            "time_boot_s": _round(v.time_boot_s, 3),
            "messages": list(v.messages)[-20:],
            "map": {"occupied": self.occupied(v), "source": v.map_source},
            "near_misses": self.history.near_misses.counts.get(v.sysid, 0),
            "path": [[_round(x), _round(y)] for x, y in v.planned_path()],
            "waypoints": [[_round(x), _round(y)] for x, y in v.waypoints[:MAX_WAYPOINTS_SHOWN]],
            "sonar": [{"id": ident, "distance": _round(s.distance), "max_range": _round(s.max_range),
                       "bearing": _round(s.yaw_offset % 360, 1), "beam": _round(s.beam, 1),
                       "pitch": _round(s.pitch, 1),
                       "age": _round(max(0.0, now - s.time))} for ident, s in sorted(v.sonar.items())],
            "crash": None if v.crash is None else {"text": v.crash[1], "age": _round(now - v.crash[0], 1)},
            "other_gcs": None if v.other_gcs is None else {"sysid": v.other_gcs[0], "last": v.other_gcs[1],
                                                           "age": _round(now - v.other_gcs[2], 1)},
        }

    def flight_left(self, v: VehicleState) -> float | None:
        """About how long the battery lasts at the rate it drained over the last DRAIN_WINDOW s of its history
        (s of the station's clock); None until it has drained for DRAIN_AT_LEAST s, or while it does not."""
        history = self.history.vehicles.get(v.sysid)
        if history is None or v.remaining is None:
            return None
        times, values = history.ordered()
        column = values[:, history.columns["battery remaining"]]
        known = (times >= history.last - DRAIN_WINDOW) & ~np.isnan(column)
        if np.count_nonzero(known) < 2:
            return None
        times, column = times[known], column[known]
        span, drop = times[-1] - times[0], float(column[0] - column[-1])
        if span < DRAIN_AT_LEAST or drop <= 0:
            return None
        return v.remaining / (drop / span)

    @staticmethod
    def map_version(v: VehicleState) -> tuple:
        """Changes whenever the vehicle's map does."""
        return v.map_source, v.map_stream.version, v.own_map.version if v.own_map is not None else 0

    def occupied(self, v: VehicleState) -> int | None:
        """Occupied cells of the vehicle's map (counted again only when the map changed: a 2000 x 2000 map
        takes milliseconds, and every status frame and history sample asks)."""
        grid = v.map_grid()
        if grid is None:
            return None
        version = self.map_version(v)
        cached = self._occupied.get(v.sysid)
        if cached is None or cached[0] != version:
            cached = self._occupied[v.sysid] = (version, int(np.count_nonzero(grid[0] >= OCCUPIED_AT)))
        return cached[1]


def _round(value: float | None, digits: int = 2) -> float | None:
    """A number for JSON: rounded, and None where there is none or it is not finite (JSON has no NaN)."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits)


MAX_WAYPOINTS_SHOWN = 500


def _command_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else f"command {command}"


def _command_text(vehicle: VehicleState, m) -> str:
    """A command as the operator would say it: "DO_SET_MODE RTL", "arm", "kill"."""
    if m.command == mavlink.MAV_CMD_DO_SET_MODE and m.param1 == mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        number = commanded_mode(m.param2)
        if number is None:
            return f"DO_SET_MODE {m.param2}"  # as sent: "nan", "inf", "-1.0"
        return f"DO_SET_MODE {name_of(vehicle.mav_type, number) or number}"
    if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
        return "arm" if m.param1 == 1 else "kill" if m.param2 == FORCE_DISARM else "disarm"
    to = " to the onboard agent" if m.target_component == COMPANION else ""
    return _command_name(m.command) + to


def _progress(progress: agent_status.AgentProgress | None) -> dict | None:
    if progress is None:
        return None
    return {"done": progress.done, "total": progress.total, "time_left": _round(progress.time_left, 0)}


def _agent_text(status: agent_status.AgentStatus) -> str:
    text = f"{status.mission or 'agent'} {status.state} ({status.phase})"
    return f"{text}: {status.reason}" if status.reason else text


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


