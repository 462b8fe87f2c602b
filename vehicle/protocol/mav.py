"""pymavlink, set up once for the whole project: MAVLink 2 and the ardupilotmega dialect.

pymavlink chooses the wire version and dialect when ``mavutil`` is first
imported and when ``set_dialect`` runs, process-wide; importing it through
this module makes every part of the project (and a test) agree. ``mavlink``
(the dialect: messages and constants) loads at once; ``mavutil``
(connections, mode tables) on first use, since a headless run needs no link
and mavutil costs a command-line run a tenth of a second.
"""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402 - must follow the environment setting


def __getattr__(name: str):
    if name == "mavutil":
        from pymavlink import mavutil

        mavutil.set_dialect("ardupilotmega")  # the module ``mavlink`` above, as every part of the project uses
        assert mavutil.mavlink is mavlink
        return mavutil
    raise AttributeError(name)



def pack(message, packer) -> bytes:
    """The message's bytes from ``packer`` (a MAVLink instance), advancing its sequence number.

    pymavlink's ``message.pack`` does not count: only ``MAVLink.send`` does, and
    that wants a file to write to. Receivers detect loss from the sequence.
    """
    packet = message.pack(packer)
    packer.seq = (packer.seq + 1) % 256
    return packet


__all__ = ["mavlink", "pack"]  # and mavutil, on first use
