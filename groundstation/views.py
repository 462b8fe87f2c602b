"""What each viewer asked of its own 3D view: camera mode, selected vehicle, layers, map opacity, target.

The page sends these over its /ws socket, which already carries its viewer
id; nothing here moves any other viewer's camera. Everything a page sends is
hostile until checked: a request is a small JSON object of a known type with
known keys and bounded values, or it is refused with a fixed message (never
an echo of what was sent).
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass, field

MODES = ("orbit", "follow", "onboard", "top")
ACTIONS = ("fit", "vehicle")  # one-shot moves: fit the scene, go to the selected vehicle
LAYERS = ("scene", "map", "trails", "beams", "echoes", "waypoints", "paths")
OPACITIES = (1.0, 0.6, 0.3)  # the map's opacity steps (each one in use is drawn once, for all viewers)
MAX_REQUEST = 2048  # bytes: every request is a few dozen
MAX_ZOOM_STEPS = 20
MAX_COORDINATE = 1e6  # m: a target further out than this from the scene's origin is no place to send a vehicle


class ViewRequestError(ValueError):
    """A request the station refuses; its text is fixed, never built from the request."""


@dataclass
class Zoom:
    x: float  # where the cursor was, -1 (left) .. 1 (right)
    y: float  # -1 (bottom) .. 1 (top)
    steps: float  # > 0 closer, < 0 further


@dataclass
class ViewSettings:
    mode: str = "orbit"
    sysid: int | None = None  # the page's selected vehicle
    layers: dict[str, bool] = field(default_factory=lambda: dict.fromkeys(LAYERS, True))
    opacity: float = 1.0
    action: str | None = None  # a one-shot move not yet made
    zooms: list[Zoom] = field(default_factory=list)
    target: tuple[float, float] | None = None  # the Go here target the page holds, marked in this 3D view
    covered: tuple[float, float, float, float] | None = None  # the part of the view under the page's 2D map
    version: int = 0  # bumped on each change, so the 3D view applies what changed once


class Views:
    """Viewer id -> its settings, shared by the web app (writer) and the 3D view's thread (reader)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._views: dict[str, ViewSettings] = {}

    def get(self, viewer: str | None) -> ViewSettings | None:
        if viewer is None:
            return None
        with self._lock:
            return self._views.get(viewer)

    def forget(self, viewer: str) -> None:
        with self._lock:
            self._views.pop(viewer, None)

    def take_zooms(self, viewer: str) -> list[Zoom]:
        with self._lock:
            view = self._views.get(viewer)
            if view is None or not view.zooms:
                return []
            zooms, view.zooms = view.zooms, []
            return zooms

    def set_target(self, viewer: str, point: tuple[float, float] | None) -> None:
        """The ground this viewer clicked in its 3D view: marked at once, before its page has heard of it."""
        with self._lock:
            view = self._views.setdefault(viewer, ViewSettings())
            view.target = point
            view.version += 1

    def take_action(self, viewer: str) -> str | None:
        with self._lock:
            view = self._views.get(viewer)
            if view is None:
                return None
            action, view.action = view.action, None
            return action

    def apply(self, viewer: str, text: str | bytes) -> dict:
        """Apply one request from ``viewer``'s page; its answer for that page (raises ViewRequestError)."""
        request = parse(text)
        with self._lock:
            view = self._views.setdefault(viewer, ViewSettings())
            kind = request["type"]
            if kind == "camera":
                if "mode" in request:
                    view.mode = request["mode"]
                if "action" in request:  # a one-shot move leaves the camera free where it put it
                    view.action, view.mode = request["action"], "orbit"
            elif kind == "select":
                view.sysid = request["sysid"]
            elif kind == "layers":
                view.layers.update(request.get("layers", {}))
                if "opacity" in request:
                    view.opacity = request["opacity"]
            elif kind == "zoom":
                if len(view.zooms) < 32:  # a flood of wheel events is cut, not queued
                    view.zooms.append(Zoom(request["x"], request["y"], request["steps"]))
            elif kind == "target":
                view.target = request["point"]
            elif kind == "covered":
                view.covered = request["box"]
            view.version += 1
            return {"type": "view", "mode": view.mode, "sysid": view.sysid, "layers": dict(view.layers),
                    "opacity": view.opacity, "target": list(view.target) if view.target else None}


