"""Scene metres <-> WGS84, the way ArduPilot does it.

ArduPilot converts between local offsets and latitude/longitude with a flat-earth
scaling (``LOCATION_SCALING_FACTOR``); using the same formula means a waypoint
round-trips through MAVLink and QGC WPL files to the same scene position.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

# metres per 1e-7 degree of latitude (ArduPilot's LOCATION_SCALING_FACTOR)
METRES_PER_DEGE7 = 0.011131884502145034


def on_earth(lat: float, lon: float) -> bool:
    """Latitude and longitude (degrees) that name a place: a peer may send any number, NaN included."""
    return abs(lat) <= 90 and abs(lon) <= 180


@dataclass(frozen=True)
class Datum:
    """The geodetic position of the scene origin (defaults: ArduPilot's simulator home)."""

    lat: float = -35.363261
    lon: float = 149.165230
    alt: float = 584.0

    @property
    def _lon_scale(self) -> float:
        return max(math.cos(math.radians(self.lat)), 0.01)

    def to_global(self, x: float, y: float) -> tuple[float, float]:
        """Latitude and longitude in degrees of the scene point (x east, y north)."""
        lat = self.lat + y / METRES_PER_DEGE7 * 1e-7
        lon = self.lon + x / (METRES_PER_DEGE7 * self._lon_scale) * 1e-7
        return lat, lon

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        """Scene x (east) and y (north) in metres of a latitude and longitude in degrees."""
        y = (lat - self.lat) * 1e7 * METRES_PER_DEGE7
        x = (lon - self.lon) * 1e7 * METRES_PER_DEGE7 * self._lon_scale
        return x, y

    @classmethod
    def parse(cls, text: str) -> Datum:
        """``LAT,LON[,ALT]`` (degrees, metres above sea level) as given on a command line."""
        try:
            parts = [float(p) for p in text.split(",")]
        except ValueError:
            parts = []
        if len(parts) not in (2, 3) or not all(map(math.isfinite, parts)):
            raise ValueError(f"a datum is LAT,LON[,ALT] in degrees and metres, not {text!r}")
        if not on_earth(parts[0], parts[1]):
            raise ValueError(f"latitude must be within +-90 and longitude within +-180 degrees, not {text!r}")
        return cls(*parts)

    @classmethod
    def of_scene(cls, hints: Mapping[str, str], given: Datum | None = None) -> Datum:
        """Where a scene's origin lies on Earth: ``given`` (a command line's), else the scene's ``datum``
        hint (a WorldInfo ``datum=LAT,LON[,ALT]`` string), else ArduPilot's simulator home."""
        if given is not None:
            return given
        if "datum" in hints:
            try:
                return cls.parse(hints["datum"])
            except ValueError as error:
                raise ValueError(f"the scene's datum hint: {error}") from None
        return cls()


def datum_option(text: str) -> Datum:
    """argparse type of a ``--datum LAT,LON[,ALT]`` option."""
    import argparse

    try:
        return Datum.parse(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def heading_vector(heading_rad: float) -> tuple[float, float]:
    """Unit (east, north) vector of a compass heading (0 = north, clockwise)."""
    return math.sin(heading_rad), math.cos(heading_rad)


def heading_of(dx: float, dy: float) -> float:
    """Compass heading in radians [0, 2pi) of the vector (east, north)."""
    return math.atan2(dx, dy) % (2 * math.pi)


def wrap_pi(angle: float) -> float:
    """Angle wrapped to [-pi, pi): the signed shortest turn."""
    return (angle + math.pi) % (2 * math.pi) - math.pi
