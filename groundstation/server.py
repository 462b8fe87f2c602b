"""The ground station assembled: fleet state, MAVLink link, recorder, 3D view, web app; and how it is served.

``GroundStation`` owns the parts and what the app's handlers need from them
(the operator token, the live/replay switch, the viewers' inboxes);
``serve`` runs it under uvicorn and prints the page's address with the token.
"""

from __future__ import annotations

import asyncio
import logging
import math
import secrets
import socket
import ssl
import sys
import time
from collections.abc import Iterable
from pathlib import Path

import uvicorn

from groundstation.app import create_app
from groundstation.link import Link
from groundstation.mapview import MapPictures
from groundstation.mission_left import route_of
from groundstation.proxy import VizProxy
from groundstation.recorder import Limits, Recorder
from groundstation.recordings import RecordingIndex, Replays
from groundstation.security import Access, is_loopback
from groundstation.state import Fleet, VehicleState
from groundstation.views import ViewRequestError
from groundstation.viz import SceneView
from vehicle.mapping.picture import draw_map
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import MissionItem
from vehicle.protocol.scene_note import note_text, scene_digest
from vehicle.protocol.waypoints import positions
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene

log = logging.getLogger("groundstation")

FAR_FROM_SCENE = 1000.0  # m outside the scene's edges: a vehicle there flies nowhere the scene shows


