"""What a vehicle knows of another vehicle of its team: where it is and how it moves, at a time.

The narrow view an onboard agent gets of its team-mates (``FlightController.traffic``), whichever way it
learnt it: from the simulated world in-process, or, later, from MAVLink traffic reports (ADSB_VEHICLE).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Traffic:
    vehicle: int  # MAVLink system id
    x: float  # scene metres, x east, y north, z up
    y: float
    z: float
    vx: float  # m/s east, north
    vy: float
    radius: float  # m, its body
    time: float  # s on the observer's flight-controller clock when this was its state
