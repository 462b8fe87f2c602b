"""Distance readings and how they travel: DISTANCE_SENSOR both ways, OBSTACLE_DISTANCE in, the sonar's servo.

A reading is where a beam started, where it pointed and what it measured, in
the scene frame. On the wire a reading is one DISTANCE_SENSOR: distances in
centimetres, ``max_distance + 1`` meaning no echo, the mount as a
MAV_SENSOR_ORIENTATION (a servo-swept sensor: ROTATION_CUSTOM with the mount
in ``quaternion``, body frame forward-right-down). A receiver turns it back
into a reading with the pose it knows; both ends are here so they agree.
Whatever a peer sends, decoding yields a finite reading or none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vehicle.protocol.frames import Pose, beam_axis
from vehicle.protocol.mav import from_wire, mavlink

CUSTOM = mavlink.MAV_SENSOR_ROTATION_CUSTOM
UNKNOWN_DISTANCE = 65535  # OBSTACLE_DISTANCE: no sensor in this sector


@dataclass(slots=True)
class Reading:
    """One range measurement in the scene frame (slots: a simulated minute makes thousands)."""

    time: float
    sensor: int
    origin: np.ndarray  # (3,) scene metres
    direction: np.ndarray  # (3,) unit vector of the beam's centre
    distance: float | None  # metres, None when nothing echoed within range
    max_range: float
    yaw_offset: float  # degrees clockwise of the nose (mount plus servo)
    beam_angle: float = 0.0  # degrees, half-angle of the cone
    min_range: float = 0.0
    pitch: float = 0.0  # degrees up of the mount
    vehicle: int | None = None  # the system id of the team-mate the echo came from, None for the scene

    @property
    def hit(self) -> np.ndarray | None:
        return None if self.distance is None else self.origin + self.direction * self.distance


@dataclass
class Servo:
    """A hobby servo turning a sensor: PWM pulse width (microseconds) maps linearly onto an angle (degrees)."""

    pwm_min: int = 1000
    pwm_max: int = 2000
    angle_min: float = -90.0
    angle_max: float = 90.0
    pwm: int = 1500
    channel: int = 9  # autopilot output that drives it (MAV_CMD_DO_SET_SERVO)

    def angle(self) -> float:
        span = (self.pwm - self.pwm_min) / (self.pwm_max - self.pwm_min)
        return self.angle_min + span * (self.angle_max - self.angle_min)

    def pwm_for(self, angle: float) -> int:
        angle = min(self.angle_max, max(self.angle_min, angle))
        span = (angle - self.angle_min) / (self.angle_max - self.angle_min)
        return round(self.pwm_min + span * (self.pwm_max - self.pwm_min))

    def set_angle(self, angle: float) -> None:
        self.pwm = self.pwm_for(angle)


# ---- sending -----------------------------------------------------------------------------------------
def orientation_of(yaw_offset: float, pitch: float) -> tuple[int, list[float]]:
    """MAV_SENSOR_ORIENTATION for a mount yaw (degrees clockwise) and pitch (up), or CUSTOM with a quaternion."""
    if pitch == 0 and yaw_offset % 45 == 0:
        return int(yaw_offset % 360) // 45, [0.0, 0.0, 0.0, 0.0]  # NONE, YAW_45 ... YAW_315
    half_yaw, half_pitch = math.radians(yaw_offset) / 2, math.radians(pitch) / 2
    # body frame is forward-right-down: yaw about z (down) then pitch about y (right)
    cy, sy, cp, sp = math.cos(half_yaw), math.sin(half_yaw), math.cos(half_pitch), math.sin(half_pitch)
    return CUSTOM, [cy * cp, -sy * sp, cy * sp, sy * cp]


# DISTANCE_SENSOR's payload in wire order (pymavlink's names; the struct format is checked where it is framed)
DISTANCE_SENSOR_WIRE = np.dtype([("time_boot_ms", "<u4"), ("min_distance", "<u2"), ("max_distance", "<u2"),
                                 ("current_distance", "<u2"), ("type", "u1"), ("id", "u1"), ("orientation", "u1"),
                                 ("covariance", "u1"), ("horizontal_fov", "<f4"), ("vertical_fov", "<f4"),
                                 ("quaternion", "<f4", 4), ("signal_quality", "u1")])


def distance_sensor(reading: Reading, time_boot_ms: int):
    """The DISTANCE_SENSOR message of a reading (the one encoder's, as a log makes thousands at once)."""
    row = distance_sensors(np.array([[time_boot_ms, reading.sensor,
                                      math.nan if reading.distance is None else reading.distance,
                                      reading.yaw_offset, reading.pitch, reading.max_range, reading.min_range,
                                      reading.beam_angle]], dtype=np.float64))[0]
    return from_wire(mavlink.MAVLink_distance_sensor_message, row)


def distance_sensors(readings: np.ndarray) -> np.ndarray:
    """DISTANCE_SENSOR payloads (``DISTANCE_SENSOR_WIRE``) of readings, one a row: time_boot_ms, sensor, distance
    (NaN: no echo, sent as ``max_distance + 1``), mount yaw and pitch (degrees), max and min range (m) and
    beam half-angle (degrees). Centimetres are truncated, as ``int`` does."""
    ms, sensor, distance, yaw_offset, pitch, max_range, min_range, beam_angle = readings.T
    out = np.zeros(len(readings), DISTANCE_SENSOR_WIRE)
    top = np.minimum(np.trunc(max_range * 100), 65534)
    bottom = np.trunc(min_range * 100)
    value = np.where(np.isnan(distance), top + 1, np.maximum(bottom, np.trunc(np.nan_to_num(distance) * 100)))
    out["time_boot_ms"] = ms.astype(np.int64) & 0xFFFFFFFF
    out["min_distance"], out["max_distance"], out["current_distance"] = bottom, top, np.minimum(value, 65535)
    out["type"] = mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND
    out["id"] = sensor.astype(np.int64) & 0xFF
    mounts, which = np.unique(np.column_stack([yaw_offset, pitch]), axis=0, return_inverse=True)
    orientations = [orientation_of(float(yaw), float(up)) for yaw, up in mounts]
    which = which.reshape(-1)
    out["orientation"] = np.array([o for o, _ in orientations], dtype=np.int64)[which]
    out["quaternion"] = np.array([q for _, q in orientations], dtype=np.float64).reshape(-1, 4)[which]
    out["horizontal_fov"] = out["vertical_fov"] = np.radians(2 * beam_angle)
    return out


# ---- receiving ---------------------------------------------------------------------------------------
def mount_of(orientation: int, quaternion) -> tuple[float, float] | None:
    """(yaw degrees clockwise of the nose, pitch degrees up) of a MAV_SENSOR_ORIENTATION; None for mounts a
    horizontal map cannot use (rolled, upside down) or a quaternion that is no rotation."""
    if 0 <= orientation < 8:  # NONE, YAW_45 ... YAW_315: clockwise from the nose
        return 45.0 * orientation, 0.0
    if orientation == mavlink.MAV_SENSOR_ROTATION_PITCH_270:
        return 0.0, -90.0
    if orientation == mavlink.MAV_SENSOR_ROTATION_PITCH_90:
        return 0.0, 90.0
    if orientation != CUSTOM:
        return None
    try:
        w, qx, qy, qz = (float(q) for q in quaternion)
    except (TypeError, ValueError):
        return None
    norm = w * w + qx * qx + qy * qy + qz * qz
    if not math.isfinite(norm) or abs(norm - 1.0) > 0.1:
        return None
    fx = 1 - 2 * (qy * qy + qz * qz)  # the sensor's x axis in the body frame (forward-right-down)
    fy = 2 * (qx * qy + w * qz)
    fz = 2 * (qx * qz - w * qy)
    return math.degrees(math.atan2(fy, fx)), math.degrees(math.atan2(-fz, math.hypot(fx, fy)))


def reading_from(message, pose: Pose, time: float) -> Reading | None:
    """The reading a DISTANCE_SENSOR describes, taken from a body at ``pose``; None if it is unusable."""
    mount = mount_of(message.orientation, getattr(message, "quaternion", None))
    if mount is None or message.max_distance <= 0:
        return None
    max_range = message.max_distance / 100.0
    current = message.current_distance
    distance = None if current > message.max_distance or current == 0 or current < message.min_distance \
        else current / 100.0
    fov = getattr(message, "horizontal_fov", 0.0)
    beam = math.degrees(fov) / 2 if math.isfinite(fov) and 0 < fov < math.pi else 0.0
    yaw_offset, pitch = mount
    return Reading(time, message.id, np.array(pose.xyz()), beam_axis(pose, yaw_offset, pitch), distance, max_range,
                   yaw_offset, beam, message.min_distance / 100.0, pitch)


def readings_from_obstacles(message, pose: Pose, time: float) -> list[Reading]:
    """The readings of an OBSTACLE_DISTANCE (one per sector with a sensor), from a body at ``pose``."""
    increment = message.increment_f if getattr(message, "increment_f", 0.0) > 0 else float(message.increment)
    offset = float(getattr(message, "angle_offset", 0.0))
    if not (math.isfinite(increment) and math.isfinite(offset)) or increment <= 0 or message.max_distance <= 0:
        return []
    earth = getattr(message, "frame", mavlink.MAV_FRAME_BODY_FRD) in (
        mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_LOCAL_NED)  # angles from north, not from the nose
    max_range = message.max_distance / 100.0
    readings = []
    for sector, value in enumerate(message.distances):
        if value == UNKNOWN_DISTANCE or sector * increment >= 360:
            continue
        yaw_offset = offset + sector * increment - (math.degrees(pose.yaw) if earth else 0.0)
        distance = None if value > message.max_distance or value < message.min_distance else value / 100.0
        readings.append(Reading(time, 100 + sector, np.array(pose.xyz()), beam_axis(pose, yaw_offset), distance,
                                max_range, yaw_offset % 360, increment / 2, message.min_distance / 100.0))
    return readings