class GroundStation:
    def __init__(self, urls: list[str], scene: Scene | None = None, token: str | None = None,
                 record_dir: str | Path | None = "recordings", datum: Datum | None = None, viser_port: int = 0,
                 scene_dirs: Iterable[str | Path] = (), signing_key: bytes | None = None,
                 require_signing: bool = False, record_limits: Limits | None = None):
        """``scene_dirs``: folders where replays look for the scenes their recordings name (besides the
        bundled scenes and the recording's own folder); ``record_limits``: how much is recorded, and when a
        recording is closed for the next (``recorder.Limits``)."""
        self.token = token or secrets.token_urlsafe(16)
        self.access = Access(self.token)  # serving beyond loopback makes it stricter (see app_config)
        self.scene = scene
        self.scene_dirs = [Path(folder) for folder in scene_dirs]
        scene_file = scene.path if scene is not None and scene.path is not None and scene.path.is_file() else None
        self.scene_digest = scene_digest(scene_file) if scene_file else None  # recordings name the scene by it
        datum_given = datum
        ground = None
        if scene is not None:
            datum = Datum.of_scene(scene.hints, datum)
            if len(scene.faces):
                ground = RayCaster(scene).ground_height
        self.datum = datum  # None (no scene, none given): the first home heard becomes the origin
        self.live = Fleet(datum, ground)
        self.vehicles_started: float | None = None  # when this station started its own vehicles (the demo)
        self.first_heard_after: float | None = None  # s from then until the first of them was heard
        self.record_dir = Path(record_dir) if record_dir else None
        self.recorder = Recorder(record_dir, note_text(scene_file) if scene_file else None, record_limits or Limits(),
                                 known=lambda sysid: sysid in self.live.vehicles) if record_dir and urls else None
        self.link_urls = list(urls)
        try:
            self.link = Link(urls, self.live, self.recorder, signing_key=signing_key,
                             require_signing=require_signing) if urls else None
        except BaseException:  # a link that cannot open: no station, and no empty recording left behind
            self._close_recording()
            raise
        self.view = SceneView(self.live, scene, viser_port, clock=self.now)
        self.proxy = VizProxy(self.view.port)
        self.view.on_target(self._target)
        self.view.viewer_of = self.proxy.viewers.get  # which page each viser client is
        self.recordings = RecordingIndex(self.record_dir, lambda: self.recorder)
        self.replays = Replays(self.view, self.live, scene, self.scene_digest, self.datum, datum_given,
                               self.scene_dirs)
        self.pictures = MapPictures()  # the 2D map's
        self._inboxes: dict[str | None, set[asyncio.Queue]] = {}  # viewer id -> its pages' /ws queues
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def replay(self):
        """The recording replayed now (``groundstation.replay.Replay``), or None: live."""
        return self.replays.replay

    @property
    def timeline(self):
        """The replayed log's whole history (``groundstation.timeline.Timeline``), scanned in the background."""
        return self.replays.timeline

    @property
    def mode(self) -> str:
        return "replay" if self.replay is not None else "live"

    @property
    def fleet(self) -> Fleet:
        """The fleet the page and the API show: the live one, or the replayed one."""
        replay = self.replay
        return replay.fleet if replay is not None else self.live

    def now(self) -> float:
        """The clock link ages are measured on: the wall, or the replayed log's own."""
        replay = self.replay
        return replay.now if replay is not None else time.time()

    def vehicles(self, sysid: int | None = None) -> list[dict]:
        """The vehicles described as of one moment: a replay cannot step between reading its clock and
        its fleet, or heartbeat ages would come out of a different moment than the messages."""
        replay = self.replay
        if replay is None:
            return self._describe(self.live, time.time(), sysid)
        with replay.lock:
            return self._describe(replay.fleet, replay.now, sysid)

    @staticmethod
    def _describe(fleet: Fleet, now: float, sysid: int | None) -> list[dict]:
        with fleet.lock:
            chosen = [fleet.vehicles[sysid]] if sysid in fleet.vehicles else [] if sysid is not None else \
                [v for _, v in sorted(fleet.vehicles.items())]
            return [fleet.describe(v, now) for v in chosen]

    def far_from_scene(self) -> list[dict]:
        """The vehicles more than FAR_FROM_SCENE outside the scene shown, and how far (km). The usual cause is a
        datum (the station's ``--datum``, or the scene's) that is not where the vehicles fly: each is then drawn
        thousands of kilometres away, and the 3D view shows the scene alone, as if nothing were wrong."""
        scene = self.view.scene
        if scene is None or not len(scene.faces):
            return []
        (x0, y0, _), (x1, y1, _) = scene.bounds
        replay = self.replay
        fleet = self.live if replay is None else replay.fleet
        with fleet.lock:
            places = [(v.sysid, v.x, v.y) for _, v in sorted(fleet.vehicles.items()) if v.x is not None]
        far = []
        for sysid, x, y in places:
            gap = math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))
            if gap > FAR_FROM_SCENE:
                far.append({"sysid": sysid, "km": round(gap / 1000.0, 1)})
        return far

    def start(self) -> None:
        if self.link is not None:
            self.link.start()
        self.view.start()

    def close(self) -> None:
        self.replays.stop()
        if self.link is not None:
            self.link.close()
        self.view.close()
        self._close_recording()
        self.recordings.close()

    def _close_recording(self) -> None:
        """Close the session's recording; one that holds no message but the scene's note (the station never ran:
        a port in use, a certificate that would not load) is removed, not left in the list as an empty session."""
        if self.recorder is None:
            return
        self.recorder.close()
        if self.recorder.path is not None and not self.recorder.messages:
            self.recorder.path.unlink(missing_ok=True)

    # ---- what the app asks for -------------------------------------------------------------------
    def status(self) -> dict:
        replay = self.replay
        return {"type": "vehicles", "mode": self.mode, "time": self.now(), "vehicles": self.vehicles(),
                "replay": replay.status() if replay is not None else None, "recordings": self.recordings.latest(),
                "starting": self.starting()}

    def expect_vehicles(self) -> None:
        """This station started its vehicles (the demo): the page says they are starting until the first is
        heard, and then how long it took. The first start after an install compiles the simulator's loops for
        some 15 s, and the page said only "No vehicles yet"."""
        self.vehicles_started = time.time()

    def starting(self) -> dict | None:
        """``since``: s since the vehicles were started; ``took``: s until the first was heard (None before)."""
        if self.vehicles_started is None:
            return None
        now = time.time()
        if self.first_heard_after is None and self.live.vehicles:
            self.first_heard_after = now - self.vehicles_started
        took = self.first_heard_after
        return {"since": round(now - self.vehicles_started, 1), "took": None if took is None else round(took, 1)}

    def map_picture(self, vehicle: VehicleState, grid: tuple) -> bytes:
        """A PNG of the vehicle's memory map ``grid`` (values, resolution, origin) for people, with its trail,
        home, planned path and waypoints (``vehicle.mapping.picture``)."""
        with self.fleet.lock:
            trail, path, waypoints = list(vehicle.trail), vehicle.planned_path(), list(vehicle.waypoints)
            home = vehicle.home
            position = (vehicle.x, vehicle.y) if vehicle.x is not None else None
            described = self.fleet.describe(vehicle, self.now())
        replay = self.replay
        scene = self.replays.world[0] if replay is not None else self.scene
        agent = described["agent"]
        title = (f"vehicle {vehicle.sysid} ({vehicle.kind})" + (f", {agent['mission']} mission" if agent else "")
                 + (f" in {scene.path.name}" if scene is not None and scene.path is not None else "")
                 + f": {vehicle.mode}" + (f", agent {agent['state'].upper()}" if agent else ""))
        when = f"replay of {replay.name} at +{replay.clock:.1f} s" if replay is not None else \
            time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
        subtitle = f"{described['map']['occupied']} occupied cells, map from the {vehicle.map_source}, {when}"
        values, resolution, origin = grid
        return draw_map(values, resolution, origin, f"{title}\n{subtitle}", home, trail, path, waypoints,
                        position).png()

    def note_waypoints(self, sysid: int, items: list[MissionItem]) -> None:
        vehicle = self.fleet.get(sysid)
        if vehicle is not None and self.fleet.datum is not None:
            vehicle.waypoints = positions(items, self.fleet.datum)
            vehicle.route = route_of(items, self.fleet.datum)

    @property
    def streams(self) -> int:
        """/ws connections open now."""
        return sum(len(inboxes) for inboxes in self._inboxes.values())

    def subscribe(self, viewer: str | None) -> asyncio.Queue:
        self._loop = asyncio.get_running_loop()
        inbox: asyncio.Queue = asyncio.Queue(maxsize=100)
        self._inboxes.setdefault(viewer, set()).add(inbox)
        return inbox

    def unsubscribe(self, viewer: str | None, inbox: asyncio.Queue) -> None:
        inboxes = self._inboxes.get(viewer)
        if inboxes is not None:
            inboxes.discard(inbox)
            if not inboxes:  # a page that went leaves nothing behind
                del self._inboxes[viewer]
                if viewer is not None:
                    self.view.views.forget(viewer)

    def view_request(self, viewer: str | None, text: str | bytes, inbox: asyncio.Queue) -> None:
        """A page's request for its own 3D view; the answer (its settings now, or why not) goes to that page."""
        if viewer is None:
            note = {"type": "view-error", "detail": "this stream has no viewer id: open it with ?viewer=ID"}
        else:
            try:
                note = self.view.views.apply(viewer, text)
            except ViewRequestError as error:
                note = {"type": "view-error", "detail": str(error)}
        _offer(inbox, note)

    def _target(self, client_id: int, x: float, y: float) -> None:
        """A viewer clicked the ground (called from viser's thread): tell that viewer's page."""
        viewer = self.proxy.viewers.get(client_id)
        if viewer is None or self._loop is None:
            return
        note = {"type": "target", "x": round(x, 2), "y": round(y, 2)}
        for inbox in list(self._inboxes.get(viewer, ())):
            self._loop.call_soon_threadsafe(_offer, inbox, note)


