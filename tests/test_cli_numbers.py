"""Numbers on both command lines (vehicle.options): a bad one is a usage error naming its option.

Each case below started something before: a socket's OverflowError (port 70000), a vehicle no station shows
(system id 0, MAVLink's broadcast address) or a struct error (300), a simulation standing still (speed-up 0
or NaN), a copter spinning for good (heading NaN), a demo of vehicles stacked on each other (more than its
spots), a sweep of nothing (0 seeds).
"""

import argparse

import pytest

from groundstation.cli import main as groundstation
from vehicle import options
from vehicle.cli import main as vehicle


@pytest.mark.parametrize("args, option", [
    (["sim", "--mission", "browse", "--speedup", "nan"], "--speedup"),
    (["sim", "--mission", "browse", "--speedup", "0"], "--speedup"),
    (["sim", "--mission", "browse", "--speedup", "-1"], "--speedup"),
    (["sim", "--mission", "browse", "--speedup", "inf"], "--speedup"),
    (["sim", "--mission", "browse", "--sysid", "0"], "--sysid"),
    (["sim", "--mission", "browse", "--sysid", "256"], "--sysid"),
    (["sim", "--mission", "browse", "--sysid", "1.5"], "--sysid"),
    (["sim", "--mission", "browse", "--failsafe-timeout", "nan"], "--failsafe-timeout"),
    (["sim", "--mission", "browse", "--duration", "-1"], "--duration"),
    (["experiment", "--mission", "browse", "--heading", "nan"], "--heading"),
    (["experiment", "--mission", "browse", "--altitude", "inf"], "--altitude"),
    (["experiment", "--mission", "browse", "--time-limit", "nan"], "--time-limit"),
    (["experiment", "--mission", "browse", "--seed", "-1"], "--seed"),
    (["agent", "--mission", "browse", "--connect", "udpin:127.0.0.1:14550", "--connect-timeout", "0"],
     "--connect-timeout"),
    (["sweep", "--seeds", "0"], "--seeds"),
    (["sweep", "--workers", "0"], "--workers"),
])
def test_a_bad_number_for_a_vehicle_is_a_usage_error_naming_the_option(args, option, capsys):
    with pytest.raises(SystemExit) as exit_:
        vehicle(args)
    assert exit_.value.code == 2
    assert f"argument {option}: expected" in capsys.readouterr().err


@pytest.mark.parametrize("args, option", [
    (["demo", "--vehicles", "0"], "--vehicles"),
    (["demo", "--vehicles", "9"], "--vehicles"),  # eight spots in the demo scene; a ninth stood on the first
    (["demo", "--speedup", "nan"], "--speedup"),
    (["demo", "--port", "99999"], "--port"),
    (["demo", "--mavlink-port", "70000"], "--mavlink-port"),
    (["serve", "--port", "-1"], "--port"),
])
def test_a_bad_number_for_the_station_is_a_usage_error_naming_the_option(args, option, capsys):
    with pytest.raises(SystemExit) as exit_:
        groundstation(args)
    assert exit_.value.code == 2
    assert f"argument {option}: expected" in capsys.readouterr().err


def test_the_checks_keep_what_is_good_and_say_what_they_wanted():
    assert options.finite("-12.5") == -12.5 and options.positive("1e9") == 1e9
    assert options.port("65535") == 65535 and options.system_id("1") == 1 and options.whole(0)("0") == 0
    for parse, text, wanted in [(options.finite, "nan", "a number"), (options.positive, "0", "above 0"),
                                (options.port, "0", "1 to 65535"), (options.whole(1), "x", "1 or more")]:
        with pytest.raises(argparse.ArgumentTypeError, match=wanted):
            parse(text)