def parse(text: str | bytes) -> dict:
    """A checked request: exactly the keys its type allows, each of the right type and range."""
    if len(text) > MAX_REQUEST:
        raise ViewRequestError("request too large")
    try:
        request = json.loads(text)
    except (ValueError, UnicodeDecodeError):
        raise ViewRequestError("not JSON") from None
    if not isinstance(request, dict):
        raise ViewRequestError("a request is a JSON object")
    kind = request.get("type")
    allowed = {"camera": {"mode", "action"}, "select": {"sysid"}, "layers": {"layers", "opacity"},
               "zoom": {"x", "y", "steps"}, "target": {"x", "y"}, "covered": {"box"}}
    if not isinstance(kind, str) or kind not in allowed:
        raise ViewRequestError("unknown request type")
    if set(request) - {"type"} - allowed[kind]:
        raise ViewRequestError(f"unexpected field in a {kind} request")
    out: dict = {"type": kind}
    if kind == "camera":
        if "mode" in request:
            out["mode"] = _choice(request["mode"], MODES, "unknown camera mode")
        if "action" in request:
            out["action"] = _choice(request["action"], ACTIONS, "unknown camera action")
        if len(out) == 1:
            raise ViewRequestError("a camera request needs a mode or an action")
    elif kind == "select":
        sysid = request.get("sysid")
        if sysid is not None and not (_is_int(sysid) and 1 <= sysid <= 255):
            raise ViewRequestError("a system id is an integer from 1 to 255, or null")
        out["sysid"] = sysid
    elif kind == "layers":
        layers = request.get("layers", {})
        if not isinstance(layers, dict) or not set(layers) <= set(LAYERS) \
                or not all(isinstance(v, bool) for v in layers.values()):
            raise ViewRequestError(f"layers are {', '.join(LAYERS)}, each true or false")
        out["layers"] = dict(layers)
        if "opacity" in request:
            opacity = request["opacity"]
            if not _is_number(opacity) or not any(abs(opacity - o) < 1e-9 for o in OPACITIES):
                raise ViewRequestError(f"the map's opacity is one of {', '.join(str(o) for o in OPACITIES)}")
            out["opacity"] = float(opacity)
    elif kind == "target":  # the page's Go here target (x and y in metres), or none (both null): reached, dropped
        x, y = request.get("x"), request.get("y")
        if x is None and y is None:
            out["point"] = None
        elif all(_is_number(v) and abs(v) <= MAX_COORDINATE for v in (x, y)):
            out["point"] = (float(x), float(y))
        else:
            raise ViewRequestError(f"a target's x and y are numbers within {MAX_COORDINATE:g} m, or both null")
    elif kind == "covered":  # the box of the view the page's 2D map lies over (image coordinates), or null
        if "box" not in request:
            raise ViewRequestError("a covered request needs a box (or null)")
        box = request["box"]
        if box is None:
            out["box"] = None
        elif isinstance(box, list) and len(box) == 4 and all(_is_number(v) and -1.0 <= v <= 1.0 for v in box) \
                and box[0] < box[2] and box[1] < box[3]:
            out["box"] = tuple(float(v) for v in box)
        else:
            raise ViewRequestError("a covered box is [x0, y0, x1, y1] from -1 to 1, x0 < x1 and y0 < y1, or null")
    else:
        for key, low, high in (("x", -1.0, 1.0), ("y", -1.0, 1.0), ("steps", -MAX_ZOOM_STEPS, MAX_ZOOM_STEPS)):
            value = request.get(key)
            if not _is_number(value) or not low <= value <= high:
                raise ViewRequestError(f"zoom {key} is a number from {low:g} to {high:g}")
            out[key] = float(value)
    return out


def _choice(value, choices: tuple[str, ...], message: str) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ViewRequestError(f"{message} (one of {', '.join(choices)})")
    return value


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    """A finite int or float (JSON's integers have no bound: one past a float's range is no number here)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False