def _offer(inbox: asyncio.Queue, note: dict) -> None:
    if not inbox.full():
        inbox.put_nowait(note)


WS_MAX_SIZE = 1 << 20  # bytes a browser may send in one websocket message (camera moves and clicks are small)
MAX_CONNECTIONS = 1000  # HTTP connections and websockets at once; beyond, uvicorn answers 503


def app_config(station: GroundStation, host: str = "127.0.0.1", port: int = 8000, tls_cert: str | None = None,
               tls_key: str | None = None, viewer_token: str | None = None,
               allowed_hosts: tuple[str, ...] = (), access: Access | None = None) -> uvicorn.Config:
    """The web app as uvicorn serves it, with who may reach it set for ``host`` unless ``access`` says
    (tests use this too)."""
    if bool(tls_cert) != bool(tls_key):
        raise ValueError("--tls-cert and --tls-key go together")
    if tls_cert:  # uvicorn loads them only once it runs, after the address was announced, and names neither
        try:
            ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(tls_cert, tls_key)
        except (OSError, ssl.SSLError) as error:
            raise ValueError(f"cannot serve HTTPS with --tls-cert {tls_cert} and --tls-key {tls_key}: "
                             f"{error.strerror or error}") from None
    station.access = access or Access.for_host(host, station.token, viewer_token, allowed_hosts)
    return uvicorn.Config(create_app(station), host=host, port=port, log_level="warning", ssl_certfile=tls_cert,
                          ssl_keyfile=tls_key, ws_ping_interval=None, ws_max_size=WS_MAX_SIZE,
                          limit_concurrency=MAX_CONNECTIONS)


