"""The simulated autopilot on the wire: MAVLink links, commands, parameters, missions, the GCS failsafe.

It makes the simulated flight controller look like ArduPilot to any ground
station or companion computer: every COMMAND_LONG/COMMAND_INT gets a
COMMAND_ACK (unknown commands MAV_RESULT_UNSUPPORTED), modes use ArduPilot's
numbers, missions follow their protocol. Garbage, truncated packets and
messages for other systems are counted and ignored. All timing here
(failsafe, retries) is wall-clock time.

An onboard computer in the same process (``Onboard``: the all-in-one
``vehicle sim``) shares the links as its own component: messages addressed to
it are its to answer, and it serves the vehicle's parameters and takes a
MISSION_START in AUTO when its mission waits or is paused. A GUIDED target or
a yaw from anyone but the vehicle's own companion is recorded as an override,
which an onboard agent takes as an operator taking over.

Only a ground station or the vehicle's own companion computer is obeyed: a
sender whose system id sent a HEARTBEAT of type GCS within the failsafe
timeout, or component 191 of the vehicle's own system. Anyone else's command
gets COMMAND_ACK DENIED (so it knows), its other orders (modes, GUIDED
targets, mission and parameter writes, manual control) are dropped, and one
STATUSTEXT per sender says why. Reading (parameters, the mission, telemetry
requests after a heartbeat) is for anyone who asks as a ground station.
(ArduPilot obeys anyone on its links; a real vehicle relies on signing.)

With a signing key it signs everything it sends and refuses every message
not signed with that key but RADIO_STATUS, as ArduPilot does once signing is
set up (``vehicle.protocol.signing``); a refused message is dropped before it
is handled or routed.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Protocol

from vehicle.protocol import links, signing
from vehicle.protocol.geodesy import on_earth
from vehicle.protocol.mav import (
    ACCEPTED,
    AUTOPILOT,
    COMPANION,
    DENIED,
    UNSUPPORTED,
    mavlink,
    pack,
)
from vehicle.protocol.modes import FORCE_DISARM, STOP_MODE, Kind, mode_name
from vehicle.protocol.tlog import TlogWriter
from vehicle.sim.avoidance import MARGIN as AVOID_MARGIN
from vehicle.sim.mission_server import MissionServer
from vehicle.sim.simulation import BATTERY_CRITICAL, BATTERY_LOW, Simulation
from vehicle.sim.telemetry import Telemetry

GCS = mavlink.MAV_TYPE_GCS
MISSION_MESSAGES = {"MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_COUNT",
                    "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT"}
COMMANDS = {"COMMAND_LONG", "COMMAND_INT"}
ORDERS = {"SET_MODE", "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT", "SET_ATTITUDE_TARGET",
          "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
          "MISSION_WRITE_PARTIAL_LIST", "PARAM_SET", "MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE"}  # obeyed, not asked
MAX_TOLD = 256  # strangers remembered as told why they are not obeyed
POSITION_IGNORED = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE)
VELOCITY_IGNORED = (mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE)


class _Command:
    """COMMAND_LONG and COMMAND_INT alike: param1..7, with COMMAND_INT's x, y, z as param5..7."""

    def __init__(self, message):
        self.command = message.command
        self.is_int = message.get_type() == "COMMAND_INT"
        for n in range(1, 5):
            setattr(self, f"param{n}", float(getattr(message, f"param{n}")))
        fifth, sixth, seventh = (message.x, message.y, message.z) if self.is_int else (
            message.param5, message.param6, message.param7)
        self.param5, self.param6, self.param7 = float(fifth), float(sixth), float(seventh)

    @property
    def latitude(self) -> float:
        return self.param5 * 1e-7 if self.is_int else self.param5

    @property
    def longitude(self) -> float:
        return self.param6 * 1e-7 if self.is_int else self.param6


class Onboard(Protocol):
    """An onboard computer in the same process, sharing the endpoint's links as its own component."""

    component: int

    def handle(self, message) -> list | None:
        """Replies to a message (addressed to it, or a parameter message for the vehicle); None: not its."""

    def mission_start(self) -> bool:
        """MISSION_START in AUTO: True if it took it (its mission waited or was paused)."""


