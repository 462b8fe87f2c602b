"""A recording's radio link records as the reconstruction's LINKS.csv (``groundstation rti export``).

The records are read the way the station reads them, live and in replay: the log is replayed into a ``Fleet``
(each vehicle's ``LinkReceiver``, its home, the scene's datum) to its end, and ``fleet.radio`` is written out. So
the command line images what the page imaged from the same flight. Positions are in the scene frame: the datum is
the one of the scene given, else of the scene the recording names (looked up beside the bundled scenes), else the
``--datum`` given, else the first vehicle's home is the origin, as at a station without a scene.
"""

from __future__ import annotations

import csv
from pathlib import Path

from groundstation.replay import Replay
from groundstation.replay_scene import find_scene, logged_scene
from groundstation.state import Fleet
from vehicle.protocol.geodesy import Datum
from vehicle.tomography.links import COLUMNS
from vehicle.world.bundled import default_scene


def export_links(tlog: str | Path, out: str | Path, scene=None, datum: Datum | None = None) -> tuple[int, str]:
    """Write ``tlog``'s link records to the CSV ``out`` (time order); returns (records written, where the frame
    came from)."""
    replay = Replay.open(tlog, Fleet(None, own_maps=False))
    if scene is None:
        scene = find_scene(logged_scene(replay), None, None, [("the bundled scenes", default_scene().parent)]).scene
    frame = f"the scene {scene.path.name}" if scene is not None and scene.path is not None else (
        "the datum given" if datum is not None else "the first vehicle's home as the origin")
    replay.fleet = Fleet(Datum.of_scene(scene.hints, datum) if scene is not None else datum, own_maps=False,
                         forget_after=None)
    replay.seek(replay.duration)
    records = sorted(replay.fleet.radio.snapshot(), key=lambda r: r.t)
    with open(out, "w", newline="", encoding="utf-8") as file:
        writer = csv.writer(file)
        writer.writerow(COLUMNS)
        for r in records:
            writer.writerow([f"{r.t:.6f}", r.tx, r.rx, f"{r.tx_x:.3f}", f"{r.tx_y:.3f}", f"{r.rx_x:.3f}",
                             f"{r.rx_y:.3f}", f"{r.rssi:g}", r.channel])
    return len(records), frame
