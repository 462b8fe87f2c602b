"""Distance sensors (ultrasonic sonar) cast into the scene: the simulator's, and an onboard agent's that flies
a real autopilot in a simulated scene (``vehicle agent --sensors scene``).

The model follows the thesis and the HC-SR04 datasheet: readings between a
minimum and a maximum range, a beam that is a cone rather than a single ray
(sampled with a centre ray and rings around it, the nearest echo wins), no
echo from surfaces hit beyond a critical angle of incidence, and optional
seeded Gaussian noise. Sensors are mounted with a yaw (and pitch) relative to
the body, optionally on a servo driven by PWM.

In a team (``vehicle.sim.team``) the other vehicles are bodies too: spheres the
cone echoes off as off a wall, met analytically (ray-sphere), the nearest echo
of mesh and bodies winning. A compiled pre-check per read keeps only the bodies
within a sensor's range and inside its cone (widened by the angle the sphere
spans); a read with none left costs what a lone vehicle's does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from vehicle.protocol.frames import Pose, body_to_world, mount_rotation
from vehicle.protocol.rangefinder import Reading, Servo
from vehicle.world.raycast import RayCaster


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
            self._mount = mount_rotation(yaw, self.mount_pitch)
            self._mount_key = yaw
        return self._mount


class Bodies(NamedTuple):
    """Other vehicles' bodies as the sonar meets them: spheres."""

    ids: np.ndarray  # (k,) system ids
    centres: np.ndarray  # (k, 3) scene metres
    radii: np.ndarray  # (k,) metres


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
        self._yaw_offsets = [s.yaw_offset for s in sensors]  # fixed unless a servo turns one
        self._max_range = max((s.max_range for s in sensors), default=0.0)
        self._cone_sin = np.array([math.sin(math.radians(s.beam_angle)) for s in sensors])
        self._cone_cos = np.array([math.cos(math.radians(s.beam_angle)) for s in sensors])
        self._max_ranges = np.array([s.max_range for s in sensors], dtype=np.float64)

    @property
    def reach(self) -> float:
        """The furthest any of the sensors can hear an echo, metres."""
        return self._max_range

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

    def read(self, pose: Pose, time: float, bodies: Bodies | None = None) -> list[Reading]:
        """Every sensor's reading from ``pose``; ``bodies``: the other vehicles around (none alone)."""
        if not self.sensors:
            return []
        xyz = (pose.x, pose.y, pose.z)
        origin = np.array(xyz)
        to_world = body_to_world(pose).T
        rays, axes = self._body_rays()
        directions = rays @ to_world
        distance, faces = self.caster.cast_from(xyz, directions)
        nearest = _nearest_echoes(distance, faces, directions, self.caster.face_normals, self._first_ray,
                                  self._cos_critical, self._min_range).tolist()
        hit_by = [None] * len(self.sensors)
        world_axes = axes @ to_world
        if bodies is not None and len(bodies.ids):
            near = self._in_cones(xyz, world_axes, bodies)
            if near:
                self._echo_off_bodies(origin, directions, bodies, near, nearest, hit_by)
        readings = []
        for index, sensor in enumerate(self.sensors):
            value = nearest[index]
            if value > sensor.max_range:
                value = None
            elif sensor.noise > 0:
                noisy = value + self.rng.normal(0.0, sensor.noise)
                value = float(min(sensor.max_range, max(sensor.min_range, noisy)))
            yaw_offset = sensor.yaw_offset if self._servos else self._yaw_offsets[index]
            readings.append(Reading(time, index, origin, world_axes[index], value, sensor.max_range,
                                    yaw_offset, sensor.beam_angle, sensor.min_range, sensor.mount_pitch,
                                    None if value is None else hit_by[index]))
        return readings

    def _in_cones(self, xyz: tuple[float, float, float], axes, bodies: Bodies) -> list[int]:
        """The bodies some sensor's cone may meet: within its range and inside its angle, widened by the angle
        the sphere itself spans (``axes``: each sensor's beam axis in the scene frame)."""
        return _bodies_in_cones(np.asarray(xyz, dtype=np.float64), np.asarray(axes, dtype=np.float64),
                                bodies.centres, bodies.radii, self._cone_sin, self._cone_cos,
                                self._max_ranges).tolist()

    def _echo_off_bodies(self, origin: np.ndarray, directions: np.ndarray, bodies: Bodies, near: list[int],
                         nearest: list[float], hit_by: list[int | None]) -> None:
        """Where a body echoes nearer than the scene, its distance replaces the scene's in ``nearest`` and its
        id goes in ``hit_by``. Only the bodies ``near`` (in some sensor's cone) are tested."""
        found, body = _body_echoes(origin, directions, bodies.centres[near], bodies.radii[near], self._first_ray,
                                   self._cos_critical, self._min_range)
        for index, (value, k) in enumerate(zip(found.tolist(), body.tolist(), strict=True)):
            if k >= 0 and value < nearest[index]:
                nearest[index] = value
                hit_by[index] = int(bodies.ids[near[k]])


