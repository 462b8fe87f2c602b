"""The station's live radio tomography: one image per window of the fleet's link records, in a thread of its own.

A frame is a pure function of the records: the frame at window boundary T (a multiple of ``window`` s of the
records' own clock) images, of every path heard in the last ``FORGET`` s before T, its records of the last
``history`` s in which it was heard (``vehicle.tomography.reconstruct``: one image over them all of each path's
attenuation below the level a path-loss model fitted across the links predicts for it, so a team's dwells build
the image up). A fixed network's paths are heard all along, so its image slides with the last ``history`` s; a
team's pair of spots is heard only while it dwells there, and stays in the image for ``FORGET`` s after, so the
image of a mission outlives the mission (the landed team's one link at home does not replace it). Links heard
fewer than ``MIN_HEARD`` times are left out (a radio in motion makes a new link with every packet: each says
little and all of them grow the solve).
The live thread images the newest complete window whenever the log grows past a boundary; a solve slower than a
window skips the windows that closed meanwhile, it never queues them. In replay the log is the replayed one,
rebuilt by a seek, so the frame at any time is the one the live station showed then. The thread reads only the
link log (its own lock), never the fleet's lock or the status stream.
"""

from __future__ import annotations

import base64
import io
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from PIL import Image

from vehicle.tomography.imaging import STANDING, reconstruct
from vehicle.tomography.links import KEY_STEP, Records, factorize, link_keys, records_of
from vehicle.tomography.picture import STOPS, colours

WINDOW = 1.0  # s of the records' clock per frame
HISTORY = 300.0  # s of a path's records imaged, back from when it was last heard: a fixed network's image slides
# with it (a person standing for most of it starts to fade into the paths' own levels)
FORGET = 900.0  # s after which a path no longer heard leaves the image: a team's mission (40 pairs of spots, 3 s
# dwells) measures each pair once, so its image needs every pair of the mission; with the last 60 s of records (10
# to 16 paths) the demo's peak jumped 2 to 8 m off a standing target between frames, and once the team landed its
# one link at home was all the image had left
CELL = 0.25  # m: the image's pixel (the experiments' choice: half the 0.5 m a target must be found within)
PEAKS = 3
EMPTY_FROM = "brief"  # a link heard only briefly gets the level a path-loss model fitted across the links predicts:
# the station has no empty-area capture, and radios on vehicles measure a pair of spots only while they stand
# there, so such a link's own level is the obstructed one (against it, the peak was 2 to 7 m off a standing
# target); links heard all along (fixed nodes) keep their own robust level
MIN_HEARD = 3  # packets a link needs in the history to be imaged
PER_LINK = 100  # records of one link imaged at most, evenly spread over the history: a fixed network heard all
# along would otherwise cost a frame in proportion to the history (16 radios on 4 channels: 2.6 s for 300 s), and
# a link's mean over 100 packets is within a tenth of its noise of the mean over all
POLL = 0.02  # s between two looks at the log's size (an arrival is noticed within this)
ARRIVALS = 500  # arrival times remembered (10 s of polls)


@dataclass
class Frame:
    """One image and what the page shows beside it."""

    t: float  # the window's end (records' clock, s)
    bounds: tuple[float, float, float, float]
    image: np.ndarray  # (ny, nx), row 0 the south edge
    peaks: list[dict]
    links: list[list[float]]  # the last window's paths: [x0, y0, x1, y1]
    links_per_s: float
    coverage: float  # share of pixels that a path of the image crosses
    paths: int
    records: int
    solve_s: float = 0.0
    latency_s: float | None = None  # from the arrival of the newest record imaged to the frame
    info: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The frame's figures, peaks and links (JSON)."""
        return {"t": self.t, "bounds": list(self.bounds), "peaks": self.peaks, "links": self.links,
                "links_per_s": round(self.links_per_s, 2), "coverage": round(self.coverage, 4),
                "paths": self.paths, "records": self.records, "solve_s": round(self.solve_s, 4),
                "latency_s": None if self.latency_s is None else round(self.latency_s, 4),
                "max": round(float(self.image.max()), 4) if self.image.size else 0.0, **self.info}


def boundary(t: float, window: float) -> float:
    """The end of the newest window that a record at ``t`` shows to be complete."""
    return math.floor(t / window + 1e-9) * window


