"""A small forward model of a radio network, for tests and benchmarks: link records with known people.

Empty-area RSS per link and channel: log-distance path loss plus a per-channel shadowing draw (so channels
fade differently, as they do). A person is an attenuating cylinder: ``depth`` dB on every link whose line passes
within ``radius`` of them, fading linearly to nothing over ``fringe`` beyond. Each reading adds Gaussian noise
(0.7 dB, the median deviation of real static links) and is rounded to the 1 dB step radios report; a share of
readings goes missing. Links may be given a drift: an offset on every reading after calibration.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vehicle.tomography.links import Records


def square(radios: int = 28, side: float = 6.4) -> np.ndarray:
    """``radios`` positions evenly spaced around a square of ``side`` metres with its corner at the origin."""
    s = np.linspace(0, 4 * side, radios, endpoint=False)
    edge, along = np.divmod(s, side)
    corners = np.array([[0, 0], [side, 0], [side, side], [0, side], [0, 0]], float)
    start, end = corners[edge.astype(int)], corners[edge.astype(int) + 1]
    return start + (end - start) * (along / side)[:, None]


def line_distance(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from ``point`` to each segment a-b (arrays of (n, 2))."""
    ab = b - a
    t = np.clip(((point - a) * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-12), 0, 1)
    return np.linalg.norm(a + ab * t[:, None] - point, axis=1)


class Network:
    """Fixed radios measuring every ordered pair on ``channels`` channels, once per sweep."""

    def __init__(self, radios: np.ndarray, channels: int = 4, seed: int = 1, p0: float = -40.0,
                 exponent: float = 2.5, shadowing: float = 4.0):
        self.radios = radios
        self.rng = np.random.default_rng(seed)
        i, j = np.nonzero(~np.eye(len(radios), dtype=bool))
        self.tx, self.rx = np.repeat(i, channels), np.repeat(j, channels)
        self.channel = np.tile(np.arange(1, channels + 1), len(i))
        d = np.linalg.norm(radios[self.tx] - radios[self.rx], axis=1)
        self.empty = p0 - 10 * exponent * np.log10(d) + self.rng.normal(0, shadowing, len(d))
        self.offset = np.zeros(len(d))

    def drift(self, pairs: list[tuple[int, int]], offset: float) -> None:
        """Shift every later reading of these radio pairs (both directions, all channels) by ``offset`` dB."""
        for a, b in pairs:
            self.offset[((self.tx == a) & (self.rx == b)) | ((self.tx == b) & (self.rx == a))] = offset

    def sweeps(self, times: np.ndarray, people=lambda t: [], noise: float = 0.7, missing: float = 0.06,
               depth: float = 4.0, radius: float = 0.2, fringe: float = 0.3, drifted: bool = True) -> Records:
        """Readings at each of ``times``; ``people(t)`` gives the people's positions then."""
        a, b = self.radios[self.tx], self.radios[self.rx]
        columns = {k: [] for k in ("t", "tx", "rx", "rssi", "channel")}
        for t in times:
            rss = self.empty + (self.offset if drifted else 0.0) + self.rng.normal(0, noise, len(self.empty))
            for person in people(t):
                gap = line_distance(np.asarray(person, float), a, b) - radius
                rss -= depth * np.clip(1 - gap / fringe, 0, 1)
            heard = self.rng.random(len(rss)) >= missing
            columns["t"].append(np.full(heard.sum(), t))
            for key, value in (("tx", self.tx), ("rx", self.rx), ("rssi", np.round(rss)), ("channel", self.channel)):
                columns[key].append(value[heard])
        c = {k: np.concatenate(v) for k, v in columns.items()}
        return Records("synthetic", c["t"], self.radios[c["tx"]], self.radios[c["rx"]], c["rssi"],
                       c["channel"].astype(np.int64))


def write_csv(records: Records, path: str | Path, ids: bool = True) -> None:
    """The records as a link file (the contract's columns; node ids are the position's index here)."""
    rows = np.column_stack([records.t, np.zeros(len(records)), np.zeros(len(records)), records.tx, records.rx,
                            records.rssi, records.channel])
    lines = ["t,tx,rx,tx_x,tx_y,rx_x,rx_y,rssi,channel"]
    lines += [f"{r[0]:.3f},0,1,{r[3]:.4f},{r[4]:.4f},{r[5]:.4f},{r[6]:.4f},{r[7]:.0f},{r[8]:.0f}" for r in rows]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