@numba.njit(cache=True)
def _bodies_in_cones(xyz, axes, centres, radii, cone_sin, cone_cos, max_range):
    """The indices of the spheres inside some sensor's range and cone (its half-angle widened by the angle the
    sphere spans from ``xyz``), or that ``xyz`` lies in. Compiled: every read of a team's vehicle asks it of
    every team-mate within range, and most answers are none."""
    near = np.empty(len(radii), dtype=np.int64)
    count = 0
    for k in range(len(radii)):
        dx, dy, dz = centres[k, 0] - xyz[0], centres[k, 1] - xyz[1], centres[k, 2] - xyz[2]
        distance = math.sqrt(dx * dx + dy * dy + dz * dz)
        radius = radii[k]
        if distance <= radius:
            near[count] = k  # inside it: every ray starts in the sphere
            count += 1
            continue
        sin_body = radius / distance  # the half-angle the sphere spans, as seen from here
        cos_body = math.sqrt(1.0 - sin_body * sin_body)
        for sensor in range(len(cone_sin)):
            if distance - radius > max_range[sensor]:
                continue
            # inside the cone when the angle to the centre is under the cone's half-angle plus the sphere's
            cos_widened = cone_cos[sensor] * cos_body - cone_sin[sensor] * sin_body
            if (dx * axes[sensor, 0] + dy * axes[sensor, 1] + dz * axes[sensor, 2]) / distance >= cos_widened:
                near[count] = k
                count += 1
                break
    return near[:count]


@numba.njit(cache=True)
def _body_echoes(origin, directions, centres, radii, first_ray, cos_critical, min_range):
    """Per sensor, the nearest distance at which one of its rays enters one of the spheres (ray-sphere),
    meeting its surface no more obliquely than the critical angle, at min_range or further, and which sphere
    (the first in ray, then sphere order on a tie); inf and -1 if none. The sphere's normal at the entry point
    against the ray: its cosine is the root's share of the radius.

    A loop over a hundred rays and a few spheres: numpy's dozen calls on arrays that small cost several times
    more, at every read that has a team-mate in a cone."""
    count = len(cos_critical)
    nearest = np.full(count, np.inf)
    which = np.full(count, -1, dtype=np.int64)
    spheres = len(radii)
    offsets = np.empty((spheres, 3))
    inside = np.empty(spheres)  # squared distance to the centre less the squared radius
    for b in range(spheres):
        ox, oy, oz = centres[b, 0] - origin[0], centres[b, 1] - origin[1], centres[b, 2] - origin[2]
        offsets[b, 0], offsets[b, 1], offsets[b, 2] = ox, oy, oz
        inside[b] = (ox * ox + oy * oy + oz * oz) - radii[b] * radii[b]
    for sensor in range(count):
        for ray in range(first_ray[sensor], first_ray[sensor + 1]):
            dx, dy, dz = directions[ray, 0], directions[ray, 1], directions[ray, 2]
            for b in range(spheres):
                along = dx * offsets[b, 0] + dy * offsets[b, 1] + dz * offsets[b, 2]
                miss = along * along - inside[b]
                if miss < 0.0:
                    continue  # the ray passes by
                root = math.sqrt(miss)
                reach = along - root
                if reach >= min_range[sensor] and root / radii[b] >= cos_critical[sensor] and reach < nearest[sensor]:
                    nearest[sensor] = reach
                    which[sensor] = b
    return nearest, which


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
