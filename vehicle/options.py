"""Numbers on the command line, checked as argparse parses them (both programs use these).

A typo or an absurd value is a usage error naming the option, before anything
starts: never a traceback from a socket (port 70000), a vehicle no station
shows (system id 0, MAVLink's broadcast address), or a simulation that stands
still (a speed-up of 0 or NaN).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def finite(text: str) -> float:
    """Any real number (NaN and infinities are no heading or altitude)."""
    value = _float(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}")
    return value


def positive(text: str) -> float:
    """A finite number above 0 (a speed-up, a timeout, a duration)."""
    value = _float(text)
    if value is None or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number above 0, not {text!r}")
    return value


def whole(lowest: int, highest: int | None = None) -> Callable[[str], int]:
    """An integer from ``lowest`` to ``highest`` (no limit if None)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < lowest or (highest is not None and value > highest):
            span = f"{lowest} or more" if highest is None else f"{lowest} to {highest}"
            raise argparse.ArgumentTypeError(f"expected a whole number {span}, not {text!r}")
        return value

    return parse


port = whole(1, 65535)
system_id = whole(1, 255)  # MAVLink's: 0 addresses every system


def _float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None
