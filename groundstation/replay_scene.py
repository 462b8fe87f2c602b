"""The scene a replay is shown in: the one its log names, found by file name and checked by its hash.

Logs name their scene (``vehicle.protocol.scene_note``). To replay one, the
station looks for a file of that name whose SHA-256 matches: its own scene
first, then the bundled scenes, the recording's folder and every folder given
with ``--scene-dir``. A log is hostile input, so only a bare file name ever
comes from it (``read_note`` refuses anything else) and only those folders are
looked in; big files are not even hashed. When the file is missing or differs,
the replay says so in its status (``scene``), for the page to show: a file of
that name that differs is not shown, unless it is the station's own scene
(which the operator chose, and which the live view shows anyway); a log that
names no scene (one from MAVProxy, say) is shown in the station's own.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundstation.replay import STATUSTEXT, Replay
from vehicle.protocol.scene_note import read_note, scene_digest
from vehicle.protocol.statustext import Reassembler
from vehicle.world.scene import Scene, SceneError, load_scene

MAX_TEXTS = 5000  # STATUSTEXT records read for the note (a log has one in its first minute, and every minute)
MAX_SCENE_BYTES = 256 << 20  # a file bigger than this is not hashed (no scene we show comes near it)


@dataclass
class ReplayScene:
    scene: Scene | None  # what the 3D view shows during the replay
    status: dict  # name, sha256, found, shown, note: for the replay's status


def logged_scene(replay: Replay) -> tuple[str, str] | None:
    """(file name, digest) of the first scene note in the log, or None."""
    texts = Reassembler()
    for i in np.flatnonzero(replay.index.msgids == STATUSTEXT)[:MAX_TEXTS]:
        message = replay.decode(int(i))
        if message is None or message.get_type() != "STATUSTEXT":
            continue
        for _, text in texts.feed(message, float(replay.index.times[i])):
            note = read_note(text)
            if note is not None:
                return note
    return None


def find_scene(note: tuple[str, str] | None, own: Scene | None, own_digest: str | None,
               folders: list[tuple[str, Path]]) -> ReplayScene:
    """The scene to show for a log's ``note``: ``own`` is the station's scene (its file's digest
    ``own_digest``), ``folders`` (what to call it, folder) where else to look, in order."""
    own_name = own.path.name if own is not None and own.path is not None else None
    if note is None:
        shown = f"; shown in the station's scene, {own_name}" if own is not None else ""
        return ReplayScene(own, _status(None, None, False, own, "the recording names no scene" + shown))
    name, digest = note
    if own is not None and own_digest == digest:
        return ReplayScene(own, _status(name, digest, True, own, f"{name}: the station's own scene"))
    differing, broken = [], []
    for where, folder in folders:
        path = folder / name
        try:
            if not path.is_file() or path.stat().st_size > MAX_SCENE_BYTES or scene_digest(path) != digest:
                differing += [where] if path.is_file() else []
                continue
            scene = load_scene(path)
        except (OSError, SceneError) as error:
            broken.append(f"{where}: {error}")
            continue
        return ReplayScene(scene, _status(name, digest, True, scene, f"{name} found in {where}"))
    if own_name == name:
        return ReplayScene(own, _status(name, digest, False, own, f"the station's own {name} is not the "
                                        f"recorded one (sha256 {own_digest}, recorded {digest}); shown anyway"))
    if differing:
        why = f"{name} in {', '.join(differing)} is not the recorded one (sha256 {digest}); not shown"
    else:
        looked = ", ".join(where for where, _ in folders)
        why = f"{name} (sha256 {digest}) was not found in {looked}; give its folder with --scene-dir"
    if broken:
        why += "; could not read " + "; ".join(broken)
    return ReplayScene(None, _status(name, digest, False, None, why))


def _status(name: str | None, digest: str | None, found: bool, shown: Scene | None, note: str) -> dict:
    shown_name = None if shown is None else shown.path.name if shown.path is not None else "(unnamed)"
    return {"name": name, "sha256": digest, "found": found, "shown": shown_name, "note": note}