def frame_at(records: Records, end: float, window: float = WINDOW, history: float = HISTORY,
             bounds: tuple[float, float, float, float] | None = None, cell: float = CELL,
             peaks: int = PEAKS) -> Frame | None:
    """The frame at window boundary ``end`` from every record the station holds (see the module's docstring);
    None when no link was heard often enough to image."""
    used = records.select((records.t >= end - FORGET - history) & (records.t < end))
    if len(used):
        _, link = factorize(pair_keys(used))
        last = np.full(int(link.max()) + 1, -np.inf)
        np.maximum.at(last, link, used.t)
        used, link = used.select(keep := (last[link] >= end - FORGET) & (used.t >= last[link] - history)), link[keep]
        used = used.select((np.bincount(link)[link] >= MIN_HEARD) & evenly(link, PER_LINK))
    if len(used) < 2:
        return None
    result = reconstruct(used, bounds=bounds, cell=cell, peaks=peaks, empty_from=EMPTY_FROM, **STANDING)
    grid, first = result.grid, result.frames[0]
    if "image" not in first:
        return None
    last = used.select(used.t >= end - window)
    links = factorize(pair_keys(last)[:, :4])[0] * KEY_STEP  # each path once, whichever way it was heard
    info = {key: result.info[key] for key in ("measure", "solver", "alpha") if key in result.info}
    return Frame(t=round(end, 6), bounds=tuple(round(v, 4) for v in grid.bounds), image=first["image"],
                 peaks=first["peaks"], links=np.round(links, 3).tolist(), links_per_s=len(last) / window,
                 coverage=coverage(factorize(pair_keys(used)[:, :4])[0] * KEY_STEP, grid.bounds, grid.cell,
                                   first["image"].shape), paths=first["paths"],
                 records=len(used), info={**info, "cell": grid.cell, "window": window, "history": history})


