"""The 3D view: the scene, the vehicles, their trails, sonar, memory maps, waypoints and planned paths, in viser.

viser runs its own server on a loopback port (the web app reverse-proxies it);
this module owns what all viewers share. A pose is sent as it comes: the fleet
marks the vehicles that moved and wakes the view's thread, which sends every
moved vehicle's pose in one atomic batch (a burst of messages is one update).
Trails, sonar and labels follow a few times a second, a map only when it
changed, and each client's own camera, markers and layer switches (its
``Viewport``) at most ``RATE`` times a second. Clicking the ground
proposes a target to that viewer alone (a marker only it sees); sending the
vehicle there goes through the REST API with the operator token.

Shared nodes sit under one root per layer (``/layers/trails/3`` is vehicle 3's
trail), so that a viewer hides a layer by hiding its own copy of that root.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import struct
import threading
import time
import warnings
from collections.abc import Callable

import numpy as np
import viser

from groundstation.state import Fleet, VehicleState
from groundstation.state import colour_of as colour
from groundstation.viewport import Vehicle, Viewport, opacity_root
from groundstation.views import Views
from vehicle.mapping import picture
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene

CLIENT_MARKER = "/_clients/"  # each client alone gets a hidden node of this name and its id (see proxy.py)
RATE = 30.0  # the viewers' cameras and markers, times a second at most (poses go as they come)
SLOW_PERIOD = 0.25  # s between two drawings of the trails, sonar, maps and labels
GATHER = 0.002  # s a pose waits for the rest of its burst (its position and attitude come back to back)
MAP_PIXELS = 512  # a map image is at most this many pixels a side
LAYER_NODES = ("trails", "beams", "echoes", "paths", "waypoints")  # a vehicle's node in each of these layers

# A viewer that closes its page is gone before viser tells us (``_gone``, which stops drawing for it): a frame
# drawn in between updates its handles, never to be delivered, and viser warns of it on the station's terminal,
# once for each viewer that left. Only viser's own warning of that is silenced.
warnings.filterwarnings("ignore", message=r"Queued a \w+ on a closed connection", category=UserWarning,
                        module=r"viser\.")


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """wxyz of a body (x forward, y left, z up) at a compass yaw, nose-up pitch and right-down roll."""
    heading = math.pi / 2 - yaw  # about +z, counter-clockwise from east
    halves = [(math.cos(a / 2), math.sin(a / 2)) for a in (heading, -pitch, roll)]
    (cz, sz), (cy, sy), (cx, sx) = halves
    # q = Rz(heading) * Ry(-pitch) * Rx(roll)
    return (cz * cy * cx + sz * sy * sx, cz * cy * sx - sz * sy * cx, cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx)


class SceneView:
    def __init__(self, fleet: Fleet, scene: Scene | None, port: int = 0, clock: Callable[[], float] = time.time):
        """``clock``: the time the fleet's messages are stamped in (the wall live, the log's own in a replay),
        so that live and replay draw alike."""
        self.fleet = fleet
        self.scene = scene
        self.clock = clock
        with contextlib.redirect_stdout(io.StringIO()):  # its banner names an internal port nobody should open
            self.server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)  # loopback: proxied only
        self.server.request_share_url = _refuse_share  # never open a public tunnel, whoever asks
        self.port = self.server.get_port()
        self.caster = RayCaster(scene) if scene is not None and len(scene.faces) else None
        self._on_target: Callable[[int, float, float], None] | None = None
        self.views = Views()  # what each page asked of its view (the web app writes it)
        self.viewer_of: Callable[[int], str | None] = lambda client_id: None  # viser client -> page (the proxy's)
        self._viewports: dict[int, Viewport] = {}
        self._generation: dict[int, int] = {}  # sysid -> how many times its shared nodes were made
        self._levels: set[float] = {1.0}  # map opacities some viewer uses: each is drawn
        self._last_frame = time.monotonic()  # the viewers' last frame
        self._drawn: dict[int, dict] = {}
        self._draw_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="viz", daemon=True)
        self._setup()

    # ---- setup ----------------------------------------------------------------------------------
    def _setup(self) -> None:
        server = self.server
        server.gui.configure_theme(show_share_button=False, control_width="small", dark_mode=True)
        server.gui.main_panel.minimize()  # the operator's panel is the page's; viser's own stays out of the way
        server.scene.set_up_direction("+z")
        # a dimmer environment than viser's default, so the scene's own colours show (not washed out)
        server.scene.configure_environment_map("city", environment_intensity=0.35)
        if self.scene is not None and len(self.scene.faces):
            server.scene.add_glb("/layers/scene/mesh", matte_glb(self.scene.mesh))
            low, high = self.scene.bounds
            size = float(max(high[0] - low[0], high[1] - low[1], 20))
            centre = ((low[0] + high[0]) / 2, (low[1] + high[1]) / 2, float(low[2]) - 0.02)
        else:
            size, centre = 200.0, (0.0, 0.0, 0.0)
        server.scene.add_grid("/layers/scene/ground", width=size, height=size, position=centre, cell_size=5.0,
                              section_size=25.0, plane="xy")

        # an oblique view of the whole scene from the south-west, for every viewer and exported replays
        server.initial_camera.position = (centre[0] - size * 0.35, centre[1] - size * 0.45, size * 0.3)
        server.initial_camera.look_at = (centre[0], centre[1], 0.0)

        @server.on_client_connect
        def _connected(client: viser.ClientHandle) -> None:
            # tells the proxy which viser client its connection carries (sent to this client only)
            client.scene.add_frame(f"{CLIENT_MARKER}{client.client_id}", show_axes=False, visible=False)
            with self._draw_lock:
                self._viewports[client.client_id] = Viewport(client)

        @server.on_client_disconnect
        def _gone(client: viser.ClientHandle) -> None:
            with self._draw_lock:
                self._viewports.pop(client.client_id, None)

        @server.scene.on_click()
        def _clicked(event) -> None:
            point = self.ground_point(event.ray_origin, event.ray_direction)
            if point is None:
                return
            viewer = self.viewer_of(event.client_id)
            with self._draw_lock:
                viewport = self._viewports.get(event.client_id)
                if viewport is not None:
                    viewport.pick(point)
                if viewer is not None:  # the page's target now, so that its next settings keep this mark
                    self.views.set_target(viewer, point[:2])
            if self._on_target is not None:
                self._on_target(event.client_id, point[0], point[1])

    def set_scene(self, scene: Scene | None) -> None:
        """Show another scene's mesh, or none: a replay's own while it plays, the live one after."""
        with self._draw_lock:
            self.scene = scene
            self.caster = RayCaster(scene) if scene is not None and len(scene.faces) else None
            self.server.scene.remove_by_name("/layers/scene/mesh")
            if self.caster is not None:
                self.server.scene.add_glb("/layers/scene/mesh", matte_glb(scene.mesh))

    def show(self, fleet: Fleet) -> None:
        """Draw this fleet from now on (the live one, or a replay's), starting from a clean slate."""
        with self._draw_lock:
            for sysid in list(self._drawn):
                self._remove_vehicle(sysid)
            self.fleet.pose_news.set()  # the loop waits on this fleet's news: it wakes to wait on the new one's
            self.fleet = fleet

    def on_target(self, callback: Callable[[int, float, float], None]) -> None:
        """``callback(client_id, x, y)`` when a viewer clicks a point on the ground."""
        self._on_target = callback

    def ground_point(self, origin, direction) -> tuple[float, float, float] | None:
        """Where a click ray meets the scene (or the plane z = 0 when there is no scene)."""
        origin = np.asarray(origin, dtype=float)
        direction = np.asarray(direction, dtype=float)
        if self.caster is not None:
            distance, _ = self.caster.cast(origin[None], direction[None])
            if np.isfinite(distance[0]):
                return tuple(float(v) for v in origin + direction * distance[0])
        if direction[2] >= -1e-6:
            return None
        t = -origin[2] / direction[2]
        return float(origin[0] + t * direction[0]), float(origin[1] + t * direction[1]), 0.0

    def ground_height(self, x: float, y: float) -> float:
        """The height of what stands at ``x, y`` (a roof, else the ground; 0 outside the scene)."""
        top = float(self.scene.bounds[1][2]) + 10.0 if self.scene is not None and len(self.scene.faces) else 10.0
        point = self.ground_point((x, y, top), (0.0, 0.0, -1.0))
        return point[2] if point is not None else 0.0

    # ---- the loop -------------------------------------------------------------------------------
    def start(self) -> SceneView:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self.fleet.pose_news.set()  # wakes the loop now, not on its next beat
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        with contextlib.redirect_stdout(io.StringIO()):  # nor its "Server stopped"
            self.server.stop()

    def _run(self) -> None:
        """Poses as they come (woken by the fleet); the viewers' frames and the slow layers on their beats."""
        next_frame = next_slow = time.monotonic()
        while not self._stop.is_set():
            if self.fleet.pose_news.wait(max(0.0, min(next_frame, next_slow) - time.monotonic())):
                if self._stop.wait(GATHER):  # the rest of the burst joins this update
                    break
            now = time.monotonic()
            slow, frame = now >= next_slow, now >= next_frame
            try:
                self.draw(slow=slow, frame=frame or slow)
            except Exception as error:  # noqa: BLE001 - a drawing problem must not stop the view
                print(f"3D view: {type(error).__name__}: {error}")
            if slow:
                next_slow = now + SLOW_PERIOD
            if frame or slow:
                next_frame = now + 1.0 / RATE

    def draw(self, slow: bool = True, frame: bool = True) -> None:
        """Bring the scene up to date with the fleet: the poses of the vehicles that moved (``slow``: of all,
        and their trails, sonar, maps and labels), then, on a ``frame``, each client's view (called by the
        loop; callable directly in tests)."""
        with self._draw_lock:
            vehicles = self._draw_poses(everyone=slow)
            if slow:
                self._draw_layers()
            if frame:
                seen = [Vehicle(v.sysid, np.array(self._drawn[v.sysid]["body"].position), v.yaw, v.pitch,
                                colour(v.sysid)) for v in vehicles if v.sysid in self._drawn]
                now = time.monotonic()
                dt, self._last_frame = min(now - self._last_frame, 0.5), now
                self._draw_viewports(seen, dt)
        self.server.flush()

    def _draw_poses(self, everyone: bool = False) -> list[VehicleState]:
        """The poses of the vehicles that moved (or of all), in one atomic update; returns the vehicles shown."""
        with self.fleet.lock:
            moved = self.fleet.take_moved()
            vehicles = [v for v in self.fleet.vehicles.values() if v.x is not None]
            gone = set(self._drawn) - {v.sysid for v in vehicles}
            with self.server.atomic():
                for sysid in gone:
                    self._remove_vehicle(sysid)
                for vehicle in vehicles:
                    if everyone or vehicle.sysid in moved or vehicle.sysid not in self._drawn:
                        self._draw_vehicle(vehicle, colour(vehicle.sysid), False)
        return vehicles

    def _draw_layers(self) -> None:
        """Each vehicle's slow layers in a hold of the fleet's lock of their own, its map picture made after
        the hold, and the poses that came meanwhile sent between two vehicles: a pose waits for one vehicle's
        layers at most, where it waited for the whole fleet's (and the fleet's messages with it)."""
        self._note_levels()
        for sysid in list(self._drawn):
            with self.fleet.lock:
                vehicle = self.fleet.vehicles.get(sysid)
                if vehicle is None or vehicle.x is None or sysid not in self._drawn:
                    continue
                with self.server.atomic():
                    self._draw_vehicle(vehicle, colour(sysid), True)
                new_map = self._drawn[sysid].pop("new_map", None)
            if new_map is not None:
                self._draw_map_picture(sysid, *new_map)
            if self.fleet.pose_news.is_set():
                self._draw_poses()
                self.server.flush()

    def _draw_viewports(self, vehicles: list[Vehicle], dt: float) -> None:
        bounds = self.scene.bounds if self.scene is not None and len(self.scene.faces) \
            else (np.array([-10.0, -10.0, 0.0]), np.array([10.0, 10.0, 2.0]))
        for client_id, viewport in list(self._viewports.items()):
            viewer = self.viewer_of(client_id)
            viewport.apply(self.views.get(viewer), self.ground_height)
            action = self.views.take_action(viewer) if viewer is not None else None
            zooms = self.views.take_zooms(viewer) if viewer is not None else []
            try:
                with viewport.client.atomic():
                    viewport.draw_markers(vehicles, self._generation)
                    viewport.move_camera(vehicles, action, zooms, dt, bounds, self.ground_point)
            except (AssertionError, ValueError) as error:  # a client mid-connect, or a pose viser refused
                print(f"3D view of client {client_id}: {type(error).__name__}: {error}")

    def _note_levels(self) -> None:
        """The map opacities viewers use now; a newly used one has every map drawn again at it."""
        levels = {viewport.opacity for viewport in self._viewports.values()} | {1.0}
        for level in self._levels - levels:
            self.server.scene.remove_by_name(opacity_root(level))
        if levels - self._levels:
            for drawn in self._drawn.values():
                drawn["map"] = None
        self._levels = levels

    def _remove_vehicle(self, sysid: int) -> None:
        scene = self.server.scene
        scene.remove_by_name(f"/vehicles/{sysid}")
        for layer in LAYER_NODES:
            scene.remove_by_name(f"/layers/{layer}/{sysid}")
        for level in self._levels:
            scene.remove_by_name(f"{opacity_root(level)}/{sysid}")
        self._drawn.pop(sysid, None)
        for viewport in self._viewports.values():
            viewport.forget(sysid)

    def _draw_vehicle(self, v: VehicleState, colour, slow: bool) -> None:
        scene = self.server.scene
        root = f"/vehicles/{v.sysid}"
        drawn = self._drawn.get(v.sysid)
        position = (v.x, v.y, self.fleet.height(v))
        if drawn is None:
            drawn = self._drawn[v.sysid] = {"version": -1, "map": None, "trail": 0, "path": None, "home": None,
                                            "drop": None}
            self._generation[v.sysid] = self._generation.get(v.sysid, 0) + 1
            drawn["body"] = scene.add_frame(f"{root}/body", show_axes=False)
            scene.add_icosphere(f"{root}/body/hull", radius=0.3, color=colour)
            scene.add_box(f"{root}/body/nose", dimensions=(0.5, 0.08, 0.08), position=(0.45, 0.0, 0.0),
                          color=(255, 255, 255))
            drawn["at"] = scene.add_frame(f"{root}/at", show_axes=False)  # its place, not turning with it
            # below the body: its marker sits on top (viewport.py), the label hangs under it
            drawn["label"] = scene.add_label(f"{root}/at/label", text=f"{v.sysid}", position=(0.0, 0.0, -0.35),
                                             anchor="top-center")
        drawn["body"].position = position
        drawn["body"].wxyz = _quaternion(v.roll, v.pitch, v.yaw)
        drawn["at"].position = position
        if not slow:
            return
        drawn["label"].text = f"{v.sysid} {v.kind} {v.mode}{' ARMED' if v.armed else ''}"
        self._draw_drop(v, root, colour, drawn, position)
        self._draw_trail(v, colour, drawn)
        self._draw_sonar(v)
        self._draw_mission(v, drawn)
        self._draw_map(v, drawn, position[2])

    def _draw_drop(self, v: VehicleState, root: str, colour, drawn: dict, position) -> None:
        """A line from the vehicle down to the ground under it: where it is over the map, and how high."""
        depth = max(0.0, position[2] - self.fleet.ground_height(v.x, v.y))
        if drawn["drop"] is not None and abs(drawn["drop"] - depth) < 0.05:
            return
        drawn["drop"] = depth
        if depth < 0.1:
            self.server.scene.remove_by_name(f"{root}/at/drop")
            return
        segment = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, -depth]]], dtype=np.float32)
        self.server.scene.add_line_segments(f"{root}/at/drop", segment, colors=colour, thickness=1.5,
                                            thickness_units="screen")

    def _draw_trail(self, v: VehicleState, colour, drawn: dict) -> None:
        if len(v.trail) < 2 or len(v.trail) == drawn["trail"]:
            return
        points = np.array(v.trail, dtype=np.float32)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        self.server.scene.add_line_segments(f"/layers/trails/{v.sysid}", segments, colors=colour, thickness=2.0,
                                            thickness_units="screen")
        drawn["trail"] = len(v.trail)

    def _draw_sonar(self, v: VehicleState) -> None:
        now = self.clock()
        rays = []
        for sonar in v.sonar.values():
            if now - sonar.time > 2.0:
                continue
            length = sonar.distance if sonar.distance is not None else min(sonar.max_range, 8.0)
            end = tuple(o + d * length for o, d in zip(sonar.origin, sonar.direction, strict=True))
            rays.append((sonar.origin, end))
        if rays:
            self.server.scene.add_line_segments(f"/layers/beams/{v.sysid}", np.array(rays, dtype=np.float32),
                                                colors=(255, 80, 80), thickness=1.5, thickness_units="screen")
        if v.hits:
            self.server.scene.add_point_cloud(f"/layers/echoes/{v.sysid}", np.array(v.hits, dtype=np.float32),
                                              colors=(255, 60, 60), point_size=0.12)

    def _draw_mission(self, v: VehicleState, drawn: dict) -> None:
        scene = self.server.scene
        root = f"/layers/waypoints/{v.sysid}"
        if v.home is not None and drawn["home"] != v.home:
            base = self.fleet.ground_height(*v.home)
            scene.add_icosphere(f"{root}/home", radius=0.35, color=(60, 220, 90), position=(*v.home, base + 0.1))
            drawn["home"] = v.home
        height = self.fleet.height(v)
        path = v.planned_path()
        if path != drawn["path"]:
            drawn["path"] = path
            if len(path) >= 2:
                points = np.array([(x, y, height) for x, y in path], dtype=np.float32)
                scene.add_line_segments(f"/layers/paths/{v.sysid}", np.stack([points[:-1], points[1:]], axis=1),
                                        colors=(255, 230, 0), thickness=3.0, thickness_units="screen")
            else:
                scene.remove_by_name(f"/layers/paths/{v.sysid}")
        if v.waypoints and drawn.get("waypoints") != v.waypoints:
            drawn["waypoints"] = list(v.waypoints)
            points = np.array([(x, y, height) for x, y in v.waypoints], dtype=np.float32)
            scene.add_point_cloud(f"{root}/points", points, colors=(80, 200, 255), point_size=0.6)

    def _draw_map(self, v: VehicleState, drawn: dict, height: float) -> None:
        """Takes a copy of a changed map (under the fleet's lock); ``_draw_map_picture`` draws it after."""
        stream_version = (v.map_stream.version, v.own_map.version if v.own_map is not None else 0)
        if drawn["map"] == stream_version:
            return
        grid = v.map_grid()
        if grid is None:
            return
        drawn["map"] = stream_version
        drawn["new_map"] = ((grid[0].copy(), *grid[1:]), height)

    def _draw_map_picture(self, sysid: int, grid: tuple, height: float) -> None:
        found = picture.overlay(*grid, MAP_PIXELS)
        if found is None:
            return
        image, (west, south, east, north) = found.image, found.window
        width, depth = east - west, north - south
        centre = ((west + east) / 2, (south + north) / 2, height - 0.05)
        with self.server.atomic():
            for level in self._levels:  # one picture per opacity some viewer uses (viser's images have none)
                faded = image.copy()
                faded[..., 3] = (faded[..., 3] * level).astype(np.uint8)
                self.server.scene.add_image(f"{opacity_root(level)}/{sysid}", faded, render_width=width,
                                            render_height=depth, format="png", position=centre)


def _refuse_share(*args, **kwargs) -> None:
    """Replaces viser's share-tunnel request: this server is never exposed beyond the web app."""
    return None


MATTE = {"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                  "roughnessFactor": 0.9}}


def matte_glb(mesh) -> bytes:
    """The scene mesh as binary glTF, its colours on a matte material. trimesh writes a mesh coloured per face
    with no material, and a glTF viewer then takes the format's default, a metal (metallicFactor 1), which
    shows only what it reflects: lit by the environment map, with none (an exported replay) every wall facing
    away from the sun was black. Written by hand because trimesh's export has no say in the material."""
    glb = mesh.export(file_type="glb")
    json_length = struct.unpack_from("<I", glb, 12)[0]
    document = json.loads(glb[20:20 + json_length])
    document["materials"] = [*document.get("materials", []), MATTE]
    for primitive in (p for m in document.get("meshes", []) for p in m["primitives"]):
        primitive.setdefault("material", len(document["materials"]) - 1)
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are padded to 4 bytes, JSON's with spaces
    rest = glb[20 + json_length:]  # the binary chunk, as it was
    return struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + len(rest)) + \
        struct.pack("<I4s", len(text), b"JSON") + text + rest

