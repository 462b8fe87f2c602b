"""What a ground station hears from the simulated autopilot: ArduPilot's standard messages.

``Telemetry.tick(now)`` returns the messages due at ``now`` on a per-message
schedule (intervals can be changed, as MAV_CMD_SET_MESSAGE_INTERVAL asks).
The schedule's clock is the caller's: wall time for a live ``vehicle sim``,
simulated time for the log of a headless experiment; the messages are the
same, and their ``time_boot_ms`` is always the simulated time since boot.
Conventions: LOCAL_POSITION_NED is metres from home (north, east, down);
DISTANCE_SENSOR carries one reading (``vehicle.protocol.rangefinder``). An
onboard agent's own messages (its map, its state) are its own: component 191.

Positions, attitude, VFR_HUD and DISTANCE_SENSOR are encoded by functions on
arrays (``poses``, ``huds``, ``rangefinder.distance_sensors``): a live vehicle
asks them for one row, an experiment's log (``vehicle.lab.log``) for thousands
at once, so both send the very same bytes.
"""

from __future__ import annotations

import math

import numpy as np

from vehicle import __version__
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import from_wire, mavlink
from vehicle.protocol.modes import mode_number
from vehicle.protocol.rangefinder import Reading, distance_sensor
from vehicle.protocol.statustext import statustexts
from vehicle.protocol.traffic import adsb_report
from vehicle.sim.simulation import Simulation

# SYS_STATUS sensor bits we claim present, enabled and healthy (MAVProxy warns of a fence breach
# unless the geofence bits are set)
SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
           | mavlink.MAV_SYS_STATUS_SENSOR_RC_RECEIVER | mavlink.MAV_SYS_STATUS_GEOFENCE
           | mavlink.MAV_SYS_STATUS_AHRS | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
           | mavlink.MAV_SYS_STATUS_SENSOR_PROXIMITY | mavlink.MAV_SYS_STATUS_PREARM_CHECK)

DEFAULT_INTERVALS = {  # seconds
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.05,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.05,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 0.05,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 0.25,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 5.0,
}
VERSION = tuple(int(p) for p in __version__.split(".")[:3])
# payloads in wire order (pymavlink's names; the struct formats are checked where the log frames them)
GLOBAL_POSITION_WIRE = np.dtype([("time_boot_ms", "<u4"), ("lat", "<i4"), ("lon", "<i4"), ("alt", "<i4"),
                                 ("relative_alt", "<i4"), ("vx", "<i2"), ("vy", "<i2"), ("vz", "<i2"),
                                 ("hdg", "<u2")])
LOCAL_POSITION_WIRE = np.dtype([("time_boot_ms", "<u4")] + [(name, "<f4") for name in
                                                            ("x", "y", "z", "vx", "vy", "vz")])
