"""Numbers on both command lines (vehicle.options): a bad one is a usage error naming its option; and
options that exclude each other.

Each case below started something before: a socket's OverflowError (port 70000), a vehicle no station shows
(system id 0, MAVLink's broadcast address) or a struct error (300), a simulation standing still (speed-up 0
or NaN), a copter spinning for good (heading NaN), a demo of vehicles stacked on each other (more than its
spots), a sweep of nothing (0 seeds).
"""

import argparse
import json

import pytest

from groundstation.cli import main as groundstation
from vehicle import options
from vehicle.cli import main as vehicle


@pytest.mark.parametrize("main, args, option", [
    (vehicle, ["sim", "--mission", "browse", "--speedup", "nan"], "--speedup"),
    (vehicle, ["sim", "--mission", "browse", "--speedup", "0"], "--speedup"),
    (vehicle, ["sim", "--mission", "browse", "--speedup", "-1"], "--speedup"),
    (vehicle, ["sim", "--mission", "browse", "--speedup", "inf"], "--speedup"),
    (vehicle, ["sim", "--mission", "browse", "--sysid", "0"], "--sysid"),
    (vehicle, ["sim", "--mission", "browse", "--sysid", "256"], "--sysid"),
    (vehicle, ["sim", "--mission", "browse", "--sysid", "1.5"], "--sysid"),
    (vehicle, ["sim", "--mission", "browse", "--failsafe-timeout", "nan"], "--failsafe-timeout"),
    (vehicle, ["sim", "--mission", "browse", "--duration", "-1"], "--duration"),
    (vehicle, ["experiment", "--mission", "browse", "--heading", "nan"], "--heading"),
    (vehicle, ["experiment", "--mission", "browse", "--altitude", "inf"], "--altitude"),
    (vehicle, ["experiment", "--mission", "browse", "--time-limit", "nan"], "--time-limit"),
    (vehicle, ["experiment", "--mission", "browse", "--seed", "-1"], "--seed"),
    (vehicle, ["agent", "--mission", "browse", "--connect", "udpin:127.0.0.1:14550", "--connect-timeout", "0"],
     "--connect-timeout"),
    (vehicle, ["sweep", "--seeds", "0"], "--seeds"),
    (vehicle, ["sweep", "--workers", "0"], "--workers"),
    (groundstation, ["demo", "--vehicles", "0"], "--vehicles"),
    (groundstation, ["demo", "--vehicles", "9"], "--vehicles"),  # eight spots in the demo scene: a ninth on the first
    (groundstation, ["demo", "--speedup", "nan"], "--speedup"),
    (groundstation, ["demo", "--port", "99999"], "--port"),
    (groundstation, ["demo", "--mavlink-port", "70000"], "--mavlink-port"),
    (groundstation, ["serve", "--port", "-1"], "--port"),
])
def test_a_bad_number_is_a_usage_error_naming_the_option(main, args, option, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    assert f"argument {option}: expected" in capsys.readouterr().err


@pytest.mark.parametrize("args", [["sim"], ["sim", "--role", "autopilot", "--mission", "browse"]])
def test_a_simulated_vehicle_is_either_one_with_a_mission_or_a_plain_autopilot(args, capsys):
    """With both, --mission was ignored in silence: the plain autopilot flew nothing."""
    assert vehicle(args) == 2
    assert "vehicle sim: --mission NAME (a vehicle with its onboard agent) or --role autopilot" in \
        capsys.readouterr().err


def test_the_checks_keep_what_is_good_and_say_what_they_wanted():
    assert options.finite("-12.5") == -12.5 and options.positive("1e9") == 1e9
    assert options.port("65535") == 65535 and options.system_id("1") == 1 and options.whole(0)("0") == 0
    for parse, text, wanted in [(options.finite, "nan", "a number"), (options.positive, "0", "above 0"),
                                (options.port, "0", "1 to 65535"), (options.whole(1), "x", "1 or more")]:
        with pytest.raises(argparse.ArgumentTypeError, match=wanted):
            parse(text)


def test_a_point_west_of_the_origin_or_south_of_the_equator_is_a_value_not_an_option(capsys):
    """``--start -40,0`` and ``--datum -35.36,149.17`` (ArduPilot's simulator home) were "expected one argument":
    argparse takes ``-40,0`` for an option, as only a plain number may start with a minus sign."""
    assert vehicle(["experiment", "--mission", "browse", "--sta", "-5,-3", "--datum", "-35.363261,149.16523,584",
                    "--json"]) == 0  # --sta: argparse's abbreviation of --start
    flown = json.loads(capsys.readouterr().out)
    assert flown["start"] == [-5.0, -3.0] and flown["outcome"] == "finished"
    with pytest.raises(SystemExit):
        vehicle(["experiment", "--mission", "browse", "--start", "-5"])
    assert "argument --start: expected X,Y or X,Y,Z, not '-5'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        groundstation(["serve", "--datum", "-91,0"])
    said = capsys.readouterr().err
    assert "argument --datum:" in said and "expected one argument" not in said  # the value reached its check
    assert options.glue_negative_points(["--start", "-1,2", "--heading", "-90", "--datum", "-.5,1", "-h"]) == \
        ["--start=-1,2", "--heading", "-90", "--datum=-.5,1", "-h"]
    assert options.glue_negative_points(["--sta", "-1,2", "--start", "--json", "--", "--start", "-3,4"]) == \
        ["--sta=-1,2", "--start", "--json", "--", "--start", "-3,4"]
    assert options.glue_negative_points(["--bounds", "-1,-2,3,4", "--targets", "-1,2;3,-4"]) == \
        ["--bounds=-1,-2,3,4", "--targets=-1,2;3,-4"]


@pytest.mark.parametrize("main, args, option", [
    (vehicle, ["agent", "--mission", "browse", "--connect", "bogus://"], "--connect"),
    (vehicle, ["agent", "--mission", "browse", "--connect", "udpin:127.0.0.1:14550", "--gcs", "tcp:host"], "--gcs"),
    (vehicle, ["sim", "--mission", "browse", "--mavlink", "udpin:127.0.0.1"], "--mavlink"),
    (groundstation, ["serve", "--mavlink", "http://127.0.0.1:14550"], "--mavlink"),
])
def test_a_link_url_that_names_no_link_is_a_usage_error_naming_the_option(main, args, option, capsys):
    """The agent waited out its connect timeout and then failed with exit code 1 ("error - not a MAVLink link"),
    a station or a simulated vehicle stopped with a plain error: a mistyped URL is a usage error, at once."""
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    said = capsys.readouterr().err
    assert f"argument {option}: " in said and ("HOST:PORT" in said or "not a MAVLink link" in said)