def evenly(link: np.ndarray, most: int) -> np.ndarray:
    """Which records to keep so that no link (``link``: each record's link number, records in time order) keeps
    more than ``most``, those it keeps spread evenly over its records."""
    order = np.argsort(link, kind="stable")
    counts = np.bincount(link)
    starts = np.cumsum(counts) - counts
    rank = np.arange(len(link)) - starts[link[order]]
    count = counts[link[order]]
    keep = np.empty(len(link), bool)
    keep[order] = (count <= most) | (rank * most // count != (rank - 1) * most // count)
    return keep


def pair_keys(records: Records) -> np.ndarray:
    """Each record's link key (rounded positions and channel) with the two ends in one order (a path both ways)."""
    keys = link_keys(records)
    swap = (keys[:, 0] > keys[:, 2]) | ((keys[:, 0] == keys[:, 2]) & (keys[:, 1] > keys[:, 3]))
    keys[swap] = keys[swap][:, [2, 3, 0, 1, 4]]
    return keys


def coverage(paths: np.ndarray, bounds, cell: float, shape: tuple[int, int]) -> float:
    """Share of the image's pixels that some path's straight line crosses (sampled every quarter pixel)."""
    hit = np.zeros(shape, bool)
    for x0, y0, x1, y1 in paths:
        steps = max(2, int(math.hypot(x1 - x0, y1 - y0) / cell * 4) + 1)
        s = np.linspace(0, 1, steps)
        ix = np.floor((x0 + (x1 - x0) * s - bounds[0]) / cell).astype(int)
        iy = np.floor((y0 + (y1 - y0) * s - bounds[1]) / cell).astype(int)
        inside = (ix >= 0) & (ix < shape[1]) & (iy >= 0) & (iy < shape[0])
        hit[iy[inside], ix[inside]] = True
    return float(hit.mean())


def rgba(image: np.ndarray) -> np.ndarray:
    """An image's pixels, north up, viridis from 0 to its maximum, more transparent the less attenuated."""
    scaled = np.clip(image, 0, None) / max(float(image.max()), 1e-9)
    return np.dstack([colours(scaled), (np.clip(scaled * 2, 0, 1) * 200).astype(np.uint8)])[::-1].copy()


def picture(frame: Frame) -> dict:
    """The frame's image as a PNG data URL (north up, viridis from 0 to the image's maximum, transparent where
    nothing is attenuated) with its bounds and the colour scale."""
    top = max(float(frame.image.max()), 1e-9)
    out = io.BytesIO()
    Image.fromarray(rgba(frame.image), "RGBA").save(out, format="PNG")
    return {"image": "data:image/png;base64," + base64.b64encode(out.getvalue()).decode("ascii"),
            "bounds": list(frame.bounds), "t": frame.t,
            "scale": {"min": 0.0, "max": round(top, 4), "unit": UNITS.get(frame.info.get("measure"), "per pixel"),
                      "colours": ["#" + "".join(f"{int(c):02x}" for c in stop) for stop in STOPS]}}


UNITS = {"mean": "dB/px", "variance": "dB²/px", "kernel": "D²/px"}


class LiveImager:
    """Keeps the latest frame of the link log that ``source()`` names (the live fleet's, or the replay's)."""

    def __init__(self, source: Callable[[], object], window: float = WINDOW, history: float = HISTORY,
                 bounds: tuple[float, float, float, float] | None = None, cell: float = CELL,
                 solve: Callable[..., Frame | None] = frame_at):
        self.source, self.window, self.history, self.bounds, self.cell = source, window, history, bounds, cell
        self.solve = solve
        self.listeners: list[Callable[[Frame | None], None]] = []  # told of every new frame (the 3D view)
        self.targets: list[list[float]] | None = None  # the simulation's targets (x, y), ground truth for the page
        self.frames = 0  # frames made
        self.skipped = 0  # windows that closed while a solve ran, never imaged
        self.error: str | None = None
        self._frame: Frame | None = None
        self._log, self._version, self._end = None, None, None
        self._arrivals: list[tuple[int, float]] = []  # (log length, wall time it was first seen)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def latest(self) -> Frame | None:
        return self._frame

    def start(self) -> None:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="rti-live", daemon=True)
                self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def _run(self) -> None:
        while not self._stop.wait(POLL):
            try:
                self.step()
            except Exception as error:  # a bad frame must not end live imaging: say it, try the next window
                self.error = f"{type(error).__name__}: {error}"

    def step(self) -> bool:
        """Look at the log once; image its newest complete window if that is new. True when a frame was made
        (or cleared)."""
        log = self.source()
        if log is not self._log:  # live <-> replay
            self._log, self._version, self._end, self._arrivals = log, None, None, []
            self._show(None)
        if log is None:
            return False
        version, size, now = getattr(log, "version", len(log)), len(log), time.monotonic()
        if version == self._version:
            return False
        self._version = version
        if self._arrivals and size < self._arrivals[-1][0]:
            self._arrivals = []  # cleared (a seek)
        if not self._arrivals or size > self._arrivals[-1][0]:
            self._arrivals = [*self._arrivals[-ARRIVALS + 1:], (size, now)]
        rows = log.snapshot()
        if not rows:
            changed, self._end = self._frame is not None, None
            self._show(None)
            return changed
        newest = max(r.t for r in rows)
        end = boundary(newest, self.window)
        if end == self._end:
            return False
        if self._end is not None and end > self._end + self.window:
            self.skipped += round((end - self._end) / self.window) - 1
        self._end = end
        started = time.perf_counter()
        frame = self.solve(records_of(rows), end, window=self.window, history=self.history,
                           bounds=self.bounds, cell=self.cell)
        if frame is not None:
            frame.solve_s = time.perf_counter() - started
            last = max((i for i, r in enumerate(rows) if r.t < end), default=None)
            arrived = next((w for n, w in self._arrivals if n > last), None) if last is not None else None
            frame.latency_s = None if arrived is None else time.monotonic() - arrived
            self.frames += 1
        self.error = None
        self._show(frame)
        return True

    def _show(self, frame: Frame | None) -> None:
        """Tell the listeners, then answer readers with ``frame`` (a listener's failure is said, not fatal)."""
        if frame is None and self._frame is None:
            return
        for listener in self.listeners:
            try:
                listener(frame)
            except Exception as error:  # noqa: BLE001 - the 3D view must not stop the imaging
                self.error = f"showing the frame: {type(error).__name__}: {error}"
        self._frame = frame
