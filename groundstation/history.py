"""What each vehicle did over time: numeric telemetry sampled into bounded series, and its events.

The page plots any numeric field against time and marks events on the same
axis (mode changes, arming, the operator's commands and the vehicle's ACKs,
messages, the onboard agent's phases, near misses between two vehicles). The Fleet feeds this as it applies
messages, live and in replay alike, so a field means the same in both: a
sample is the vehicle's state as the Fleet knew it at that moment. Series are
numpy ring buffers (an hour at two samples a second is half a megabyte per
vehicle). Events that matter (the operator's commands and their answers, mode
changes, arming, failsafes, warnings and errors, the agent's state, crashes,
near misses) are kept for the whole flight (up to KEPT_EVENTS); routine ones
(the onboard agent's own commands acknowledged, information messages) go to a
bounded deque, and an acknowledgement of the agent's own command is only
counted: an agent flying a search sent 961 of the last 1,000 events as
"DO_REPOSITION: accepted", and the operator's commands were pushed out. Each
event names its source (autopilot, agent, operator, station) and has a
severity (MAVLink's, 0 emergency .. 7 debug), by which the page filters.
Nothing stored is ever NaN on the way out: a value that is missing or not
finite is sent as null.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

SAMPLE_EVERY = 0.5  # s of the fleet's clock between samples of a vehicle
SAMPLES_KEPT = 7200  # an hour at SAMPLE_EVERY
EVENTS_KEPT = 1000  # routine events (the newest)
KEPT_EVENTS = 20000  # events that matter: a flight's worth (a safety bound, not a window)
SOURCES = ("autopilot", "agent", "operator", "station")
MATTERS_AT = 4  # MAV_SEVERITY_WARNING: this or worse always matters
MAX_SONARS = 12  # sonar columns per vehicle; more sensors are not plotted

# (name, unit): the fields every vehicle has; each sonar adds "sonar ID" (m)
FIELDS = [("altitude", "m"), ("speed", "m/s"), ("climb", "m/s"), ("heading", "°"), ("roll", "°"),
          ("pitch", "°"), ("battery voltage", "V"), ("battery remaining", "%"), ("battery current", "A"),
          ("occupied cells", "cells")]
BASE = [name for name, _ in FIELDS]
UNITS = dict(FIELDS)


@dataclass
class Event:
    time: float
    kind: str  # mode, armed, command, ack, message, agent, near miss, crash
    text: str
    severity: int | None = None  # MAVLink severity (0 emergency .. 7 debug)
    source: str = "autopilot"  # autopilot, agent, operator or station

    def as_json(self) -> dict:
        return {"t": round(self.time, 3), "kind": self.kind, "text": self.text, "severity": self.severity,
                "source": self.source}


@dataclass
class VehicleHistory:
    capacity: int = SAMPLES_KEPT
    times: np.ndarray = field(init=False)
    values: np.ndarray = field(init=False)
    columns: dict[str, int] = field(default_factory=lambda: {name: i for i, name in enumerate(BASE)})
    count: int = 0  # samples ever taken (the ring holds the last ``capacity``)
    last: float = -math.inf
    events: deque = field(default_factory=lambda: deque(maxlen=EVENTS_KEPT))  # routine, the newest
    kept: deque = field(default_factory=lambda: deque(maxlen=KEPT_EVENTS))  # what matters, the whole flight
    counted: dict = field(default_factory=dict)  # (source, text) -> [times, last time]: routine, not listed

    def __post_init__(self) -> None:
        self.times = np.zeros(self.capacity)
        self.values = np.full((self.capacity, len(BASE) + MAX_SONARS), np.nan, dtype=np.float32)

    def column(self, name: str) -> int | None:
        index = self.columns.get(name)
        if index is None and len(self.columns) < self.values.shape[1]:
            index = self.columns[name] = len(self.columns)
        return index

    def add(self, time: float, values: dict[str, float | None]) -> None:
        slot = self.count % self.capacity
        self.times[slot] = time
        row = self.values[slot]
        row[:] = np.nan
        for name, value in values.items():
            index = self.column(name)
            if index is not None and value is not None and math.isfinite(value):
                row[index] = value
        self.count += 1
        self.last = time

    def ordered(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and values of the samples kept, oldest first."""
        kept = min(self.count, self.capacity)
        start = self.count - kept
        order = (np.arange(start, self.count)) % self.capacity
        return self.times[order], self.values[order]

    def as_json(self, since: float | None = None, limit: int | None = None) -> dict:
        """Columns of the samples after ``since`` (all without it), at most ``limit`` of them (evenly thinned);
        the events after ``since``."""
        times, values = self.ordered()
        if since is not None:
            keep = times > since
            times, values = times[keep], values[keep]
        if limit is not None and len(times) > limit:
            pick = np.linspace(0, len(times) - 1, limit).round().astype(int)
            times, values = times[pick], values[pick]
        names = sorted(self.columns, key=self.columns.get)
        series = {}
        for name in names:
            column = values[:, self.columns[name]]
            if np.isnan(column).all():
                continue
            series[name] = [None if math.isnan(v) else round(float(v), 3) for v in column]
        events = [e.as_json() for e in heapq.merge(self.kept, self.events, key=lambda e: e.time)
                  if since is None or e.time > since]
        counted = [{"source": source, "text": text, "count": count, "last": round(last, 3)}
                   for (source, text), (count, last) in self.counted.items()]
        return {"t": [round(float(t), 3) for t in times], "series": series,
                "units": {name: UNITS.get(name, "m" if name.startswith("sonar") else "") for name in series},
                "events": events, "counted": counted}

    def add_event(self, event: Event, routine: bool) -> None:
        """``routine``: may be dropped for newer ones, unless its severity is a warning or worse."""
        if routine and (event.severity is None or event.severity > MATTERS_AT):
            self.events.append(event)
        else:
            self.kept.append(event)

    def count_event(self, time: float, source: str, text: str) -> None:
        entry = self.counted.setdefault((source, text), [0, time])
        entry[0] += 1
        entry[1] = time


