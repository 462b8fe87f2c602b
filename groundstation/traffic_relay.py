"""The station tells each vehicle where its team-mates are, when nothing else does.

An onboard agent keeps clear of its team-mates by the ADSB_VEHICLE reports it
hears (``vehicle.agent.traffic``). Our simulated world's autopilots report
every team-mate themselves; vehicles that do not share a world (two ArduPilot
autopilots, each with its own physics) hear of each other only through the
station, which hears them all. So the station sends, every RELAY_PERIOD, an
ADSB_VEHICLE for each vehicle it sees moving (a fresh position) to every link,
unless some vehicle reported it within REPORTED_FOR: its team already hears it
first-hand, and a relay, a few tens of milliseconds older, would only blur it.
A vehicle's own report reaches it too: agents ignore their own address. The
reports go to the agents' direct links (``vehicle agent --gcs``), where an
agent takes them from a ground station; ArduPilot does not forward them from
the station's port to its companion's.
"""

from __future__ import annotations

import math

from groundstation.state import Fleet
from vehicle.protocol.traffic import adsb_report

RELAY_PERIOD = 0.05  # s of wall time between two rounds of reports (20 Hz: half a second of a 10-times-fast SITL)
FRESH_FOR = 1.0  # s: a vehicle whose last position is older is not reported (its link went quiet)
REPORTED_FOR = 3.0  # s a vehicle's own team's report of a team-mate stands in for the relay


def relay_reports(fleet: Fleet, now: float) -> list:
    """The ADSB_VEHICLE messages to send now: one per vehicle with a fresh position that no vehicle reports,
    when there are two vehicles or more to tell each other."""
    with fleet.lock:
        if len(fleet.vehicles) < 2:
            return []
        reports = []
        for sysid, v in fleet.vehicles.items():
            if v.positioned is None or now - v.positioned > FRESH_FOR:
                continue
            if now - fleet.reported.get(sysid, -math.inf) <= REPORTED_FOR:
                continue
            reports.append(adsb_report(sysid, v.lat, v.lon, v.alt_msl, *v.velocity, math.degrees(v.yaw)))
        return reports
