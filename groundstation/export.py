"""A replay as one standalone HTML file that plays offline, made with viser's scene serializer.

The recording is played into a private 3D view (its own loopback viser
server, never served) while the serializer records every scene change with
the time between frames; viser then packs its client and the recording into
a single page with play, pause, scrub and speed controls.
"""

from __future__ import annotations

from pathlib import Path

from groundstation.replay import Replay
from groundstation.state import Fleet
from groundstation.viz import SceneView
from vehicle.protocol.geodesy import Datum
from vehicle.world.scene import Scene

MAX_FRAMES = 600
MIN_FRAME = 0.25  # s of log time between frames


def export_html(path: str | Path, scene: Scene | None, datum: Datum | None, ground_height=None) -> str:
    fleet = Fleet(datum, ground_height)
    replay = Replay.open(path, fleet)
    view = SceneView(fleet, scene, clock=lambda: replay.now)
    try:
        serializer = view.server.get_scene_serializer()
        frame = max(MIN_FRAME, replay.duration / MAX_FRAMES)
        view.draw()
        while replay.clock < replay.duration:
            replay.advance(frame)
            view.draw()
            serializer.insert_sleep(frame)
        return serializer.as_html(dark_mode=True)
    finally:
        view.close()