def serve(station: GroundStation, host: str = "127.0.0.1", port: int = 8000, tls_cert: str | None = None,
          tls_key: str | None = None, announce=print, viewer_token: str | None = None,
          allowed_hosts: tuple[str, ...] = ()) -> None:
    """Run the web app until interrupted (blocking); the station is closed when it returns, or fails to start."""
    try:
        _run_app(station, host, port, tls_cert, tls_key, announce, viewer_token, allowed_hosts)
    finally:
        station.close()
    time.sleep(0)


def _run_app(station, host, port, tls_cert, tls_key, announce, viewer_token, allowed_hosts) -> None:
    config = app_config(station, host, port, tls_cert, tls_key, viewer_token, allowed_hosts)
    scheme = "https" if tls_cert else "http"
    if not is_loopback(host):
        if not tls_cert:
            print(f"WARNING: serving on {host} without TLS: the operator token and commands cross the network "
                  "in clear text. Give --tls-cert and --tls-key, or bind to 127.0.0.1.", file=sys.stderr, flush=True)
        print("Serving beyond loopback: watching needs the operator token"
              + (" or the viewer token" if viewer_token else " (give --viewer-token for read-only viewers)")
              + "; host names other than IP addresses and localhost need --allowed-host.", file=sys.stderr,
              flush=True)
    server = uvicorn.Server(config)
    listening = _listening_socket(host, port)  # before anything starts or is announced: a port in use is an error
    station.start()
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    if ":" in shown:
        shown = f"[{shown}]"  # an IPv6 address in a URL
    links = ", ".join(station.link_urls) or "no MAVLink links"
    announce(f"ground station: {scheme}://{shown}:{port}/#token={station.token}  (operator token {station.token}; "
             f"listening to {links}"
             + (f"; {_recording(station.recorder)}" if station.recorder else "") + ")")
    server.run(sockets=[listening])


def _recording(recorder: Recorder) -> str:
    return f"recording to {recorder.path}" if recorder.path is not None else recorder.refused


def _listening_socket(host: str, port: int) -> socket.socket:
    """The web app's socket, bound and listening now, so that a port in use is a clear error before the page's
    address is announced (uvicorn binds later, after the announcement, and only logs the failure), and so that
    the address works from the moment it shows."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    listening = socket.socket(family, socket.SOCK_STREAM)
    listening.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # TCP: rebinding past TIME_WAIT only
    try:
        listening.bind((host, port))
    except OSError as error:
        listening.close()
        raise OSError(error.errno, f"cannot serve on {host}:{port}: {error.strerror}") from None
    listening.listen(2048)  # uvicorn's backlog: a page opened as soon as the address shows waits, not refused
    return listening
