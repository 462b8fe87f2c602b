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

# Who is who in a vehicle's system: the flight controller, and the onboard agent on its companion computer.
AUTOPILOT = mavlink.MAV_COMP_ID_AUTOPILOT1  # 1
COMPANION = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191

# A COMMAND_ACK's result, as the simulated autopilot, its endpoint and the agent answer and read it.
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
TEMPORARILY_REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
FAILED = mavlink.MAV_RESULT_FAILED
# MAV_RESULT values MAVLink defines (common.xml) that pymavlink 2.4.50's generated dialects lack (no 6, and 9 is
# their ENUM_END): CANCELLED answers a long command stopped by COMMAND_CANCEL.
MAV_RESULT_CANCELLED = getattr(mavlink, "MAV_RESULT_CANCELLED", 6)
MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME = getattr(mavlink, "MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME", 9)
RESULT_WORDS = {  # a COMMAND_ACK's result as the operator reads it (every MAV_RESULT MAVLink defines)
    mavlink.MAV_RESULT_ACCEPTED: "accepted", mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink.MAV_RESULT_DENIED: "denied", mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed", mavlink.MAV_RESULT_IN_PROGRESS: "in progress",
    MAV_RESULT_CANCELLED: "cancelled",
    mavlink.MAV_RESULT_COMMAND_LONG_ONLY: "COMMAND_LONG only", mavlink.MAV_RESULT_COMMAND_INT_ONLY: "COMMAND_INT only",
    MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME: "unsupported frame",
}
COMMAND_NAMES = {value: name.removeprefix("MAV_CMD_").lower() for name, value in vars(mavlink).items()
                 if name.startswith("MAV_CMD_") and isinstance(value, int)}  # 22: "nav_takeoff"
NO_ANSWER = -1  # what a command returns when the autopilot never acknowledged it


def refusal(command: int, result: int) -> str:
    """A command the flight controller refused (or never answered), as the operator reads it."""
    words = "no answer" if result == NO_ANSWER else RESULT_WORDS.get(result, result)
    return f"flight controller: {COMMAND_NAMES.get(command, command)} {words}"


def __getattr__(name: str):
    if name == "mavutil":
        from pymavlink import mavutil

        mavutil.set_dialect("ardupilotmega")  # the module ``mavlink`` above, as every part of the project uses
        assert mavutil.mavlink is mavlink
        globals()["mavutil"] = mavutil  # found directly from now on (this runs on first use only)
        return mavutil
    raise AttributeError(name)



def from_wire(message_class, row):
    """A pymavlink message of ``message_class`` from one row of a numpy array of its payloads (fields named as
    pymavlink names them), so that one vectorised encoder serves a single message and a batch of thousands."""
    return message_class(**{name: row[name].tolist() for name in row.dtype.names})


def pack(message, packer) -> bytes:
    """The message's bytes from ``packer`` (a MAVLink instance), advancing its sequence number.

    pymavlink's ``message.pack`` does not count: only ``MAVLink.send`` does, and
    that wants a file to write to. Receivers detect loss from the sequence.
    """
    packet = message.pack(packer)
    packer.seq = (packer.seq + 1) % 256
    return packet


__all__ = ["ACCEPTED", "AUTOPILOT", "COMMAND_NAMES", "COMPANION", "DENIED", "FAILED", "RESULT_WORDS",
           "TEMPORARILY_REJECTED", "UNSUPPORTED", "from_wire", "mavlink", "pack"]  # and mavutil, on first use
