"""Simulated distance sensors (ultrasonic sonar) and the servo that can sweep one.

The model follows the thesis and the HC-SR04 datasheet: readings between a
minimum and a maximum range, a beam that is a cone rather than a single ray
(sampled with a centre ray and rings around it, the nearest echo wins), no
echo from surfaces hit beyond a critical angle of incidence, and optional
seeded Gaussian noise. Sensors are mounted with a yaw (and pitch) relative to
the body, optionally on a servo driven by PWM.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from vehicle.sim.physics import Pose
from vehicle.world.raycast import RayCaster


@dataclass
class Servo:
    """A hobby servo: PWM pulse width (microseconds) maps linearly onto an angle (degrees)."""

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


@dataclass
class Sonar:
    """An ultrasonic range finder. Angles in degrees; yaw clockwise from the nose, pitch up."""

    name: str = "front"
    mount_yaw: float = 0.0
    mount_pitch: float = 0.0
    min_range: float = 0.02
    max_range: float = 40.0
    beam_angle: float = 7.5  # half-angle of the cone (HC-SR04: a 15 degree measuring angle)
    rings: int = 3  # rings of rays around the centre ray (6 more rays on each ring further out)
    critical_angle: float = 60.0  # no echo from surfaces hit more obliquely than this
    noise: float = 0.0  # standard deviation in metres
    servo: Servo | None = None
    _local_rays: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        self._local_rays = cone_rays(math.radians(self.beam_angle), self.rings)
        self._cos_critical = math.cos(math.radians(self.critical_angle))
        self._mount_key: float | None = None
        self._mount = np.eye(3)

    @property
    def yaw_offset(self) -> float:
        """Current yaw of the sensor relative to the nose, in degrees (mount plus servo)."""
        return self.mount_yaw + (self.servo.angle() if self.servo else 0.0)

    def axis(self, pose: Pose) -> np.ndarray:
        """Unit vector of the beam's centre in the scene frame."""
        return self._to_world(pose) @ np.array([1.0, 0.0, 0.0])

    def _to_world(self, pose: Pose, body: np.ndarray | None = None) -> np.ndarray:
        """Rotation from the sensor frame (x forward, y left, z up) to the scene frame."""
        return (body_to_world(pose) if body is None else body) @ self._mount_rotation()

    def _mount_rotation(self) -> np.ndarray:
        yaw = self.yaw_offset
        if yaw != self._mount_key:  # only a servo moves it; cached because every step asks
            self._mount = rotation_zy(-math.radians(yaw), math.radians(self.mount_pitch))
            self._mount_key = yaw
        return self._mount


@dataclass
class Reading:
    """One sonar measurement: where the beam started, where it pointed, what it measured."""

    time: float
    sensor: int
    origin: np.ndarray  # (3,) scene metres
    direction: np.ndarray  # (3,) unit vector of the beam's centre
    distance: float | None  # metres, None when nothing echoed within range
    max_range: float
    yaw_offset: float  # degrees, sensor relative to the nose (for DISTANCE_SENSOR orientation)
    beam_angle: float = 0.0  # degrees, half-angle of the cone

    @property
    def hit(self) -> np.ndarray | None:
        return None if self.distance is None else self.origin + self.direction * self.distance


class SonarArray:
    """Reads every sensor on the vehicle with one batched ray cast."""

    def __init__(self, sensors: list[Sonar], caster: RayCaster, seed: int = 0):
        self.sensors = sensors
        self.caster = caster
        self.rng = np.random.default_rng(seed)
        self._mount_key: tuple[float, ...] | None = None
        self._first_ray = np.cumsum([0] + [len(s._local_rays) for s in sensors])
        self._cos_critical = np.array([s._cos_critical for s in sensors])
        self._min_range = np.array([s.min_range for s in sensors])
        self._servos = any(s.servo is not None for s in sensors)

    def _body_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """All sensors' rays and beam axes in the body frame; recomputed only when a servo moved."""
        if self._mount_key is not None and not self._servos:
            return self._rays, self._axes
        key = tuple(s.yaw_offset for s in self.sensors)
        if key != self._mount_key:
            mounts = [s._mount_rotation() for s in self.sensors]
            self._rays = np.concatenate([s._local_rays @ m.T for s, m in zip(self.sensors, mounts, strict=True)])
            self._axes = np.array([m[:, 0] for m in mounts])
            self._mount_key = key
        return self._rays, self._axes

    def read(self, pose: Pose, time: float) -> list[Reading]:
        if not self.sensors:
            return []
        origin = np.array((pose.x, pose.y, pose.z))
        body = body_to_world(pose)
        rays, axes = self._body_rays()
        directions = rays @ body.T
        distance, faces = self.caster.cast_from(origin, directions)
        nearest = _nearest_echoes(distance, faces, directions, self.caster.face_normals, self._first_ray,
                                  self._cos_critical, self._min_range).tolist()
        world_axes = axes @ body.T
        readings = []
        for index, sensor in enumerate(self.sensors):
            value = nearest[index] if nearest[index] <= sensor.max_range else None
            if value is not None and sensor.noise > 0:
                noisy = value + self.rng.normal(0.0, sensor.noise)
                value = float(min(sensor.max_range, max(sensor.min_range, noisy)))
            readings.append(Reading(time, index, origin, world_axes[index], value, sensor.max_range,
                                    sensor.yaw_offset, sensor.beam_angle))
        return readings


