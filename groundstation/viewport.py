"""One viser client's own view: its camera in each mode, vehicle markers sized for its screen, its layers.

viser scopes nodes per client (``client.scene``): a client's node shadows a
shared one of the same name, and shared nodes hang under it by name. So each
client gets its own layer roots (``/layers/trails`` ...), whose visibility
hides or shows every vehicle's shared trail in that client alone, and its own
marker on each vehicle (a dart along the heading and, on the selected
vehicle, a ring), rescaled every frame from that client's camera distance so
that a vehicle is never smaller than ``MARKER_PIXELS`` on its screen.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
import viser

from groundstation import camera
from groundstation.views import LAYERS, OPACITIES, ViewSettings, Zoom

MARKER_PIXELS = 44.0  # a vehicle's dart is at least this long on screen
DART_LENGTH = 0.9  # m at scale 1 (the hull is 0.6 m across)
HALO_RADIUS = 0.7  # m at scale 1
HEADING_LAG = 0.5  # s: the follow camera turns after the vehicle with this time constant
ZOOM_STEP = 0.85  # distance factor per wheel step
FOLLOW_DISTANCE = (8.0, 2.0, 200.0)  # m behind the vehicle: default, nearest, furthest
TOP_HEIGHT = (30.0, 3.0, 500.0)  # m above the vehicle (top-down): default, lowest, highest
SELECTED = (255, 255, 255)
TARGET_COLOUR = (255, 230, 0)
WALL_MARGIN = 0.3  # m: the follow camera stops this far in front of a wall between it and the vehicle
PAN_SECONDS = 0.6  # the orbit camera's slide that brings a vehicle that flew out of sight back into it
STILL = 1e-3  # m: a camera that moved less than this since the last frame was left alone by its viewer


def opacity_root(opacity: float) -> str:
    return f"/layers/map/o{round(opacity * 100)}"


@dataclass
class Vehicle:
    """What a viewport needs of a drawn vehicle."""
    sysid: int
    position: np.ndarray
    yaw: float
    pitch: float
    colour: tuple[int, int, int]


def clear_eye(vehicle, eye, ground_point) -> np.ndarray:
    """The eye pulled in front of the first wall (or the ground) between the vehicle and it, so the
    follow camera sees the vehicle rather than the back of a building. ``ground_point(origin, direction)``
    is the scene's ray cast (falling back to the plane z = 0)."""
    vehicle, eye = np.asarray(vehicle, dtype=float), np.asarray(eye, dtype=float)
    offset = eye - vehicle
    length = float(np.linalg.norm(offset))
    if length < 1e-6:
        return eye
    direction = offset / length
    hit = ground_point(vehicle, direction)
    if hit is None:
        return eye
    distance = float(np.dot(np.asarray(hit, dtype=float) - vehicle, direction))
    if distance < 0.0 or distance >= length:
        return eye
    return vehicle + direction * max(distance - WALL_MARGIN, 0.0)


def _dart() -> tuple[np.ndarray, np.ndarray]:
    """A flat arrowhead along +x (the body's nose), a little raised in the middle so it reads from the side."""
    length = DART_LENGTH
    vertices = np.array([(length * 0.6, 0, 0), (-length * 0.4, length * 0.45, 0), (-length * 0.15, 0, 0),
                         (-length * 0.4, -length * 0.45, 0), (-length * 0.05, 0, length * 0.18),
                         (-length * 0.05, 0, -length * 0.18)], dtype=np.float32)
    vertices[:, 2] += length * 0.35  # on top of the hull: a vehicle on the ground does not bury it
    top = [(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)]
    faces = np.array(top + [(b, a, 5) for a, b, _ in top], dtype=np.uint32)
    return vertices, faces


DART = _dart()
HALO = trimesh.creation.torus(major_radius=HALO_RADIUS, minor_radius=0.06, major_sections=32, minor_sections=6)
HALO.apply_translation((0.0, 0.0, 0.1))  # just above the ground under a landed vehicle


def _target_symbol() -> trimesh.Trimesh:
    """A ring on the ground with a pole through it: a picked point that reads from afar (1 m high at scale 1)."""
    ring = trimesh.creation.torus(major_radius=0.5, minor_radius=0.06, major_sections=32, minor_sections=6)
    ring.apply_translation((0.0, 0.0, 0.06))
    pole = trimesh.creation.cylinder(radius=0.04, height=1.0, sections=8)
    pole.apply_translation((0.0, 0.0, 0.5))
    return trimesh.util.concatenate([ring, pole])


TARGET = _target_symbol()


