"""Numbers on the command line, checked as argparse parses them (both programs use these).

A typo or an absurd value is a usage error naming the option, before anything
starts: never a traceback from a socket (port 70000), a vehicle no station
shows (system id 0, MAVLink's broadcast address), or a simulation that stands
still (a speed-up of 0 or NaN). A point that starts with a minus sign
(``--start -40,0``, ``--datum -35.36,149.17``) is taken as the value it is, not
as an option (``glue_negative_points``).
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable, Sequence


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


def link_url(text: str) -> str:
    """A MAVLink link's URL that ``vehicle.protocol.links.connect`` can open (pymavlink loads only when the
    option is given: help stays fast)."""
    from vehicle.protocol.links import check_url

    try:
        check_url(text)
        return text
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


# their values are comma-separated numbers (X,Y[,Z], LAT,LON[,ALT], X0,Y0,X1,Y1, X,Y[;X,Y...])
POINT_OPTIONS = ("--start", "--datum", "--bounds", "--targets", "--radio-nodes")
_NEGATIVE = re.compile(r"-\.?\d")


def glue_negative_points(argv: Sequence[str]) -> list[str]:
    """``argv`` with a point that starts with a minus sign joined to its option (``--start -40,0`` becomes
    ``--start=-40,0``, as does ``--sta -40,0``, argparse's abbreviation): argparse takes a plain number such as
    ``-40`` for a value, but ``-40,0`` for an option, and said "expected one argument", with no hint, to a start
    west of the origin or a datum south of the equator (ArduPilot's simulator home among them). Nothing after
    ``--`` is touched."""
    out: list[str] = []
    for index, arg in enumerate(argv):
        if arg == "--":
            return out + list(argv[index:])
        if out and _names_a_point_option(out[-1]) and _NEGATIVE.match(arg):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def _names_a_point_option(arg: str) -> bool:
    """``--start`` or ``--datum``, or an abbreviation of one (argparse says which when it is ambiguous)."""
    return arg.startswith("--") and len(arg) > 2 and "=" not in arg and any(o.startswith(arg) for o in POINT_OPTIONS)


def targets_option(text: str) -> list[tuple[float, float]]:
    """``X,Y[;X,Y...]``: radio tomography targets (people) in scene metres."""
    from vehicle.world.radio import parse_targets

    try:
        return parse_targets(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def radio_nodes_option(text: str) -> list[tuple[float, float, float]]:
    """``X,Y[,Z][;...]`` or ``@FILE``: fixed radio nodes in scene metres."""
    from vehicle.world.radio import parse_nodes

    try:
        return parse_nodes(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_radio_options(parser: argparse.ArgumentParser) -> None:
    """The simulated radios' options (``vehicle sim``, ``vehicle experiment``, ``groundstation demo``): one
    definition, so the three take the same text."""
    parser.add_argument("--targets", type=targets_option, metavar="X,Y[;X,Y...]",
                        help="radio tomography targets (people, cylinders the radios' links pass through) in scene "
                             "metres; a simulated vehicle then carries a radio")
    parser.add_argument("--radio-nodes", type=radio_nodes_option, metavar="X,Y[,Z][;...]|@FILE",
                        help="fixed radio nodes in scene metres (Z: height, default 1 m), or a file of one X,Y[,Z] "
                             "a line; fixed node k has the radio id 200 + k")
    parser.add_argument("--radio", dest="radio_settings", action="append", default=[], metavar="NAME=VALUE",
                        help="a radio model setting (vehicle.world.radio.RadioModel: power_dbm, path_loss_exponent, "
                             "wall_loss_db, target_loss_db, noise_sigma_db, packet_loss, ...; repeatable); the "
                             "vehicles carry radios when any radio option is given, or the mission is rti")