ATTITUDE_WIRE = np.dtype([("time_boot_ms", "<u4")] + [(name, "<f4") for name in
                                                      ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed")])
VFR_HUD_WIRE = np.dtype([("airspeed", "<f4"), ("groundspeed", "<f4"), ("alt", "<f4"), ("climb", "<f4"),
                         ("heading", "<i2"), ("throttle", "<u2")])


def poses(datum: Datum, home, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE payloads of poses, one a row: time (s since boot),
    x, y, z (scene m), yaw (compass), pitch, roll (rad), vx, vy, vz (m/s east, north, up), yaw rate. Heights
    are above the start's ground (``home``'s z); integers are truncated as ``int`` does, degrees E7 rounded."""
    now, x, y, z, yaw, pitch, roll, vx, vy, vz, yaw_rate = rows.T
    ms = (now * 1000).astype(np.int64) & 0xFFFFFFFF
    lat, lon = datum.to_global(x, y)
    height = z - home[2]
    position = np.empty(len(rows), GLOBAL_POSITION_WIRE)
    position["time_boot_ms"] = ms
    position["lat"] = np.rint(lat * 1e7)  # round(), half to even
    position["lon"] = np.rint(lon * 1e7)
    position["alt"] = ((datum.alt + home[2]) + height) * 1000
    position["relative_alt"] = height * 1000
    position["vx"], position["vy"], position["vz"] = vy * 100, vx * 100, -vz * 100  # north, east, down
    position["hdg"] = np.mod(np.trunc(np.degrees(yaw) * 100).astype(np.int64), 36000)
    local = np.empty(len(rows), LOCAL_POSITION_WIRE)
    attitude = np.empty(len(rows), ATTITUDE_WIRE)
    local["time_boot_ms"] = attitude["time_boot_ms"] = ms
    for name, value in zip(LOCAL_POSITION_WIRE.names[1:], (y - home[1], x - home[0], -height, vy, vx, -vz),
                           strict=True):
        local[name] = value
    wrapped = np.where(yaw <= math.pi, yaw, yaw - 2 * math.pi)
    for name, value in zip(ATTITUDE_WIRE.names[1:], (roll, pitch, wrapped, 0.0, 0.0, yaw_rate), strict=True):
        attitude[name] = value
    return position, local, attitude


def huds(datum: Datum, home, rows: np.ndarray) -> np.ndarray:
    """VFR_HUD payloads, one a row: ground speed (m/s), yaw (compass, rad), z (scene m), vz (m/s up), flying
    (1 or 0: the throttle shows 50 % while it flies)."""
    speed, yaw, z, vz, flying = rows.T
    hud = np.empty(len(rows), VFR_HUD_WIRE)
    hud["airspeed"] = hud["groundspeed"] = speed
    hud["alt"] = (datum.alt + home[2]) + (z - home[2])
    hud["climb"] = vz
    hud["heading"] = np.mod(np.trunc(np.degrees(yaw)).astype(np.int64), 360)
    hud["throttle"] = np.where(flying > 0, 50, 0)
    return hud


class Telemetry:
    def __init__(self, world: Simulation, start: float = 0.0, sysid: int = 1):
        self.world = world
        self.sysid = sysid
        self.boot = start
        self.intervals: dict[int, float] = dict(DEFAULT_INTERVALS)
        self._due: dict[int, float] = dict.fromkeys(self.intervals, start)
        self._texts = 0

    # ---- schedule ------------------------------------------------------------------------------
    def set_interval(self, message_id: int, interval: float | None) -> bool:
        """Set how often a message is sent (seconds; None restores the default, <= 0 stops it)."""
        if message_id not in self.builders():
            return False
        if interval is None:
            interval = DEFAULT_INTERVALS.get(message_id, 1.0)
        self.intervals[message_id] = interval
        self._due[message_id] = self.boot
        return True

    def tick(self, now: float) -> list:
        """Messages due at ``now``: the periodic ones and the autopilot's events."""
        out = []
        builders = self.builders()
        for message_id, interval in self.intervals.items():
            if interval > 0 and now >= self._due.get(message_id, now):
                self._due[message_id] = max(self._due.get(message_id, now) + interval, now)
                out.append(builders[message_id](now))
        out += self.events(now)
        return out

    def next_due(self) -> float:
        """When the next periodic message falls due (inf if none is sent): until then, and while the autopilot
        reports no events, ``tick`` has nothing to send."""
        return min((self._due[i] for i, interval in self.intervals.items() if interval > 0), default=math.inf)

    def builders(self) -> dict:
        return {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self.battery_status,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self.vfr_hud,
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
        }

    def _ms(self, now: float) -> int:
        """time_boot_ms: the vehicle's simulated time since boot (as ArduPilot's SITL reports it)."""
        return int(self.world.time * 1000) & 0xFFFFFFFF

    # ---- messages ------------------------------------------------------------------------------
    def heartbeat(self, now: float):
        pilot = self.world.autopilot
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if pilot.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if pilot.mode in ("GUIDED", "AUTO", "RTL", "LAND", "LOITER", "BRAKE", "HOLD"):
            base |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        status = mavlink.MAV_STATE_ACTIVE if pilot.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(self.world.kind.mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                 base, mode_number(self.world.kind, pilot.mode), status, 3)

    def sys_status(self, now: float):
        battery = self.world.battery
        return mavlink.MAVLink_sys_status_message(
            SENSORS, SENSORS, SENSORS, 250, int(battery.voltage * 1000), int(battery.current * 100),
            int(battery.remaining * 100), 0, 0, 0, 0, 0, 0)

    def battery_status(self, now: float):
        battery = self.world.battery
        cell = int(battery.voltage * 1000 / 4)
        return mavlink.MAVLink_battery_status_message(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 32767, [cell] * 4 + [65535] * 6,
            int(battery.current * 100), int(battery.consumed_mah), -1, int(battery.remaining * 100))

    def _poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        body, pose = self.world.body, self.world.pose
        row = (self.world.time, pose.x, pose.y, pose.z, pose.yaw, pose.pitch, pose.roll, body.vx, body.vy, body.vz,
               body.yaw_rate)
        return poses(self.world.datum, self.world.home, np.array([row], dtype=np.float64))

    def global_position(self, now: float):
        return from_wire(mavlink.MAVLink_global_position_int_message, self._poses()[0][0])

    def local_position(self, now: float):
        return from_wire(mavlink.MAVLink_local_position_ned_message, self._poses()[1][0])

    def attitude(self, now: float):
        return from_wire(mavlink.MAVLink_attitude_message, self._poses()[2][0])

    def vfr_hud(self, now: float):
        body = self.world.body
        row = (body.speed, self.world.pose.yaw, self.world.pose.z, body.vz, self.world.autopilot.flying)
        return from_wire(mavlink.MAVLink_vfr_hud_message,
                         huds(self.world.datum, self.world.home, np.array([row], dtype=np.float64))[0])

    def mission_current(self, now: float):
        pilot = self.world.autopilot
        total = len(pilot.mission)
        state = mavlink.MISSION_STATE_NO_MISSION if total <= 1 else (
            mavlink.MISSION_STATE_ACTIVE if pilot.mission_running else
            mavlink.MISSION_STATE_COMPLETE if pilot.current >= total else mavlink.MISSION_STATE_PAUSED)
        return mavlink.MAVLink_mission_current_message(min(pilot.current, max(total - 1, 0)), total, state,
                                                       1 if pilot.mode == "AUTO" else 0)

    def home_position(self, now: float):
        home = self.world.home
        lat, lon = self.world.datum.to_global(home[0], home[1])
        return mavlink.MAVLink_home_position_message(
            int(round(lat * 1e7)), int(round(lon * 1e7)), int((self.world.datum.alt + home[2]) * 1000),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def extended_sys_state(self, now: float):
        """On the ground, taking off, in the air or landing (a companion asks for it, as of ArduPilot)."""
        pilot = self.world.autopilot
        if self.world.kind != "copter":
            state = mavlink.MAV_LANDED_STATE_ON_GROUND
        elif pilot.taking_off:
            state = mavlink.MAV_LANDED_STATE_TAKEOFF
        elif not pilot.flying:
            state = mavlink.MAV_LANDED_STATE_ON_GROUND
        else:
            state = mavlink.MAV_LANDED_STATE_LANDING if pilot.mode == "LAND" else mavlink.MAV_LANDED_STATE_IN_AIR
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, state)

    def autopilot_version(self, now: float):
        capabilities = (mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                        | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                        | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                        | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT)
        major, minor, patch = (VERSION + (0, 0, 0))[:3]
        software = (major << 24) | (minor << 16) | (patch << 8) | 255  # 255: official release
        return mavlink.MAVLink_autopilot_version_message(capabilities, software, 0, 0, 0, [0] * 8, [0] * 8,
                                                         [0] * 8, 0, 0, self.sysid)

    def events(self, now: float) -> list:
        """STATUSTEXT, MISSION_ITEM_REACHED and MISSION_CURRENT for what the autopilot reported."""
        out = []
        events = self.world.autopilot.events
        while events:
            event = events.popleft()
            if event.kind == "text":
                out += self.text(event.text, event.severity)
            elif event.kind == "reached":
                out.append(mavlink.MAVLink_mission_item_reached_message(event.seq))
            elif event.kind == "current":
                out.append(self.mission_current(now))
        return out

    def text(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> list:
        """STATUSTEXT of a text (chunks when it is long)."""
        self._texts += 1
        return statustexts(text, severity, self._texts)

    def distance_sensor(self, reading: Reading, now: float):
        return distance_sensor(reading, self._ms(now))


def adsb_vehicle(other: Simulation, sysid: int):
    """ADSB_VEHICLE for a team-mate, as an ADS-B receiver on an ArduPilot vehicle forwards what it hears (its
    altitude the datum's plus scene z)."""
    body, pose = other.body, other.pose
    lat, lon = other.datum.to_global(pose.x, pose.y)
    return adsb_report(sysid, float(lat), float(lon), other.datum.alt + pose.z, body.vx, body.vy, body.vz,
                       math.degrees(pose.yaw), simulated=True)
