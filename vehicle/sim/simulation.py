"""The simulation: a scene, one vehicle in it (body, autopilot, sensors, battery), and the simulated clock.

Everything here runs on simulated time in fixed steps, so a run is a pure
function of its inputs and seed. ``Simulation.step()`` moves the vehicle one
step, checks the swept body against the scene, and returns the sonar readings
taken. It knows nothing of an onboard agent: one talks to its autopilot
(``vehicle.sim.onboard`` in-process, or MAVLink through ``vehicle.sim.endpoint``).
"""

from __future__ import annotations

import math

import numpy as np

from vehicle.protocol.frames import Pose
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.modes import Kind
from vehicle.protocol.rangefinder import Reading, Servo
from vehicle.sim.autopilot import Autopilot
from vehicle.sim.avoidance import BAND as AVOID_BAND
from vehicle.sim.avoidance import MARGIN as AVOID_MARGIN
from vehicle.sim.avoidance import ObstacleDatabase
from vehicle.sim.battery import Battery
from vehicle.sim.physics import Body, Limits
from vehicle.world.collision import Collider, Contact, TriangleGrid
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene
from vehicle.world.sonar import Bodies, Sonar, SonarArray
from vehicle.world.suites import DEFAULT_SUITE, LOOKS_DOWN, LOOKS_UP, sensor_suite

DEFAULT_STEP = 0.05  # s
SONAR_RATE = 10.0  # Hz: readings per second, as long-range ultrasonic sensors manage
STEP_HEIGHT = 0.5  # m: a rover climbs onto surfaces at most this far above its wheels
BATTERY_LOW = 0.2  # share of the charge left when the autopilot warns (ArduPilot's BATT_LOW_MAH, as a share)
BATTERY_CRITICAL = 0.1  # ... and when it lands a copter or holds a rover (BATT_FS_CRT_ACT)
FARTHEST_START = 100_000.0  # m from the scene's origin: a scene is local metres, and telemetry's positions overflow


class PlacementError(ValueError):
    """The vehicle cannot start where it was asked to."""


