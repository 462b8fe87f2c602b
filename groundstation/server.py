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
import stat as file_mode
import sys
import threading
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import uvicorn

from groundstation.app import create_app
from groundstation.export import export_html
from groundstation.link import Link
from groundstation.mapview import MapPictures
from groundstation.proxy import VizProxy
from groundstation.recorder import Recorder
from groundstation.replay import Player, Replay, ReplayError, index_tlog
from groundstation.replay_scene import find_scene, logged_scene
from groundstation.security import Access, is_loopback
from groundstation.state import Fleet, VehicleState
from groundstation.timeline import Timeline
from groundstation.views import ViewRequestError
from groundstation.viz import SceneView
from vehicle.mapping.picture import draw_map
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mission import MissionItem
from vehicle.protocol.scene_note import note_text, scene_digest
from vehicle.protocol.waypoints import positions
from vehicle.world.bundled import scenes_dir
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene

log = logging.getLogger("groundstation")

RECORDINGS_STREAMED = 200  # the newest recordings the status stream lists
FAR_FROM_SCENE = 1000.0  # m outside the scene's edges: a vehicle there flies nowhere the scene shows


class GroundStation:
    def __init__(self, urls: list[str], scene: Scene | None = None, token: str | None = None,
                 record_dir: str | Path | None = "recordings", datum: Datum | None = None, viser_port: int = 0,
                 scene_dirs: Iterable[str | Path] = (), signing_key: bytes | None = None,
                 require_signing: bool = False):
        """``scene_dirs``: folders where replays look for the scenes their recordings name (besides the
        bundled scenes and the recording's own folder)."""
        self.token = token or secrets.token_urlsafe(16)
        self.access = Access(self.token)  # serving beyond loopback makes it stricter (see app_config)
        self.scene = scene
        self.scene_dirs = [Path(folder) for folder in scene_dirs]
        scene_file = scene.path if scene is not None and scene.path is not None and scene.path.is_file() else None
        self.scene_digest = scene_digest(scene_file) if scene_file else None  # recordings name the scene by it
        self.given_datum = datum
        ground = None
        if scene is not None:
            datum = Datum.of_scene(scene.hints, datum)
            if len(scene.faces):
                ground = RayCaster(scene).ground_height
        self.datum = datum  # None (no scene, none given): the first home heard becomes the origin
        self.live = Fleet(datum, ground)
        self.record_dir = Path(record_dir) if record_dir else None
        self.recorder = Recorder(record_dir, note_text(scene_file) if scene_file else None) \
            if record_dir and urls else None
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
        self.replay: Replay | None = None  # set while a recording is replayed
        self.timeline: Timeline | None = None  # the replayed log's whole history, scanned in the background
        self.pictures = MapPictures()  # the 2D map's
        self._recordings: tuple[float, list[dict]] = (-1e9, [])  # (when listed, the list) for the stream
        self._replay_world: tuple = (scene, self.datum, self.live.ground_height)  # its scene, datum, ground
        self._player: Player | None = None
        self._replay_lock = threading.Lock()
        self._durations: dict[Path, tuple[tuple, float | None]] = {}  # path -> (its size and time, duration)
        self._indexing: set[Path] = set()  # recordings the indexer has yet to read
        self._untold: set[str] = set()  # recordings not listed, their names no text: said once each
        self._indexer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recording-index")
        self._inboxes: dict[str | None, set[asyncio.Queue]] = {}  # viewer id -> its pages' /ws queues
        self._loop: asyncio.AbstractEventLoop | None = None

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
        self.stop_replay()
        if self.link is not None:
            self.link.close()
        self.view.close()
        self._close_recording()
        self._indexer.shutdown(wait=False, cancel_futures=True)

    def _close_recording(self) -> None:
        """Close the session's recording; one that holds no message but the scene's note (the station never ran:
        a port in use, a certificate that would not load) is removed, not left in the list as an empty session."""
        if self.recorder is None:
            return
        self.recorder.close()
        if not self.recorder.messages:
            self.recorder.path.unlink(missing_ok=True)

    # ---- what the app asks for -------------------------------------------------------------------
    def status(self) -> dict:
        replay = self.replay
        return {"type": "vehicles", "mode": self.mode, "time": self.now(), "vehicles": self.vehicles(),
                "replay": replay.status() if replay is not None else None, "recordings": self.recordings_now()}

    def recordings_now(self, every: float = 1.0) -> list[dict]:
        """The recordings as the stream shows them: listed again at most every ``every`` seconds."""
        listed, found = self._recordings
        if time.monotonic() - listed >= every:
            found = self.recordings()[:RECORDINGS_STREAMED]
            self._recordings = (time.monotonic(), found)
        return found

    # ---- recordings and replay -----------------------------------------------------------------------
    def recordings(self) -> list[dict]:
        """The recordings in the record folder, newest first: regular files only (never a pipe that would
        block a read, nor a folder), listed without reading them (see ``_duration``)."""
        if self.record_dir is None or not self.record_dir.is_dir():
            return []
        found = []
        for path in self.record_dir.glob("*.tlog"):
            if not _is_text(path.name):  # JSON cannot carry it, and no request could name it
                if path.name not in self._untold:
                    self._untold.add(path.name)
                    log.warning("the recording %r is not listed: its name is no UTF-8 text (rename it)", path.name)
                continue
            try:
                stat = path.stat()
            except OSError:  # gone since the listing
                continue
            if not file_mode.S_ISREG(stat.st_mode):
                continue
            recording = self.recorder is not None and path == self.recorder.path
            found.append({"name": path.name, "size": stat.st_size, "modified": stat.st_mtime,
                          "recording": recording,
                          "duration_s": self.recorder.duration if recording else self._duration(path, stat)})
        return sorted(found, key=lambda r: r["modified"], reverse=True)

    def _duration(self, path: Path, stat) -> float | None:
        """How long a recording lasts, from its index, kept while the file does not change; None until the
        indexer has read it. Indexing reads the whole file (a gigabyte takes some 20 s), and the status
        stream lists recordings on the event loop, so it is done in the background, one file at a time."""
        version = (stat.st_mtime, stat.st_size)
        known = self._durations.get(path)
        if known is not None and known[0] == version:
            return known[1]
        if path not in self._indexing:
            self._indexing.add(path)
            self._indexer.submit(self._index, path, version)
        return None

    def _index(self, path: Path, version: tuple) -> None:
        """On the indexer's thread: a failure is a recording without a duration (and a line in the log if it is
        no bad file but a bug), never a path left marked as being indexed, which would never be again."""
        try:
            duration = round(index_tlog(path, columns=False).duration, 1)
        except (ReplayError, OSError):
            duration = None
        except Exception:
            log.exception("could not index the recording %s", path.name)
            duration = None
        self._durations[path] = (version, duration)  # a file that changed meanwhile is indexed again
        self._indexing.discard(path)  # after: a listing between the two would index it once more

    def recording_path(self, name: str) -> Path | None:
        """The recording called ``name`` in the record folder (no paths, only .tlog files), or None."""
        if self.record_dir is None or Path(name).name != name or not name.endswith(".tlog"):
            return None
        path = self.record_dir / name
        try:
            return path if path.is_file() else None
        except OSError:  # a name too long for the file system, say
            return None

    def start_replay(self, path: Path) -> Replay:
        """Show a recording instead of the live vehicles (the live link goes on in the background), in the
        scene it names (see ``replay_scene``)."""
        with self._replay_lock:
            replay = Replay.open(path, Fleet(self.datum, self.live.ground_height))
            folders = [("the bundled scenes", scenes_dir()), ("the recording's folder", path.parent),
                       *((f"--scene-dir {folder}", folder) for folder in self.scene_dirs)]
            chosen = find_scene(logged_scene(replay), self.scene, self.scene_digest, folders)
            replay.scene = chosen.status
            world = self._world(chosen.scene)
            if chosen.scene is not self.scene:  # placed by that scene's datum, on its ground
                replay.fleet = Fleet(world[1], world[2])
                replay.seek(0.0)
            self._stop_player()
            self.replay = replay
            self._replay_world = world
            if self.view.scene is not chosen.scene:
                self.view.set_scene(chosen.scene)
            self._player = Player(replay).start()
            if self.timeline is not None:
                self.timeline.cancel()
            self.timeline = Timeline(replay)
            self.view.show(replay.fleet)
            replay.playing = True
            return replay

    def _world(self, scene: Scene | None) -> tuple:
        """(scene, datum, ground height) a replay in ``scene`` is shown with."""
        if scene is self.scene:
            return scene, self.datum, self.live.ground_height
        if scene is None:
            return None, self.given_datum, None
        try:
            datum = Datum.of_scene(scene.hints, self.given_datum)
        except ValueError:  # a broken datum hint: the default datum, as the simulator would refuse it
            datum = self.given_datum or Datum()
        return scene, datum, RayCaster(scene).ground_height if len(scene.faces) else None

    def stop_replay(self) -> None:
        with self._replay_lock:
            self._stop_player()
            if self.replay is not None:
                self.replay = None
                if self.timeline is not None:
                    self.timeline.cancel()
                self.timeline = None
                if self.view.scene is not self.scene:
                    self.view.set_scene(self.scene)
                self.view.show(self.live)

    def export_replay(self, replay: Replay) -> str:
        """The replay as one HTML file that plays offline (see ``export``), in the scene it is shown in."""
        scene, datum, ground = self._replay_world if replay is self.replay else (self.scene, self.datum,
                                                                                  self.live.ground_height)
        return export_html(replay.index.path, scene, datum, ground)

    def _stop_player(self) -> None:
        if self._player is not None:
            self._player.stop()
            self._player = None

    def map_picture(self, vehicle: VehicleState, grid: tuple) -> bytes:
        """A PNG of the vehicle's memory map ``grid`` (values, resolution, origin) for people, with its trail,
        home, planned path and waypoints (``vehicle.mapping.picture``)."""
        with self.fleet.lock:
            trail, path, waypoints = list(vehicle.trail), vehicle.planned_path(), list(vehicle.waypoints)
            home = vehicle.home
            position = (vehicle.x, vehicle.y) if vehicle.x is not None else None
            described = self.fleet.describe(vehicle, self.now())
        replay = self.replay
        scene = self._replay_world[0] if replay is not None else self.scene
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


def _is_text(name: str) -> bool:
    """A file name that is text: not one with bytes no encoding decodes (Python keeps them as surrogates)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


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
             + (f"; recording to {station.recorder.path}" if station.recorder else "") + ")")
    server.run(sockets=[listening])


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