@numba.njit(cache=True)
def _nearest_echoes(distance, faces, directions, normals, first_ray, cos_critical, min_range):
    """Per sensor (its rays are first_ray[i] up to first_ray[i + 1]), the nearest distance at which a ray
    hit a face it meets no more obliquely than the critical angle, at min_range or further; inf if none.

    A loop over a hundred rays: in numpy the same takes a dozen calls on small arrays,
    several times slower at the ten readings a second every simulated vehicle takes.
    """
    nearest = np.full(len(cos_critical), np.inf)
    for sensor in range(len(cos_critical)):
        for ray in range(first_ray[sensor], first_ray[sensor + 1]):
            face, reach = faces[ray], distance[ray]
            if face < 0 or reach < min_range[sensor] or reach >= nearest[sensor]:
                continue
            cos = abs(normals[face, 0] * directions[ray, 0] + normals[face, 1] * directions[ray, 1]
                      + normals[face, 2] * directions[ray, 2])
            if cos >= cos_critical[sensor]:
                nearest[sensor] = reach
    return nearest


SENSOR_SUITES = {
    "single": "one sonar looking forward (the thesis's vehicle)",
    "triple": "three sonars: forward and 45 degrees to each side (sees walls alongside the path)",
    "servo": "one sonar on a servo that sweeps it 90 degrees either side (the thesis's servo option)",
}


def sensor_suite(name: str) -> list[Sonar]:
    """The sonars of a named sensor suite (see SENSOR_SUITES)."""
    if name == "single":
        return [Sonar("front")]
    if name == "triple":
        return [Sonar("front"), Sonar("left", mount_yaw=-45.0), Sonar("right", mount_yaw=45.0)]
    if name == "servo":
        return [Sonar("sweep", servo=Servo())]
    raise ValueError(f"unknown sensor suite {name!r}; suites: {', '.join(SENSOR_SUITES)}")


def cone_rays(half_angle: float, rings: int, per_ring: int = 6) -> np.ndarray:
    """Unit rays in the sensor frame (x forward): the centre plus ``rings`` rings spread over the cone,
    ring k with k * ``per_ring`` rays, so that rays are about as far apart around a ring as between rings."""
    rays = [(1.0, 0.0, 0.0)]
    for ring in range(1, rings + 1):
        tilt = half_angle * ring / rings
        count = per_ring * ring
        for k in range(count):
            around = 2 * math.pi * (k + 0.5 * (ring % 2)) / count
            rays.append((math.cos(tilt), math.sin(tilt) * math.cos(around), math.sin(tilt) * math.sin(around)))
    return np.array(rays)


def rotation_zy(yaw_left: float, pitch_up: float) -> np.ndarray:
    """Rotation by ``pitch_up`` about -y (nose up) then ``yaw_left`` about z, in a frame with x forward, z up."""
    cy, sy = math.cos(yaw_left), math.sin(yaw_left)
    cp, sp = math.cos(pitch_up), math.sin(pitch_up)
    yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    pitch = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
    return yaw @ pitch


def body_to_world(pose: Pose) -> np.ndarray:
    """Rotation from the body frame (x forward, y left, z up) to the scene frame (x east, y north, z up).

    Applies roll, then pitch, then yaw (the aerospace order the thesis uses), with
    MAVLink's signs: yaw a compass heading, pitch nose up, roll right side down.
    """
    heading = math.pi / 2 - pose.yaw  # counter-clockwise angle from east: forward maps to (sin yaw, cos yaw)
    ch, sh = math.cos(heading), math.sin(heading)
    cp, sp = math.cos(pose.pitch), math.sin(pose.pitch)
    cr, sr = math.cos(pose.roll), math.sin(pose.roll)
    # Rz(heading) @ R(pitch nose up) @ Rx(roll, left side up), multiplied out
    return np.array([
        [ch * cp, -ch * sp * sr - sh * cr, sh * sr - ch * sp * cr],
        [sh * cp, ch * cr - sh * sp * sr, -sh * sp * cr - ch * sr],
        [sp, cp * sr, cp * cr],
    ])
