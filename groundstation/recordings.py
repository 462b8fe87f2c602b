"""The record folder and the replay of one recording: which recordings there are (listed without reading them,
their durations indexed in the background) and a replay's lifecycle (its scene and world, its player, its
timeline, back to live).

``GroundStation`` holds one ``RecordingIndex`` and one ``Replays``; the API's
recordings area uses both.
"""

from __future__ import annotations

import logging
import stat as file_mode
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from groundstation.export import export_html
from groundstation.replay import Player, Replay, ReplayError, index_tlog
from groundstation.replay_scene import find_scene, logged_scene
from groundstation.state import Fleet
from groundstation.timeline import Timeline
from groundstation.viz import SceneView
from vehicle.protocol.geodesy import Datum
from vehicle.world.bundled import scenes_dir
from vehicle.world.raycast import RayCaster
from vehicle.world.scene import Scene

log = logging.getLogger("groundstation")

RECORDINGS_STREAMED = 200  # the newest recordings the status stream lists


class RecordingIndex:
    """The .tlog files of the record folder, newest first, each with its size and duration."""

    def __init__(self, folder: Path | None, being_recorded: Callable[[], object]):
        """``being_recorded``: the station's recorder now (None for none), whose file is the session's."""
        self.folder = folder
        self._being_recorded = being_recorded
        self._listed: tuple[float, list[dict]] = (-1e9, [])  # (when listed, the list) for the stream
        self._durations: dict[Path, tuple[tuple, float | None]] = {}  # path -> (its size and time, duration)
        self._indexing: set[Path] = set()  # recordings the indexer has yet to read
        self._untold: set[str] = set()  # recordings not listed, their names no text: said once each
        self._indexer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recording-index")

    def close(self) -> None:
        self._indexer.shutdown(wait=False, cancel_futures=True)

    def listing(self) -> list[dict]:
        """The recordings in the record folder, newest first: regular files only (never a pipe that would
        block a read, nor a folder), listed without reading them (see ``_duration``)."""
        if self.folder is None or not self.folder.is_dir():
            return []
        recorder = self._being_recorded()
        found = []
        for path in self.folder.glob("*.tlog"):
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
            recording = recorder is not None and path == recorder.path
            found.append({"name": path.name, "size": stat.st_size, "modified": stat.st_mtime,
                          "recording": recording,
                          "duration_s": recorder.duration if recording else self._duration(path, stat)})
        return sorted(found, key=lambda r: r["modified"], reverse=True)

    def latest(self, every: float = 1.0) -> list[dict]:
        """The recordings as the stream shows them: listed again at most every ``every`` seconds."""
        listed, found = self._listed
        if time.monotonic() - listed >= every:
            found = self.listing()[:RECORDINGS_STREAMED]
            self._listed = (time.monotonic(), found)
        return found

    def path(self, name: str) -> Path | None:
        """The recording called ``name`` in the record folder (no paths, only .tlog files), or None."""
        if self.folder is None or Path(name).name != name or not name.endswith(".tlog"):
            return None
        path = self.folder / name
        try:
            return path if path.is_file() else None
        except OSError:  # a name too long for the file system, say
            return None

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


class Replays:
    """One recording replayed at a time in the station's view, in the scene it names, instead of the live fleet
    (which goes on in the background)."""

    def __init__(self, view: SceneView, live: Fleet, scene: Scene | None, scene_digest: str | None,
                 datum: Datum | None, given_datum: Datum | None, scene_dirs: Iterable[Path]):
        self.view, self.live = view, live
        self.scene, self.scene_digest = scene, scene_digest
        self.datum, self.given_datum = datum, given_datum
        self.scene_dirs = list(scene_dirs)
        self.replay: Replay | None = None  # set while a recording is replayed
        self.timeline: Timeline | None = None  # the replayed log's whole history, scanned in the background
        self.world: tuple = (scene, datum, live.ground_height)  # the replay's scene, datum and ground
        self._player: Player | None = None
        self._lock = threading.Lock()

    def start(self, path: Path) -> Replay:
        """Show a recording instead of the live vehicles, in the scene it names (see ``replay_scene``)."""
        with self._lock:
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
            self.world = world
            if self.view.scene is not chosen.scene:
                self.view.set_scene(chosen.scene)
            self._player = Player(replay).start()
            if self.timeline is not None:
                self.timeline.cancel()
            self.timeline = Timeline(replay)
            self.view.show(replay.fleet)
            replay.playing = True
            return replay

    def stop(self) -> None:
        """Back to the live vehicles, in the station's own scene."""
        with self._lock:
            self._stop_player()
            if self.replay is not None:
                self.replay = None
                if self.timeline is not None:
                    self.timeline.cancel()
                self.timeline = None
                if self.view.scene is not self.scene:
                    self.view.set_scene(self.scene)
                self.view.show(self.live)

    def export(self, replay: Replay) -> str:
        """The replay as one HTML file that plays offline (see ``export``), in the scene it is shown in."""
        scene, datum, ground = self.world if replay is self.replay else (self.scene, self.datum,
                                                                         self.live.ground_height)
        return export_html(replay.index.path, scene, datum, ground)

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

    def _stop_player(self) -> None:
        if self._player is not None:
            self._player.stop()
            self._player = None


def _is_text(name: str) -> bool:
    """A file name that is text: not one with bytes no encoding decodes (Python keeps them as surrogates)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True
