"""What a vehicle knows of another vehicle of its team: where it is and how it moves, at a time.

The narrow view an onboard agent gets of its team-mates (``FlightController.traffic``), whichever way it
learnt it: from the simulated world in-process, or from MAVLink traffic reports (ADSB_VEHICLE), which our
simulated autopilots send of their team-mates and the ground station relays for vehicles that hear none
(``adsb_report`` writes them for both).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vehicle.protocol.mav import mavlink

ADSB_FLAGS = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
              | mavlink.ADSB_FLAGS_VALID_VELOCITY | mavlink.ADSB_FLAGS_VALID_CALLSIGN
              | mavlink.ADSB_FLAGS_VERTICAL_VELOCITY_VALID)


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


def adsb_report(sysid: int, lat: float, lon: float, alt_msl: float, east: float, north: float, up: float,
                heading: float, simulated: bool = False):
    """ADSB_VEHICLE for a team-mate: the ICAO address is its system id, its callsign VEH<id>, its altitude
    geometric (m above sea level), its track and ground speed from its velocity (m/s east, north, up), or its
    ``heading`` (compass degrees) while it stands."""
    speed = math.hypot(east, north)
    track = math.degrees(math.atan2(east, north)) % 360 if speed > 0.05 else heading % 360
    flags = ADSB_FLAGS | (mavlink.ADSB_FLAGS_SIMULATED if simulated else 0)
    return mavlink.MAVLink_adsb_vehicle_message(
        sysid, int(round(lat * 1e7)), int(round(lon * 1e7)), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
        int(round(alt_msl * 1000)), int(track * 100) % 36000, min(65535, int(round(speed * 100))),
        max(-32768, min(32767, int(round(up * 100)))), f"VEH{sysid}".encode(), mavlink.ADSB_EMITTER_TYPE_UAV, 0,
        flags, 0)