class History:
    """Every vehicle's history, by system id. The Fleet calls it under its own lock."""

    def __init__(self, every: float = SAMPLE_EVERY, capacity: int = SAMPLES_KEPT):
        self.every = every
        self.capacity = capacity
        self.vehicles: dict[int, VehicleHistory] = {}
        self.near_misses = NearMisses()

    def of(self, sysid: int) -> VehicleHistory:
        found = self.vehicles.get(sysid)
        if found is None:
            found = self.vehicles[sysid] = VehicleHistory(self.capacity)
        return found

    def due(self, sysid: int, now: float) -> bool:
        found = self.vehicles.get(sysid)
        return found is None or now - found.last >= self.every or now < found.last

    def sample(self, sysid: int, now: float, values: dict[str, float | None]) -> None:
        self.of(sysid).add(now, values)

    def event(self, sysid: int, now: float, kind: str, text: str, severity: int | None = None,
              source: str = "autopilot", routine: bool = False) -> None:
        self.of(sysid).add_event(Event(now, kind, text[:300], severity, source), routine)

    def count(self, sysid: int, now: float, source: str, text: str) -> None:
        """A routine event counted, not listed (an acknowledgement of the onboard agent's own command)."""
        self.of(sysid).count_event(now, source, text)

    def clear(self) -> None:
        self.vehicles.clear()
        self.near_misses.clear()


NEAR_MISS_MARGIN = 2.0  # m between two bodies: the agents' default separation
ASSUMED_RADIUS = 0.3  # m: a vehicle's body (MAVLink tells the station no size; the simulator's and agent's default)
PARTED = 1.0  # m beyond the margin two vehicles must part before coming close again is a new near miss


class NearMisses:
    """Two vehicles closer than the separation margin (``margin`` plus both bodies' radii), from the poses the
    station hears: one event on each one's timeline naming both as they come within it, counted once; the
    same pair again only after they parted by PARTED more."""

    def __init__(self, margin: float = NEAR_MISS_MARGIN, radius: float = ASSUMED_RADIUS):
        self.reach = margin + 2 * radius
        self.margin = margin
        self.close: dict[tuple[int, int], float] = {}  # pair -> the closest their centres came, while close
        self.counts: dict[int, int] = {}  # system id -> near misses it was in
        self.total = 0

    def check(self, sysid: int, positions: dict[int, tuple[float, float, float]], now: float,
              history: History) -> None:
        """Vehicle ``sysid`` moved: compare it with every other whose position is known."""
        here = positions.get(sysid)
        if here is None:
            return
        for other, there in positions.items():
            if other == sysid:
                continue
            pair = (min(sysid, other), max(sysid, other))
            apart = math.dist(here, there)
            if pair in self.close:
                if apart > self.reach + PARTED:
                    del self.close[pair]
                continue
            if apart < self.reach:
                self.close[pair] = apart
                self.total += 1
                text = (f"near miss: vehicles {pair[0]} and {pair[1]} {apart:.1f} m apart (centres), within the "
                        f"{self.margin:g} m separation margin")
                for each in pair:
                    self.counts[each] = self.counts.get(each, 0) + 1
                    history.event(each, now, "near miss", text, 4, "station")  # MAV_SEVERITY_WARNING

    def clear(self) -> None:
        self.close.clear()
        self.counts.clear()
        self.total = 0
