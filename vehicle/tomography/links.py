"""Link records (``t,tx,rx,tx_x,tx_y,rx_x,rx_y,rssi,channel``): reading, checking, and naming the links.

A link is a pair of positions and a channel, not a pair of node ids: radios on moving vehicles that stop at the
same spots again are the same link there, and calibrated as such. Positions are rounded to ``KEY_STEP`` for the
key, so a vehicle holding a spot within a few centimetres keeps its link.
"""

from __future__ import annotations

import gzip
import io
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

COLUMNS = ("t", "tx", "rx", "tx_x", "tx_y", "rx_x", "rx_y", "rssi", "channel")
KEY_STEP = 0.05  # metres: positions closer than this are one spot
SKIP_REASONS = {
    "malformed": "malformed (too few fields, or a number that does not parse)",
    "not_finite": "with a NaN or infinite value",
    "same_point": "whose two ends are the same point",
    "out_of_order": "earlier than the row before (out of time order)",
}


class LinkError(ValueError):
    """A link file that cannot be used at all; the message names the file and the line."""


@dataclass
class Records:
    """The usable rows of one file as columns, and what was skipped (reason -> count, and the first line)."""

    path: str
    t: np.ndarray
    tx: np.ndarray  # (n, 2) positions
    rx: np.ndarray
    rssi: np.ndarray
    channel: np.ndarray  # int
    skipped: dict[str, int] = field(default_factory=dict)
    first_skipped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    def select(self, keep: np.ndarray) -> Records:
        return Records(self.path, self.t[keep], self.tx[keep], self.rx[keep], self.rssi[keep], self.channel[keep],
                       dict(self.skipped), dict(self.first_skipped))

    def warnings(self) -> list[str]:
        """One line per kind of skipped row, naming the file and the first such line."""
        return [f"{self.path}:{self.first_skipped[kind]}: skipped {count} row(s) {SKIP_REASONS[kind]}"
                for kind, count in self.skipped.items() if count]

    def radios(self) -> np.ndarray:
        """Every distinct radio position (rounded to the key step), for drawing."""
        ends = np.round(np.vstack([self.tx, self.rx]) / KEY_STEP).astype(np.int64)
        return factorize(ends)[0] * KEY_STEP if len(ends) else np.zeros((0, 2))


def _open_text(path: Path) -> io.TextIOBase:
    with open(path, "rb") as probe:
        gzipped = probe.read(2) == b"\x1f\x8b"
    if gzipped:
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", errors="replace", newline="")
    return open(path, encoding="utf-8", errors="replace", newline="")


def read_links(path: str | Path) -> Records:
    """Read a link file (plain or gzip). Bad rows are skipped and counted; a file with no header, no columns we
    need or no usable row at all raises LinkError naming the file and line."""
    path = Path(path)
    name = str(path)
    try:
        handle = _open_text(path)
    except OSError as error:
        raise LinkError(f"{name}: cannot read: {error.strerror or error}") from None
    with handle:
        try:
            header = handle.readline()
        except (OSError, EOFError, gzip.BadGzipFile) as error:
            raise LinkError(f"{name}:1: cannot read: {error}") from None
        names = [part.strip().lower() for part in header.strip().lstrip("\ufeff").split(",")]
        missing = [column for column in COLUMNS if column not in names]
        if not header.strip():
            raise LinkError(f"{name}:1: empty file (expected a header: {','.join(COLUMNS)})")
        if missing:
            raise LinkError(f"{name}:1: the header lacks {', '.join(missing)} (expected {','.join(COLUMNS)})")
        index = [names.index(column) for column in COLUMNS]
        try:
            text = handle.read()
        except (OSError, EOFError, gzip.BadGzipFile) as error:  # a truncated or corrupt gzip stream
            raise LinkError(f"{name}: cannot read further: {error}") from None
    data, lines = _parse_fast(text, index)
    if data is None:
        data, lines, skipped, first = _parse_slow(text, index)
    else:
        skipped, first = dict.fromkeys(SKIP_REASONS, 0), {}
    keep = _check(data, lines, skipped, first)
    data = data[keep]
    if not len(data):
        why = "; ".join(f"{count} {SKIP_REASONS[kind]}" for kind, count in skipped.items() if count)
        last = 1 + max(1, text.count("\n"))  # the last line read, or where the first record belonged
        raise LinkError(f"{name}:{last}: no usable link records" + (f" ({why})" if why else ""))
    return Records(name, data[:, 0], data[:, 1:3], data[:, 3:5], data[:, 5], data[:, 6].astype(np.int64),
                   {k: v for k, v in skipped.items() if v}, first)


@dataclass
class LinkTable:
    """The distinct links of some records: each row's link-channel index, each link-channel's geometry index
    (the unordered pair of rounded positions: both directions of a pair see the same path), and the paths."""

    row_lc: np.ndarray  # (rows,) index into the link-channels
    lc_keys: np.ndarray  # (L, 5) int: tx x, tx y, rx x, rx y in key steps, channel
    lc_path: np.ndarray  # (L,) index into paths
    paths: np.ndarray  # (P, 4) float: x0, y0, x1, y1 of each path, in metres

    @property
    def lc_length(self) -> np.ndarray:
        ends = self.paths[self.lc_path]
        return np.hypot(ends[:, 2] - ends[:, 0], ends[:, 3] - ends[:, 1])