class Endpoint:
    def __init__(self, urls: list[str], world: Simulation, telemetry: Telemetry, sysid: int = 1,
                 failsafe_timeout: float = 5.0, log: TlogWriter | None = None, onboard: Onboard | None = None,
                 signing_key: bytes | None = None):
        self.world = world
        self.autopilot = world.autopilot
        self.onboard = onboard
        self.telemetry = telemetry
        self.sysid = sysid
        self.failsafe_timeout = failsafe_timeout
        self.log = log
        self.links = [links.connect(url, sysid, AUTOPILOT, signing_key) for url in urls]
        self.packers = {component: mavlink.MAVLink(None, srcSystem=sysid, srcComponent=component)
                        for component in {AUTOPILOT, onboard.component if onboard else AUTOPILOT}}
        if signing_key is not None:
            for packer in self.packers.values():
                signing.sign_outgoing(packer, signing_key)
        self.missions = MissionServer(self.autopilot)
        self.stats: Counter[str] = Counter()
        self.gcs_seen: float | None = None  # wall time of the last GCS heartbeat
        self.stations: dict[int, float] = {}  # system id -> wall time of its last GCS heartbeat (at most 255)
        self._told: set[tuple[int, int]] = set()  # strangers told once that they are not obeyed
        self.in_failsafe = False

    def close(self) -> None:
        for link in self.links:
            link.close()

    # ---- sending -------------------------------------------------------------------------------
    def send(self, messages: list, now: float, component: int = AUTOPILOT) -> None:
        """Send as the autopilot, or as the onboard computer (its ``component``). Counted as sent only while a
        link is up: a vehicle whose only link is down sends nothing, and its summary should not say otherwise."""
        packer = self.packers[component]
        for message in messages:
            packet = pack(message, packer)
            for link in self.links:
                try:
                    link.write(packet)
                except OSError:
                    self.stats["send errors"] += 1
            if self.log is not None:
                self.log.write(packet, now)
        self.stats["sent" if any(link.up for link in self.links) else "unsent (no link up)"] += len(messages)

    # ---- receiving -----------------------------------------------------------------------------
    def poll(self, now: float) -> None:
        """Handle everything waiting on every link, then the timers (mission retries, failsafe)."""
        for link in self.links:
            for _ in range(links.MAX_DATAGRAMS):
                message = link.recv_msg()
                if message is None:
                    break
                self._route(message, link, now)
                self._receive(message, now)
        self.send(self.missions.poll(now), now)
        self._check_failsafe(now)

    def _route(self, message, source, now: float) -> None:
        """Pass on what is not for the autopilot alone to the other links, as ArduPilot routes: a companion's map
        reaches the ground stations, a ground station's command for the companion reaches it (a stranger's
        orders go nowhere)."""
        if len(self.links) < 2 or message.get_type() == "BAD_DATA" or message.get_srcSystem() == self.sysid and \
                message.get_srcComponent() == AUTOPILOT or self._stranger_orders(message, now):
            return
        if (getattr(message, "target_system", 0), getattr(message, "target_component", 0)) == (self.sysid, AUTOPILOT):
            return
        packet = message.get_msgbuf()
        for link in self.links:
            if link is not source:
                link.write(packet)
        self.stats["routed"] += 1

    def _receive(self, message, now: float) -> None:
        kind = message.get_type()
        if kind == "BAD_DATA":
            self.stats["bad packets"] += 1
            return
        if self.log is not None:
            self.log.write(message.get_msgbuf(), now)
        target = getattr(message, "target_system", 0)
        if target not in (0, self.sysid):
            self.stats["for other systems"] += 1
            return
        if self._stranger_orders(message, now):
            self.stats["refused strangers"] += 1
            self.send(self._refuse(message), now)
            return
        component = getattr(message, "target_component", 0)
        onboard = self.onboard
        if onboard is not None and component == onboard.component:
            self.stats["received"] += 1
            self.send(self._ask_onboard(message) or [], now, onboard.component)
            return
        if component not in (0, AUTOPILOT):
            self.stats["for other components"] += 1
            return
        self.stats["received"] += 1
        try:
            replies = self.handle(message, now)
        except Exception as error:  # noqa: BLE001 - one bad message must not take the vehicle down
            self.stats["messages refused"] += 1
            replies = self._text(f"Refused {kind}: {type(error).__name__}", mavlink.MAV_SEVERITY_WARNING)
        self.send(replies, now)

    def _stranger_orders(self, message, now: float) -> bool:
        """An order (a command, a mode, a target, a write) from neither a ground station nor the companion."""
        kind = message.get_type()
        return (kind in COMMANDS or kind in ORDERS) and not self._obeys(message, now)

    def _obeys(self, message, now: float) -> bool:
        """The sender is a ground station (its system's GCS heartbeat less than the failsafe timeout ago: the
        failsafe's own rule, ``_gcs_lost``) or the vehicle's own companion computer."""
        sender = message.get_srcSystem()
        if (sender, message.get_srcComponent()) == (self.sysid, COMPANION):
            return True
        return not self._gcs_lost(self.stations.get(sender), now)

    def _refuse(self, message) -> list:
        """COMMAND_ACK DENIED for a command (nothing for other orders), and once per sender a STATUSTEXT why."""
        sender = (message.get_srcSystem(), message.get_srcComponent())
        replies = []
        if message.get_type() in COMMANDS:
            replies.append(mavlink.MAVLink_command_ack_message(message.command, DENIED, 0, 0, *sender))
        if sender not in self._told:
            if len(self._told) >= MAX_TOLD:
                self._told.clear()
            self._told.add(sender)
            replies += self._text(f"Not obeying {sender[0]}/{sender[1]}: no GCS heartbeat from it",
                                  mavlink.MAV_SEVERITY_WARNING)
        return replies

    def _ask_onboard(self, message) -> list | None:
        try:
            return self.onboard.handle(message)
        except Exception as error:  # noqa: BLE001 - one bad message must not take the vehicle down
            self.stats["messages refused"] += 1
            return self._text(f"Refused {message.get_type()}: {type(error).__name__}", mavlink.MAV_SEVERITY_WARNING)

    def handle(self, message, now: float) -> list:
        """The replies to one message (already checked to be for us)."""
        kind = message.get_type()
        if kind == "HEARTBEAT":
            if message.type == GCS:
                self.stations[message.get_srcSystem()] = now
                self._gcs_heard(now)
            return []
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            return self._command(message, now)
        if kind == "SET_MODE":
            result = self._set_mode(message.custom_mode) if message.base_mode & 1 else UNSUPPORTED
            return [] if result == ACCEPTED else self._text(f"Mode change refused ({result})", 4)
        if kind in MISSION_MESSAGES:
            return self.missions.handle(message, now)
        if kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            if self.onboard is not None:  # one vehicle to the outside: its agent's mission parameters
                replies = self.onboard.handle(message) or []
                if replies or kind != "PARAM_REQUEST_READ":
                    return replies  # (a name the agent has not may still be the autopilot's own)
            return self._autopilot_param(message)
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target_local(message)
        elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
            self._position_target_global(message)
        return []

    # ---- commands ------------------------------------------------------------------------------
    def _command(self, message, now: float) -> list:
        replies: list = []
        try:
            result = self._run_command(message, replies)
        except (ValueError, OverflowError):
            result = DENIED
        ack = mavlink.MAVLink_command_ack_message(message.command, result, 0, 0, message.get_srcSystem(),
                                                  message.get_srcComponent())
        return [ack, *replies]

    def _override(self, message, what: str, result: int = ACCEPTED) -> int:
        """A station (not the onboard agent) steered the vehicle directly, if ``result`` says it was obeyed:
        a refused target steers nothing, so it takes nothing over."""
        if result == ACCEPTED and (message.get_srcSystem(), message.get_srcComponent()) != (self.sysid, COMPANION):
            self.autopilot.overridden(what)
        return result

    def _run_command(self, message, replies: list) -> int:
        m = _Command(message)
        cmd = m.command
        pilot = self.autopilot
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            return self._set_mode(int(m.param2)) if int(m.param1) & 1 else UNSUPPORTED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            force = int(round(m.param2)) == FORCE_DISARM
            if m.param1 not in (0.0, 1.0):  # as ArduPilot: 1 arms, 0 disarms, anything else (NaN) neither
                return DENIED
            return pilot.arm(force) if m.param1 == 1.0 else pilot.disarm(force)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            return pilot.takeoff(m.param7)
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            return self._set_mode_named("LAND") if self.world.kind is Kind.COPTER else UNSUPPORTED
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode_named("RTL")
        if cmd == mavlink.MAV_CMD_MISSION_START:
            return self._mission_start(int(m.param1))
        if cmd == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            return pilot.set_speed(m.param2)
        if cmd == mavlink.MAV_CMD_DO_REPOSITION:
            return self._override(message, "repositioned the vehicle", self._reposition(m))
        if cmd == mavlink.MAV_CMD_CONDITION_YAW:
            direction = -1.0 if m.param3 < 0 else 1.0
            turn = math.radians(m.param1) * (direction if m.param4 else 1.0)
            return self._override(message, "turned the vehicle", pilot.set_yaw(turn, relative=bool(m.param4)))
        if cmd == mavlink.MAV_CMD_DO_SET_SERVO:
            return pilot.set_servo(int(m.param1), int(m.param2))
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not (m.param2 in (-1.0, 0.0) or 0 < m.param2 < math.inf):  # -1 stops it, 0 is its default rate
                return DENIED
            interval = {-1.0: -1.0, 0.0: None}.get(m.param2, m.param2 / 1e6)
            return ACCEPTED if self.telemetry.set_interval(int(m.param1), interval) else UNSUPPORTED
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(int(m.param1), replies)
        if cmd == mavlink.MAV_CMD_GET_HOME_POSITION:
            return self._request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION, replies)
        if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return self._request_message(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, replies)
        return UNSUPPORTED

    def _set_mode(self, number: int) -> int:
        name = mode_name(self.world.kind, number)
        return UNSUPPORTED if name is None else self._set_mode_named(name)

    def _set_mode_named(self, name: str) -> int:
        return self.autopilot.set_mode(name, source="gcs", agent_on_board=self.onboard is not None)

    def _mission_start(self, first: int) -> int:
        """AUTO + MISSION_START: fly the mission a ground station uploaded; else start the onboard mission if it
        waits, resume it if paused; else run AUTO."""
        if self.autopilot.mode != "AUTO":
            return DENIED
        if self.onboard is not None and not self.missions.holds_station_mission and self.onboard.mission_start():
            return ACCEPTED
        return self.autopilot.start_mission(first)

    def _reposition(self, m: _Command) -> int:
        lat, lon = m.latitude, m.longitude
        if not on_earth(lat, lon):
            return DENIED
        if int(m.param2) & mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE and self.autopilot.mode != "GUIDED":
            self._set_mode_named("GUIDED")
        x, y = self.world.datum.to_local(lat, lon)
        altitude = None if math.isnan(m.param7) else m.param7
        return self.autopilot.goto(x, y, altitude)

    def _request_message(self, message_id: int, replies: list) -> int:
        builder = self.telemetry.builders().get(message_id)
        if builder is None:
            return UNSUPPORTED
        replies.append(builder(self.world.time))
        return ACCEPTED

    # ---- guided targets -------------------------------------------------------------------------
    def _position_target_local(self, m) -> None:
        if m.target_system != self.sysid:
            return
        pose, home = self.world.pose, self.world.home
        if m.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED:
            x, y, altitude = home[0] + m.y, home[1] + m.x, -m.z
        elif m.coordinate_frame == mavlink.MAV_FRAME_LOCAL_OFFSET_NED:
            x, y, altitude = pose.x + m.y, pose.y + m.x, pose.z - home[2] - m.z
        elif m.coordinate_frame == mavlink.MAV_FRAME_BODY_OFFSET_NED:
            forward, right = m.x, m.y
            sin, cos = math.sin(pose.yaw), math.cos(pose.yaw)
            x, y = pose.x + forward * sin + right * cos, pose.y + forward * cos - right * sin
            altitude = pose.z - home[2] - m.z
        else:
            self.stats["unsupported frames"] += 1
            return
        self._apply_target(m, x, y, altitude)

    def _position_target_global(self, m) -> None:
        if m.target_system != self.sysid:
            return
        lat, lon = m.lat_int * 1e-7, m.lon_int * 1e-7
        if m.coordinate_frame in (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT):
            altitude = m.alt
        elif m.coordinate_frame in (mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL):  # above sea level
            altitude = m.alt - (self.world.datum.alt + self.world.home[2])
        else:
            self.stats["unsupported frames"] += 1
            return
        if not on_earth(lat, lon):
            self.stats["non-finite targets"] += 1
            return
        x, y = self.world.datum.to_local(lat, lon)
        self._apply_target(m, x, y, altitude)

    def _apply_target(self, m, x: float, y: float, altitude: float) -> None:
        """A position target, else a velocity target, each with a heading if one is given; or a heading alone
        (what ArduPilot's Rover takes for turning in place). Non-finite numbers are no target."""
        mask, vn, ve, vd, yaw = m.type_mask, m.vx, m.vy, m.vz, m.yaw
        if not all(math.isfinite(v) for v in (x, y, altitude, vn, ve, vd, yaw)):
            self.stats["non-finite targets"] += 1
            return
        self._override(m, "set a guided target")
        if not mask & POSITION_IGNORED:
            self.autopilot.goto(x, y, altitude if not mask & mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE else None)
        elif not mask & VELOCITY_IGNORED:
            self.autopilot.set_velocity(ve, vn, -vd)
        if not mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE:
            self.autopilot.set_yaw(yaw % (2 * math.pi))

    # ---- the autopilot's own parameters (as a plain autopilot) ------------------------------------------
    def _autopilot_params(self) -> dict[str, float]:
        """What an onboard agent reads to plan as the autopilot flies, and a ground station shows of its battery
        failsafe (ArduPilot's names and units: it warns at BATTERY_LOW, lands a copter or holds a rover at
        BATTERY_CRITICAL, no voltage levels); only RTL_ALT (cm) can be set."""
        capacity = self.world.battery.capacity_mah
        return {"AVOID_ENABLE": 7.0 if self.autopilot.avoidance is not None else 0.0, "AVOID_MARGIN": AVOID_MARGIN,
                "WP_RADIUS": self.autopilot.wp_radius, "RTL_ALT": self.autopilot.rtl_altitude * 100.0,
                "BATT_CAPACITY": capacity, "BATT_LOW_VOLT": 0.0, "BATT_CRT_VOLT": 0.0,
                "BATT_LOW_MAH": BATTERY_LOW * capacity, "BATT_CRT_MAH": BATTERY_CRITICAL * capacity,
                "BATT_FS_LOW_ACT": 0.0, "BATT_FS_CRT_ACT": 1.0 if self.world.kind is Kind.COPTER else 2.0}

    def _autopilot_param(self, m) -> list:
        params = self._autopilot_params()
        names = list(params)
        kind = m.get_type()
        if kind == "PARAM_REQUEST_LIST":
            indices = range(len(names))
        else:
            wanted = m.param_id.rstrip("\0") if isinstance(m.param_id, str) else m.param_id.decode(errors="replace")
            index = getattr(m, "param_index", -1) if kind == "PARAM_REQUEST_READ" else -1
            found = index if 0 <= index < len(names) else (names.index(wanted) if wanted in names else None)
            if found is None:
                return []  # ArduPilot stays silent about unknown parameters
            if kind == "PARAM_SET" and names[found] == "RTL_ALT" and math.isfinite(m.param_value) \
                    and 0 <= m.param_value <= 30000:
                self.autopilot.rtl_altitude = m.param_value / 100.0
                params = self._autopilot_params()
            indices = [found]
        return [mavlink.MAVLink_param_value_message(names[i].encode(), float(params[names[i]]),
                                                    mavlink.MAV_PARAM_TYPE_REAL32, len(names), i) for i in indices]

    # ---- GCS failsafe ------------------------------------------------------------------------------
    def _gcs_heard(self, now: float) -> None:
        self.gcs_seen = now
        if self.in_failsafe:
            self.in_failsafe = False
            self.send(self._text("GCS failsafe cleared: ground station back"), now)

    def _gcs_lost(self, heard: float | None, now: float) -> bool:
        """Silent for the whole failsafe timeout (or never heard): as ArduPilot's Rover (``gcs_failsafe_check``:
        ``last_gcs_update_ms >= gcs_timeout_ms``), a silence that reaches FS_GCS_TIMEOUT is a lost ground
        station, both for the failsafe and for whom the vehicle obeys."""
        return heard is None or now - heard >= self.failsafe_timeout

    def _check_failsafe(self, now: float) -> None:
        if self.gcs_seen is None or self.in_failsafe or not self._gcs_lost(self.gcs_seen, now):
            return
        self.in_failsafe = True
        action = "RTL" if self.world.kind is Kind.COPTER else STOP_MODE["rover"]
        if self.autopilot.armed:
            self.autopilot.set_mode(action, source="failsafe")
        self.send(self._text(f"GCS failsafe: no ground station for {self.failsafe_timeout:g} s, {action}",
                             mavlink.MAV_SEVERITY_CRITICAL), now)

    def _text(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> list:
        return self.telemetry.text(text, severity)
