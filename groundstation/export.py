"""A replay as one standalone HTML file that plays offline, made with viser's scene serializer.

The recording is played into a private 3D view (its own loopback viser
server, never served) while the serializer records every scene change with
the time between frames; viser then packs its client and the recording into
a single page with play, pause, scrub and speed controls.

The serializer keeps the 3D scene only (viser leaves its GUI panels out of
the file), so the telemetry panel goes into the scene: a label above each
vehicle, rewritten every frame, says what the page's panel says as of that
moment of the log (mode, armed, altitude, speed, battery, the onboard agent's
state and the latest message), with the log's clock. The radio tomography's
image lies on the ground as the live station showed it (``rti_live``: the
frame of the records up to then), imaged at most every RTI_EVERY s of the log.
"""

from __future__ import annotations

import math
import time
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

from groundstation import rti_view
from groundstation.replay import Replay
from groundstation.rti_live import LiveImager
from groundstation.state import Fleet
from groundstation.viz import SceneView
from vehicle.protocol.geodesy import Datum
from vehicle.world.scene import Scene

MAX_FRAMES = 600
MIN_FRAME = 0.25  # s of log time between frames
RTI_EVERY = 5.0  # s of log time between two radio tomography frames in the file (each costs a solve)
LABEL_HEIGHT = 1.4  # m above the vehicle
MESSAGE_CHARS = 60  # of the latest message shown


def export_html(path: str | Path, scene: Scene | None, datum: Datum | None, ground_height=None) -> str:
    fleet = Fleet(datum, ground_height)
    replay = Replay.open(path, fleet)
    view = SceneView(fleet, scene, clock=lambda: replay.now)
    try:
        serializer = view.server.get_scene_serializer()
        # no environment map in the file: viser hides the canvas until one is decoded, which in software WebGL
        # often never ends (the exported page stayed blank in one headless run of two); its lights remain, and an
        # even light stands in for the map's (without either, every wall facing away from the sun was black)
        view.server.scene.configure_environment_map(None)
        view.server.scene.add_light_ambient("/export/ambient", intensity=0.9)
        frame = max(MIN_FRAME, replay.duration / MAX_FRAMES)
        telemetry = TelemetryLabels(view, replay)
        imager = LiveImager(lambda: getattr(fleet, "radio", None))
        imager.listeners.append(lambda shown: rti_view.draw(view.server.scene, shown))
        view.draw()
        telemetry.draw()
        imaged = -math.inf
        while replay.clock < replay.duration:
            replay.advance(frame)
            view.draw()
            telemetry.draw()
            if replay.clock - imaged >= RTI_EVERY:
                imaged = replay.clock
                imager.step()
            serializer.insert_sleep(frame)
        return serializer.as_html(dark_mode=True)
    finally:
        view.close()


class TelemetryLabels:
    """A label per vehicle in a 3D view, with its telemetry as of the replay's clock."""

    def __init__(self, view: SceneView, replay: Replay):
        self.view = view
        self.replay = replay
        self.labels: dict[int, object] = {}  # sysid -> viser's label handle
        self.texts: dict[int, str] = {}

    def draw(self) -> None:
        fleet, scene = self.replay.fleet, self.view.server.scene
        with fleet.lock:
            now = self.replay.now
            shown = {v.sysid: (fleet.describe(v, now), fleet.height(v)) for v in fleet.vehicles.values()
                     if v.x is not None}
        clock = f"{time.strftime('%H:%M:%S', time.gmtime(now))} UTC, +{self.replay.clock:.1f} s"
        for sysid in set(self.labels) - set(shown):
            self.labels.pop(sysid).remove()
            self.texts.pop(sysid)
        for sysid, (described, height) in shown.items():
            text = telemetry_text(described, clock)
            position = (described["position"]["x"], described["position"]["y"], height + LABEL_HEIGHT)
            label = self.labels.get(sysid)
            if label is None:
                self.labels[sysid] = scene.add_label(f"/telemetry/{sysid}", text, position=position,
                                                     anchor="bottom-left", font_screen_scale=0.9)
            else:
                label.position = position
                if self.texts[sysid] != text:
                    label.text = text
            self.texts[sysid] = text


def telemetry_text(v: dict, clock: str) -> str:
    """The page's panel for one vehicle (``Fleet.describe``'s dict), as lines of text."""
    agent = v["agent"]
    position = v["position"]
    lines = [
        f"{v['sysid']} {v['type']}  {v['mode']}  {'ARMED' if v['armed'] else 'disarmed'}",
        f"alt {_number(position['alt'])} m  {_number(v['speed'])} m/s  heading {_number(v['heading'], 0)}°",
        f"battery {battery_text(v['battery'])}",
    ]
    if agent is not None:
        why = f" ({agent['reason']})" if agent["reason"] and agent["state"] != "RUNNING" else ""
        lines.append(f"agent {agent['state'].upper()} {agent['mission'] or ''}".rstrip() + why)
    if v["status"]:
        message = v["status"]
        lines.append(message if len(message) <= MESSAGE_CHARS else message[:MESSAGE_CHARS - 1] + "…")
    lines.append(clock)
    return "\n".join(lines)


def battery_text(battery: dict | None) -> str:
    """A battery as the page says it (``batteryText`` in ``static/common.js``, and a test holds the two to the
    same text): "12.3 V, 87 %", the voltage rounded as JavaScript's ``toFixed(1)``, the percentage left out when
    unknown (MAVLink's -1, or None)."""
    if not battery:
        return "–"
    parts = []
    voltage, remaining = battery.get("voltage"), battery.get("remaining")
    if _finite(voltage):
        parts.append(f"{_fixed(voltage)} V")
    if _finite(remaining) and remaining >= 0:
        parts.append(f"{math.floor(remaining + 0.5)} %")  # Math.round
    return ", ".join(parts) or "–"


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _fixed(value: float, digits: int = 1) -> str:
    """JavaScript's ``toFixed`` (halves of the exact value away from zero), never "-0.0": the page's ``fmt``."""
    text = str(Decimal(value).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))
    return text.lstrip("-") if Decimal(text) == 0 else text


def _number(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
