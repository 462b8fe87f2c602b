"""pymavlink, set up once for the whole project: MAVLink 2 and the ardupilotmega dialect.

pymavlink chooses the wire version and dialect when ``mavutil`` is first
imported and when ``set_dialect`` runs, process-wide; importing it through
this module makes every part of the project (and a test) agree.
"""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402 - must follow the environment setting

mavutil.set_dialect("ardupilotmega")
mavlink = mavutil.mavlink

__all__ = ["mavlink", "mavutil"]
