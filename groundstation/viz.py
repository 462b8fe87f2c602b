"""The 3D view: the scene, the vehicles, their trails, sonar, memory maps, waypoints and planned paths, in viser.

viser runs its own server on a loopback port (the web app reverse-proxies it);
this module owns what it shows. A loop redraws at most ``RATE`` times a second,
in one atomic batch, and only what changed: poses every frame, trails and
sonar a few times a second, a map only when it changed. Clicking the ground
proposes a target to that viewer alone (a marker only it sees); sending the
vehicle there goes through the REST API with the operator token.
"""

from __future__ import annotations

import contextlib
import io
import math
import threading
import time
from collections.abc import Callable

import numpy as np
import viser

from groundstation.state import Fleet, VehicleState
from vehicle.mapping.memory_map import state_image, states_of
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene

CLIENT_MARKER = "/_clients/"  # each client alone gets a hidden node of this name and its id (see proxy.py)
RATE = 30.0  # frames per second at most (poses); trails, sonar and maps far less often
SLOW_EVERY = 8  # trails, sonar, maps and labels every this many frames
MAP_PIXELS = 512  # a map image is at most this many pixels a side
COLOURS = [(230, 90, 40), (40, 150, 240), (120, 200, 60), (220, 60, 200), (240, 200, 40), (60, 220, 200)]


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
            server.scene.add_mesh_trimesh("/scene", self.scene.mesh)
            low, high = self.scene.bounds
            size = float(max(high[0] - low[0], high[1] - low[1], 20))
            centre = ((low[0] + high[0]) / 2, (low[1] + high[1]) / 2, float(low[2]) - 0.02)
        else:
            size, centre = 200.0, (0.0, 0.0, 0.0)
        server.scene.add_grid("/ground", width=size, height=size, position=centre, cell_size=5.0,
                              section_size=25.0, plane="xy")

        # an oblique view of the whole scene from the south-west, for every viewer and exported replays
        server.initial_camera.position = (centre[0] - size * 0.35, centre[1] - size * 0.45, size * 0.3)
        server.initial_camera.look_at = (centre[0], centre[1], 0.0)

        @server.on_client_connect
        def _connected(client: viser.ClientHandle) -> None:
            # tells the proxy which viser client its connection carries (sent to this client only)
            client.scene.add_frame(f"{CLIENT_MARKER}{client.client_id}", show_axes=False, visible=False)

        @server.scene.on_click()
        def _clicked(event) -> None:
            point = self.ground_point(event.ray_origin, event.ray_direction)
            if point is None:
                return
            event.client.scene.add_icosphere("/target", radius=0.4, color=(255, 230, 0), position=point)
            if self._on_target is not None:
                self._on_target(event.client_id, point[0], point[1])

    def set_scene(self, scene: Scene | None) -> None:
        """Show another scene's mesh, or none: a replay's own while it plays, the live one after."""
        with self._draw_lock:
            self.scene = scene
            self.caster = RayCaster(scene) if scene is not None and len(scene.faces) else None
            self.server.scene.remove_by_name("/scene")
            if self.caster is not None:
                self.server.scene.add_mesh_trimesh("/scene", scene.mesh)

    def show(self, fleet: Fleet) -> None:
        """Draw this fleet from now on (the live one, or a replay's), starting from a clean slate."""
        with self._draw_lock:
            for sysid in list(self._drawn):
                self.server.scene.remove_by_name(f"/vehicles/{sysid}")
            self._drawn.clear()
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

    # ---- the loop -------------------------------------------------------------------------------
    def start(self) -> SceneView:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        with contextlib.redirect_stdout(io.StringIO()):  # nor its "Server stopped"
            self.server.stop()

    def _run(self) -> None:
        frame = 0
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                self.draw(slow=frame % SLOW_EVERY == 0)
            except Exception as error:  # noqa: BLE001 - a drawing problem must not stop the view
                print(f"3D view: {type(error).__name__}: {error}")
            frame += 1
            self._stop.wait(max(0.0, 1.0 / RATE - (time.monotonic() - started)))

    def draw(self, slow: bool = True) -> None:
        """Bring the scene up to date with the fleet (called by the loop; callable directly in tests)."""
        with self._draw_lock, self.fleet.lock:
            vehicles = [(v.sysid, v) for v in self.fleet.vehicles.values() if v.x is not None]
            gone = set(self._drawn) - {sysid for sysid, _ in vehicles}
            with self.server.atomic():
                for sysid in gone:
                    self.server.scene.remove_by_name(f"/vehicles/{sysid}")
                    del self._drawn[sysid]
                for index, (_, vehicle) in enumerate(vehicles):
                    self._draw_vehicle(vehicle, COLOURS[index % len(COLOURS)], slow)
        self.server.flush()

    def _draw_vehicle(self, v: VehicleState, colour, slow: bool) -> None:
        scene = self.server.scene
        root = f"/vehicles/{v.sysid}"
        drawn = self._drawn.get(v.sysid)
        position = (v.x, v.y, self.fleet.height(v))
        if drawn is None:
            drawn = self._drawn[v.sysid] = {"version": -1, "map": None, "trail": 0, "path": None, "home": None}
            drawn["body"] = scene.add_frame(f"{root}/body", axes_length=0.8, axes_radius=0.04)
            scene.add_icosphere(f"{root}/body/hull", radius=0.3, color=colour)
            scene.add_box(f"{root}/body/nose", dimensions=(0.5, 0.08, 0.08), position=(0.45, 0.0, 0.0),
                          color=(255, 255, 255))
            drawn["label"] = scene.add_label(f"{root}/body/label", text=f"{v.sysid}", position=(0.0, 0.0, 0.8))
        drawn["body"].position = position
        drawn["body"].wxyz = _quaternion(v.roll, v.pitch, v.yaw)
        if not slow:
            return
        drawn["label"].text = f"{v.sysid} {v.kind} {v.mode}{' ARMED' if v.armed else ''}"
        self._draw_trail(v, root, colour, drawn)
        self._draw_sonar(v, root)
        self._draw_mission(v, root, drawn)
        self._draw_map(v, root, drawn, position[2])

    def _draw_trail(self, v: VehicleState, root: str, colour, drawn: dict) -> None:
        if len(v.trail) < 2 or len(v.trail) == drawn["trail"]:
            return
        points = np.array(v.trail, dtype=np.float32)
        segments = np.stack([points[:-1], points[1:]], axis=1)
        self.server.scene.add_line_segments(f"{root}/trail", segments, colors=colour, thickness=2.0,
                                            thickness_units="screen")
        drawn["trail"] = len(v.trail)

    def _draw_sonar(self, v: VehicleState, root: str) -> None:
        now = self.clock()
        rays = []
        for sonar in v.sonar.values():
            if now - sonar.time > 2.0:
                continue
            length = sonar.distance if sonar.distance is not None else min(sonar.max_range, 8.0)
            end = tuple(o + d * length for o, d in zip(sonar.origin, sonar.direction, strict=True))
            rays.append((sonar.origin, end))
        if rays:
            self.server.scene.add_line_segments(f"{root}/rays", np.array(rays, dtype=np.float32),
                                                colors=(255, 80, 80), thickness=1.5, thickness_units="screen")
        if v.hits:
            self.server.scene.add_point_cloud(f"{root}/hits", np.array(v.hits, dtype=np.float32),
                                              colors=(255, 60, 60), point_size=0.12)

    def _draw_mission(self, v: VehicleState, root: str, drawn: dict) -> None:
        scene = self.server.scene
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
                scene.add_line_segments(f"{root}/path", np.stack([points[:-1], points[1:]], axis=1),
                                        colors=(255, 230, 0), thickness=3.0, thickness_units="screen")
            else:
                scene.remove_by_name(f"{root}/path")
        if v.waypoints and drawn.get("waypoints") != v.waypoints:
            drawn["waypoints"] = list(v.waypoints)
            points = np.array([(x, y, height) for x, y in v.waypoints], dtype=np.float32)
            scene.add_point_cloud(f"{root}/waypoints", points, colors=(80, 200, 255), point_size=0.6)

    def _draw_map(self, v: VehicleState, root: str, drawn: dict, height: float) -> None:
        stream_version = (v.map_stream.version, v.own_map.version if v.own_map is not None else 0)
        if drawn["map"] == stream_version:
            return
        grid = v.map_grid()
        if grid is None:
            return
        drawn["map"] = stream_version
        values, resolution, origin = grid
        states = states_of(values)
        rows = np.flatnonzero(states.any(axis=1))
        cols = np.flatnonzero(states.any(axis=0))
        if not len(rows):
            return
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        part = states[r0:r1, c0:c1]
        step = max(1, int(math.ceil(max(part.shape) / MAP_PIXELS)))
        if step > 1:  # shrink, keeping obstacles visible: the max of each block
            h, w = (part.shape[0] // step) * step, (part.shape[1] // step) * step
            part = part[:h, :w].reshape(h // step, step, w // step, step).max(axis=(1, 3))
        image = state_image(part)
        width, depth = (c1 - c0) / resolution, (r1 - r0) / resolution
        centre = (origin[0] + (c0 + c1) / 2 / resolution, origin[1] + (r0 + r1) / 2 / resolution, height - 0.05)
        self.server.scene.add_image(f"{root}/map", image, render_width=width, render_height=depth,
                                    format="png", position=centre)


def _refuse_share(*args, **kwargs) -> None:
    """Replaces viser's share-tunnel request: this server is never exposed beyond the web app."""
    return None