class Viewport:
    """The per-client half of the 3D view (driven by ``SceneView`` on its thread, under its lock)."""

    def __init__(self, client: viser.ClientHandle):
        self.client = client
        self.roots = {name: client.scene.add_frame(f"/layers/{name}", show_axes=False) for name in LAYERS}
        self.levels = {o: client.scene.add_frame(opacity_root(o), show_axes=False, visible=o == 1.0)
                       for o in OPACITIES}
        self.markers: dict[int, dict] = {}  # sysid -> its dart, its ring and their last scale
        self.target: dict | None = None  # the page's Go here target: its symbol, where, its scale
        self.version = -1
        self.mode = "orbit"
        self.sysid: int | None = None
        self.opacity = 1.0
        self.heading: float | None = None
        self.follow_distance = FOLLOW_DISTANCE[0]
        self.top_height = TOP_HEIGHT[0]
        self.covered: camera.Box | None = None  # the part of the view under the page's 2D map
        self.seen: tuple | None = None  # the orbit camera's last pose, and whether the vehicle was in sight
        self.pan: tuple | None = None  # a slide under way: from, to, seconds into it

    # ---- settings -------------------------------------------------------------------------------
    def apply(self, settings: ViewSettings | None, ground: Callable[[float, float], float]) -> None:
        """Take the page's settings when they changed: layers, map opacity and the target (marked on the
        ``ground`` height there) now, the mode from the next frame."""
        if settings is None or settings.version == self.version:
            return
        self.version = settings.version
        held = tuple(self.target["point"]) if self.target is not None else None
        if settings.target is None:
            self.drop_target()
        elif held is None or not np.allclose(held, settings.target, atol=1e-6):
            x, y = settings.target
            self.pick((x, y, ground(x, y)))
        if settings.mode != self.mode:
            self.heading = None
        self.mode, self.sysid, self.opacity = settings.mode, settings.sysid, settings.opacity
        self.covered = settings.covered
        for name, root in self.roots.items():
            root.visible = bool(settings.layers.get(name, True))
        for opacity, root in self.levels.items():
            root.visible = opacity == settings.opacity

    def selected(self, vehicles: list[Vehicle]) -> Vehicle | None:
        """The page's selected vehicle, else the first."""
        chosen = [v for v in vehicles if v.sysid == self.sysid]
        return chosen[0] if chosen else (vehicles[0] if vehicles else None)

    # ---- markers --------------------------------------------------------------------------------
    def draw_markers(self, vehicles: list[Vehicle], generation: dict[int, int]) -> None:
        """Each vehicle's dart and the selected one's ring, scaled for this client's screen."""
        eye, pixels_per_metre_at_1m = self._lens()
        selected = self.selected(vehicles)
        for sysid in set(self.markers) - {v.sysid for v in vehicles}:
            self.forget(sysid)
        for v in vehicles:
            marker = self.markers.get(v.sysid)
            if marker is None or marker["generation"] != generation.get(v.sysid):
                self.forget(v.sysid)
                marker = self.markers[v.sysid] = self._add_marker(v, generation.get(v.sysid))
            scale = 1.0
            if eye is not None:
                distance = float(np.linalg.norm(v.position - eye))
                scale = max(1.0, MARKER_PIXELS * distance / (pixels_per_metre_at_1m * DART_LENGTH))
            own_view = self.mode == "onboard" and selected is v
            if abs(scale - marker["scale"]) > marker["scale"] * 0.03:
                marker["dart"].scale = scale
                marker["halo"].scale = scale
                marker["scale"] = scale
            marker["dart"].visible = not own_view
            marker["halo"].visible = selected is v and not own_view
        self._draw_target(eye, pixels_per_metre_at_1m)

    def pick(self, point: tuple[float, float, float]) -> None:
        """Mark the page's Go here target (a new one replaces the old). The page drops it: it knows which
        vehicle was sent there and sees it arrive (static/target.js)."""
        self.drop_target()
        node = self.client.scene.add_mesh_simple("/target", TARGET.vertices.astype(np.float32),
                                                 TARGET.faces.astype(np.uint32), color=TARGET_COLOUR,
                                                 position=point)
        self.target = {"node": node, "point": np.array(point[:2]), "scale": 1.0}

    def drop_target(self) -> None:
        if self.target is not None:
            self.target["node"].remove()
            self.target = None

    def _draw_target(self, eye: np.ndarray | None, pixels_per_metre_at_1m: float) -> None:
        """Scale the target for this screen: the same size on the screen from near and far."""
        target = self.target
        if target is None or eye is None:
            return
        distance = float(np.linalg.norm(np.array(target["node"].position) - eye))
        scale = max(1.0, MARKER_PIXELS * distance / pixels_per_metre_at_1m)
        if abs(scale - target["scale"]) > target["scale"] * 0.03:
            target["node"].scale = target["scale"] = scale

    def _lens(self) -> tuple[np.ndarray | None, float]:
        """The client's eye and its pixels per metre at 1 m (None before it reported its camera)."""
        try:
            cam = self.client.camera
            eye, fov, height = np.array(cam.position), float(cam.fov), float(cam.image_height)
        except AssertionError:  # viser asserts until the client first reports its camera
            return None, 1.0
        if not (fov > 0 and height > 0):
            return None, 1.0
        return eye, height / (2 * math.tan(fov / 2))

    def _add_marker(self, v: Vehicle, generation: int | None) -> dict:
        scene = self.client.scene
        root = f"/vehicles/{v.sysid}"
        vertices, faces = DART
        dart = scene.add_mesh_simple(f"{root}/body/dart", vertices, faces, color=v.colour, side="double",
                                     flat_shading=True)
        halo = scene.add_mesh_simple(f"{root}/at/halo", HALO.vertices.astype(np.float32),
                                     HALO.faces.astype(np.uint32), color=SELECTED, visible=False)
        return {"dart": dart, "halo": halo, "scale": 1.0, "generation": generation}

    def forget(self, sysid: int) -> None:
        marker = self.markers.pop(sysid, None)
        if marker is not None:
            marker["dart"].remove()
            marker["halo"].remove()

    # ---- camera ---------------------------------------------------------------------------------
    def move_camera(self, vehicles: list[Vehicle], action: str | None, zooms: list[Zoom], dt: float,
                    bounds: tuple[np.ndarray, np.ndarray], ground_point) -> None:
        """One frame of this client's camera: a one-shot move, the wheel, then the mode's own pose."""
        target = self.selected(vehicles)
        if action == "fit":
            try:
                lens = {"fov": float(self.client.camera.fov), "aspect": float(self.client.camera.aspect)}
            except (AssertionError, ZeroDivisionError):
                lens = {}
            self._place(camera.fit(*self._fit_box(bounds, vehicles), **lens))
        elif action == "vehicle" and target is not None:
            self._place(camera.overview(target.position, target.yaw))
        for zoom in zooms:
            self._zoom(zoom, ground_point)
        if target is None:
            return
        if self.mode == "follow":
            self.heading = camera.smooth_angle(self.heading, target.yaw, dt, HEADING_LAG)
            eye, look = camera.follow(target.position, self.heading, self.follow_distance)
            self._place((clear_eye(target.position, eye, ground_point), look))
        elif self.mode == "onboard":
            self._place(camera.onboard(target.position, target.yaw, target.pitch))
        elif self.mode == "top":
            self._place(camera.top(target.position, self.top_height))
        elif self.mode == "orbit":
            self._keep_in_sight(target, dt)

    def _keep_in_sight(self, vehicle: Vehicle, dt: float) -> None:
        """The orbit camera is the viewer's own, but a vehicle flying out of it (off the edge, behind the
        page's 2D map) while the viewer left the camera alone slides the camera after it, its angle kept.
        A viewer who turned the camera away from the vehicle is not followed back."""
        try:
            cam = self.client.camera
            eye, look = np.array(cam.position, dtype=float), np.array(cam.look_at, dtype=float)
            wxyz, fov, aspect = np.array(cam.wxyz, dtype=float), float(cam.fov), float(cam.aspect)
        except (AssertionError, ZeroDivisionError):
            return
        if self.pan is not None:
            start, end, spent = self.pan
            spent += dt
            self.pan = None if spent >= PAN_SECONDS else (start, end, spent)
            eye, look = camera.blend(start, end, min(1.0, spent / PAN_SECONDS))
            self._place((eye, look))
        sighted = camera.in_sight(camera.project(wxyz, eye, fov, aspect, vehicle.position), self.covered)
        before = self.seen
        self.seen = (eye, look, sighted)
        if self.pan is not None or before is None or sighted or not before[2]:
            return
        if np.linalg.norm(eye - before[0]) > STILL or np.linalg.norm(look - before[1]) > STILL:
            return  # the viewer moved the camera off the vehicle: theirs to look where they like
        end = camera.recentre(eye, look, wxyz, fov, aspect, vehicle.position, camera.open_middle(self.covered))
        self.pan = ((eye, look), end, 0.0)

    @staticmethod
    def _fit_box(bounds, vehicles: list[Vehicle]) -> tuple[np.ndarray, np.ndarray]:
        low, high = np.array(bounds[0], dtype=float), np.array(bounds[1], dtype=float)
        for v in vehicles:
            low, high = np.minimum(low, v.position), np.maximum(high, v.position)
        return low, high

    def _zoom(self, zoom: Zoom, ground_point) -> None:
        factor = ZOOM_STEP ** zoom.steps
        if self.mode == "follow":
            self.follow_distance = float(np.clip(self.follow_distance * factor, *FOLLOW_DISTANCE[1:]))
        elif self.mode == "top":
            self.top_height = float(np.clip(self.top_height * factor, *TOP_HEIGHT[1:]))
        elif self.mode == "orbit":
            try:
                cam = self.client.camera
                eye, target = np.array(cam.position), np.array(cam.look_at)
                direction = camera.ray(cam.wxyz, cam.fov, cam.aspect, zoom.x, zoom.y)
            except (AssertionError, ZeroDivisionError):
                return
            point = ground_point(eye, direction)
            if point is None:  # the sky: towards the point as far along the ray as the orbit centre is
                point = eye + direction * float(np.linalg.norm(target - eye))
            self._place(camera.zoom_at(eye, target, point, factor))

    def _place(self, pose: camera.Pose) -> None:
        eye, target = (np.asarray(p, dtype=float) for p in pose)
        if not (np.all(np.isfinite(eye)) and np.all(np.isfinite(target))) or np.allclose(eye, target):
            return
        cam = self.client.camera
        try:
            cam.position  # noqa: B018 - viser asserts until the client first reported its camera
        except AssertionError:
            return
        cam.up_direction = (0.0, 0.0, 1.0)
        cam.position = eye
        cam.look_at = target