class Simulation:
    def __init__(self, scene: Scene, kind: Kind | str = Kind.COPTER, start: tuple[float, ...] | None = None,
                 heading: float | None = None, seed: int = 0, dt: float = DEFAULT_STEP,
                 sensors: list[Sonar] | None = None, datum: Datum | None = None, limits: Limits | None = None,
                 backend: str = "auto", sonar_rate: float = SONAR_RATE, cruise_speed: float = 2.5,
                 wp_radius: float = 2.0, battery: Battery | None = None):
        """``start`` is x, y (scene metres), or x, y, z: then the vehicle stands on the highest surface below
        z (a floor under a roof); without it, the scene's own start. ``cruise_speed`` and ``wp_radius`` are
        the autopilot's (WPNAV_SPEED, WP_RADIUS); ``battery`` the flight battery (default: 5 Ah, 4 cells)."""
        self.scene = scene
        self.kind = Kind(kind)
        self.dt = dt
        self.time = 0.0
        self.steps = 0
        self.datum = datum or Datum()
        self.caster = scene.prepared(("caster", backend), lambda: RayCaster(scene, backend))
        self.limits = limits or Limits()
        x, y, *height = start if start is not None else (scene.start or (0.0, 0.0))
        if not all(abs(v) <= FARTHEST_START for v in (x, y, *height)):  # NaN too
            raise PlacementError(f"the start {', '.join(f'{v:g}' for v in (x, y, *height))} lies more than "
                                 f"{FARTHEST_START / 1000:g} km from the scene's origin")
        heading = heading if heading is not None else (scene.start_heading or 0.0)
        ground = self.caster.ground_height(x, y)
        if height and ground > height[0]:  # a roof above the start height: stand on what is below it
            ground = self.caster.ground_height(x, y, default=math.nan, below=height[0])
            if math.isnan(ground):
                raise PlacementError(f"nothing to stand on below the start x={x:g} y={y:g} z={height[0]:g}")
        self._check_footing(x, y, ground)
        self.body = Body(self.kind, self.limits, Pose(x, y, 0.0, yaw=math.radians(heading) % (2 * math.pi)))
        self.body.pose.z = self.body.rest_height(ground)
        walkable = self.kind is Kind.ROVER  # a rover's wheels touch the ground it drives on
        grid = scene.prepared(("triangles", walkable), lambda: TriangleGrid(scene, ignore_walkable=walkable))
        self.collider = Collider(grid, self.limits.radius)
        if self.collider.touches(np.array(self.body.pose.xyz())):
            raise PlacementError(f"the start x={x:g} y={y:g} is inside an obstacle")
        self.avoidance = ObstacleDatabase(margin=AVOID_MARGIN, accel=self.limits.accel, body_radius=self.limits.radius)
        self.autopilot = Autopilot(self.kind, self.body, (x, y, ground), self.datum,
                                   cruise_speed=cruise_speed, wp_radius=wp_radius,
                                   avoidance=self.avoidance)
        self.sonars = SonarArray(sensors if sensors is not None else sensor_suite(DEFAULT_SUITE, self.kind),
                                 self.caster, seed)
        self.battery = battery or Battery()
        self._battery_alarm_mah = BATTERY_LOW * self.battery.capacity_mah  # the charge the next alarm comes at
        self.collision: Contact | None = None
        self.distance_travelled = 0.0
        self._ground = (ground, (0.0, 0.0, 1.0))
        self._ground_xy = (x, y)
        self.sonar_rate = sonar_rate
        self._next_reading = 0.0

    def _check_footing(self, x: float, y: float, ground: float) -> None:
        """Refuse a start whose ground falls away under the body (the top of a wall, the edge of a roof): the
        vehicle would stand on nothing there, and a copter landing back home would land onto the edge."""
        radius = self.limits.radius
        heights = [self.caster.ground_height(x + radius * math.cos(a), y + radius * math.sin(a),
                                             below=ground + radius) for a in np.linspace(0, 2 * math.pi, 8, False)]
        if not all(abs(h - ground) <= radius for h in heights):
            low = min(heights, key=lambda h: -abs(h - ground))
            raise PlacementError(f"the start x={x:g} y={y:g} stands on an edge: the ground {radius:g} m from it "
                                 f"lies at {low:.2f} m, {ground:.2f} m under it")

    def _battery_alarm(self) -> None:
        """The battery crossed the low or the critical level: the autopilot says so, and at critical acts."""
        battery = self.battery
        critical = battery.remaining <= BATTERY_CRITICAL
        self._battery_alarm_mah = -1.0 if critical else BATTERY_CRITICAL * battery.capacity_mah
        self.autopilot.battery_failsafe(critical, battery.voltage, battery.remaining)

    @property
    def servo(self) -> Servo | None:
        """The servo that turns a sonar, if the vehicle has one (the onboard agent scans with it)."""
        return next((s.servo for s in self.sonars.sensors if s.servo is not None), None)

    @property
    def pose(self) -> Pose:
        return self.body.pose

    @property
    def home(self) -> tuple[float, float, float]:
        return self.autopilot.home

    def ground_under(self, x: float, y: float, z: float) -> tuple[float, tuple[float, float, float]]:
        """Height and normal of the surface below a point (a rover's wheels may climb a small step)."""
        top = z + STEP_HEIGHT
        distance, face = self.caster.cast_down(x, y, top)
        if not math.isfinite(distance):
            return self._ground[0], (0.0, 0.0, 1.0)
        nx, ny, nz = self.caster.face_normals[face].tolist()
        if nz < 0:
            nx, ny, nz = -nx, -ny, -nz
        return top - distance, (nx, ny, nz)

    def _ground_stale(self) -> bool:
        """A copter high above the ground it last measured need not look again until it moves a metre."""
        if self.kind is Kind.ROVER:
            return True
        pose = self.body.pose
        return (pose.z - self._ground[0] < 2.0
                or math.hypot(pose.x - self._ground_xy[0], pose.y - self._ground_xy[1]) > 1.0)

    def step(self) -> list[Reading]:
        """Advance one fixed step; returns the sonar readings taken at its end (when one is due)."""
        self.move()
        return self.sense()

    def move(self) -> tuple[tuple[float, float, float], tuple[float, float, float]] | None:
        """The first half of a step: the autopilot moves the body and the swept body is checked against the
        scene. Returns where the body went from and to, or None for a wreck (a team checks the bodies
        against each other between this and ``sense``)."""
        if self.collision is not None:  # the wreck lies still; its clock goes on
            self.steps += 1
            self.time = self.steps * self.dt
            return None
        pose = self.body.pose
        if self._ground_stale():
            bottom = pose.z - self.limits.radius - self.limits.ground_clearance
            self._ground = self.ground_under(pose.x, pose.y, bottom)
            self._ground_xy = (pose.x, pose.y)
        before = pose.xyz()
        self.autopilot.step(self.dt, *self._ground)
        after = pose.xyz()
        self.steps += 1
        self.time = self.steps * self.dt
        contact = self.collider.sweep(before, after)
        if contact is not None:
            self.crash(contact)
            return None
        self.distance_travelled += math.dist(before, after)
        autopilot, body = self.autopilot, self.body
        self.battery.drain(self.dt, autopilot.armed, autopilot.flying, math.hypot(body.vx, body.vy), body.vz)
        if self.battery.charge_mah <= self._battery_alarm_mah:
            self._battery_alarm()
        return before, after

    def crash(self, contact: Contact) -> None:
        """The body touched something: it stops where it first touched, disarmed, a wreck from now on."""
        pose = self.body.pose
        pose.x, pose.y, pose.z = (float(v) for v in contact.point)
        self.body.stop()
        self.collision = contact
        self.autopilot.crashed()

    @property
    def reading_due(self) -> bool:
        """The sonars read at the end of this step (a wreck's never do)."""
        return self.collision is None and self.time + 1e-9 >= self._next_reading

    def sense(self, bodies: Bodies | None = None) -> list[Reading]:
        """The second half of a step: the sonar readings, when one is due (``bodies``: the team-mates around)."""
        if self.collision is not None or self.time + 1e-9 < self._next_reading:
            return []
        pose = self.body.pose
        self._next_reading += 1.0 / self.sonar_rate
        for sensor in self.sonars.sensors:  # servos follow the autopilot's outputs
            if sensor.servo is not None and sensor.servo.channel in self.autopilot.servos:
                sensor.servo.pwm = self.autopilot.servos[sensor.servo.channel]
        readings = self.sonars.read(pose, self.time, bodies)
        if readings:
            ox, oy, oz = readings[0].origin.tolist()  # one origin for every sensor of a read
            for reading in readings:
                distance = reading.distance
                if not LOOKS_DOWN < reading.pitch < LOOKS_UP:
                    continue  # the ground's sensor and the overhead one: as ArduPilot's proximity library,
                    # the avoidance takes level range finders only (it skips custom orientations)
                if distance is not None and reading.vehicle is None:  # the team keeps apart by giving way: a
                    # team-mate held in the database of fixed obstacles would block the way after it left
                    dx, dy, dz = reading.direction.tolist()  # reading.hit, in plain floats
                    hz = oz + dz * distance
                    if abs(hz - pose.z) <= AVOID_BAND:
                        self.avoidance.add(ox + dx * distance, oy + dy * distance, hz, self.time)
        return readings

    def run_for(self, seconds: float) -> list[Reading]:
        """Step for a span of simulated time; returns every reading taken."""
        readings: list[Reading] = []
        for _ in range(max(1, round(seconds / self.dt))):
            readings.extend(self.step())
            if self.collision is not None:
                break
        return readings