def link_keys(records: Records) -> np.ndarray:
    """(rows, 5) integer keys: rounded tx and rx positions (in KEY_STEP units) and the channel."""
    tx = np.round(records.tx / KEY_STEP).astype(np.int64)
    rx = np.round(records.rx / KEY_STEP).astype(np.int64)
    return np.column_stack([tx, rx, records.channel])


def _parse_fast(text: str, index: list[int]) -> tuple[np.ndarray | None, np.ndarray]:
    """All rows at once with numpy's C parser: (rows x 7: t, tx_x, tx_y, rx_x, rx_y, rssi, channel) and their
    line numbers, or (None, ...) when some row does not parse or a blank line would shift the numbering."""
    body = text.rstrip("\n")
    if not body or "\n\n" in body or "\r" in body:
        return None, np.zeros(0)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(io.StringIO(body), delimiter=",", usecols=[index[i] for i in (0, 3, 4, 5, 6, 7, 8)],
                              ndmin=2, dtype=float)
    except ValueError:
        return None, np.zeros(0)
    if len(data) != body.count("\n") + 1:
        return None, np.zeros(0)
    return data, np.arange(2, len(data) + 2)


def _parse_slow(text: str, index: list[int]) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """Row by row, skipping (and counting) the rows that do not parse."""
    need = max(index) + 1
    columns = [index[i] for i in (0, 3, 4, 5, 6, 7, 8)]
    rows, lines = [], []
    skipped, first = dict.fromkeys(SKIP_REASONS, 0), {}
    for number, line in enumerate(text.splitlines(), start=2):
        if not line.strip():
            continue
        parts = line.split(",")
        try:
            if len(parts) < need:
                raise ValueError
            rows.append([float(parts[i]) for i in columns])
            lines.append(number)
        except ValueError:
            skipped["malformed"] += 1
            first.setdefault("malformed", number)
    return np.array(rows, dtype=float).reshape(-1, 7), np.array(lines, dtype=np.int64), skipped, first


def _check(data: np.ndarray, lines: np.ndarray, skipped: dict, first: dict) -> np.ndarray:
    """Which parsed rows to keep: finite, two distinct ends, not earlier than the kept rows before them."""
    keep = np.ones(len(data), bool)

    def drop(kind: str, bad: np.ndarray) -> None:
        bad &= keep
        if bad.any():
            skipped[kind] += int(bad.sum())
            first[kind] = min(first.get(kind, 1 << 62), int(lines[np.argmax(bad)]))
            keep[bad] = False

    drop("not_finite", ~np.isfinite(data).all(axis=1))
    with np.errstate(invalid="ignore"):
        drop("same_point", np.hypot(data[:, 1] - data[:, 3], data[:, 2] - data[:, 4]) < KEY_STEP)
    # a row is out of order when earlier than the latest kept row before it; skipped rows are earlier than
    # that latest one, so it is the running maximum over all the rows still kept
    t = np.where(keep, data[:, 0], -np.inf)
    latest = np.concatenate([[-np.inf], np.maximum.accumulate(t)[:-1]])
    drop("out_of_order", t < latest)
    return keep


def factorize(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Like np.unique(rows, axis=0, return_inverse=True) for integer rows, column by column (much faster)."""
    code = np.zeros(len(rows), np.int64)
    for column in rows.T:
        values, inverse = np.unique(column, return_inverse=True)
        _, code = np.unique(code * len(values) + inverse.ravel(), return_inverse=True)
        code = code.ravel()
    first = np.zeros(int(code.max()) + 1 if len(code) else 0, np.int64)
    first[code[::-1]] = np.arange(len(code))[::-1]
    return rows[first], code


def link_table(records: Records) -> LinkTable:
    keys = link_keys(records)
    lc_keys, row_lc = factorize(keys)
    ends = lc_keys[:, :4].reshape(-1, 2, 2)
    order = np.lexsort((ends[:, :, 1], ends[:, :, 0]))  # sort the two ends of each pair
    pair = np.take_along_axis(ends, order[:, :, None], axis=1).reshape(-1, 4)
    path_keys, lc_path = factorize(pair)
    return LinkTable(row_lc.ravel(), lc_keys, lc_path.ravel(), path_keys.astype(float) * KEY_STEP)


def match_keys(keys: np.ndarray, table_keys: np.ndarray) -> np.ndarray:
    """For each row of ``keys``, its index in ``table_keys`` (both (n, 5) ints), or -1 when absent."""
    lookup = {tuple(k): i for i, k in enumerate(table_keys.tolist())}
    return np.array([lookup.get(tuple(k), -1) for k in keys.tolist()], dtype=np.int64)


def records_of(rows, name: str = "radio") -> Records:
    """Link records (anything with ``t, tx_x, tx_y, rx_x, rx_y, rssi, channel``: the radio stream's
    ``LinkRecord``) as the reconstruction's columns, sorted by time."""
    rows = sorted(rows, key=lambda r: r.t)
    if not rows:
        return Records(name, np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
    data = np.array([(r.t, r.tx_x, r.tx_y, r.rx_x, r.rx_y, r.rssi, r.channel) for r in rows], float)
    return Records(name, data[:, 0], data[:, 1:3], data[:, 3:5], data[:, 5], data[:, 6].astype(np.int64))
