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



def pack(message, packer) -> bytes:
    """The message's bytes from ``packer`` (a MAVLink instance), advancing its sequence number.

    pymavlink's ``message.pack`` does not count: only ``MAVLink.send`` does, and
    that wants a file to write to. Receivers detect loss from the sequence.
    """
    packet = message.pack(packer)
    packer.seq = (packer.seq + 1) % 256
    return packet


__all__ = ["mavlink", "mavutil", "pack"]
