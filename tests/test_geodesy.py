"""Scene metres <-> WGS84 and compass-heading helpers (vehicle.geodesy)."""

import math

import pytest

from vehicle.protocol.geodesy import METRES_PER_DEGE7, Datum, heading_of, heading_vector, wrap_pi

POINTS = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (-40.0, 0.0), (123.456, -987.654), (-2500.0, 3100.0), (1e4, 1e4)]


def test_the_default_datum_is_the_ardupilot_simulator_home():
    assert Datum() == Datum(-35.363261, 149.165230, 584.0)


@pytest.mark.parametrize(("x", "y"), POINTS)
def test_to_global_and_to_local_round_trip_within_a_millimetre(x, y):
    datum = Datum()
    back = datum.to_local(*datum.to_global(x, y))
    assert math.dist(back, (x, y)) < 1e-3


@pytest.mark.parametrize("datum", [Datum(51.5, -0.12), Datum(0.0, 0.0), Datum(-89.9, 10.0), Datum(70.0, 179.9)])
def test_round_trip_holds_at_other_datums(datum):
    for x, y in POINTS:
        assert math.dist(datum.to_local(*datum.to_global(x, y)), (x, y)) < 1e-3


def test_the_origin_is_the_datum():
    datum = Datum(10.0, 20.0, 5.0)
    assert datum.to_global(0.0, 0.0) == (10.0, 20.0)
    assert datum.to_local(10.0, 20.0) == (0.0, 0.0)


def test_one_metre_north_is_about_8_98e_6_degrees_of_latitude():
    datum = Datum()
    lat, lon = datum.to_global(0.0, 1.0)
    assert lat - datum.lat == pytest.approx(8.983e-6, rel=1e-3)
    assert lon == datum.lon
    assert 1e-7 / METRES_PER_DEGE7 == pytest.approx(8.983e-6, rel=1e-3)


def test_one_metre_east_is_more_longitude_away_from_the_equator():
    datum = Datum()
    lat, lon = datum.to_global(1.0, 0.0)
    assert lat == datum.lat
    assert lon - datum.lon == pytest.approx(8.983e-6 / math.cos(math.radians(datum.lat)), rel=1e-3)


def test_north_is_plus_y_and_east_is_plus_x():
    datum = Datum()
    lat, lon = datum.to_global(-3.0, 5.0)
    assert lat > datum.lat and lon < datum.lon


def test_datum_parse():
    assert Datum.parse("-35.1,149.2") == Datum(-35.1, 149.2, 584.0)
    assert Datum.parse("1,2,3") == Datum(1.0, 2.0, 3.0)
    with pytest.raises(ValueError):
        Datum.parse("1")
    with pytest.raises(ValueError):
        Datum.parse("1,2,3,4")


@pytest.mark.parametrize("text", ["north,east", "91,0", "0,181", "nan,0", ""])
def test_a_bad_datum_is_refused_with_a_reason(text):
    with pytest.raises(ValueError, match="datum is LAT,LON|latitude must be"):
        Datum.parse(text)


def test_a_scene_datum_comes_from_the_command_line_then_the_scene_then_the_default():
    assert Datum.of_scene({}) == Datum()
    assert Datum.of_scene({"datum": "47.4,8.5,410"}) == Datum(47.4, 8.5, 410.0)
    assert Datum.of_scene({"datum": "47.4,8.5"}, Datum(1.0, 2.0, 3.0)) == Datum(1.0, 2.0, 3.0)
    with pytest.raises(ValueError, match="the scene's datum hint"):
        Datum.of_scene({"datum": "here"})


@pytest.mark.parametrize(("degrees", "vector"), [(0, (0, 1)), (90, (1, 0)), (180, (0, -1)), (270, (-1, 0)),
                                                 (45, (math.sqrt(0.5), math.sqrt(0.5)))])
def test_heading_vector_is_compass_east_north(degrees, vector):
    assert heading_vector(math.radians(degrees)) == pytest.approx(vector, abs=1e-12)


@pytest.mark.parametrize(("dx", "dy", "degrees"), [(0, 1, 0), (1, 0, 90), (0, -1, 180), (-1, 0, 270), (1, 1, 45),
                                                   (-1, 1, 315), (-1e-9, 1, 360)])
def test_heading_of_is_a_compass_heading_in_0_to_2pi(dx, dy, degrees):
    heading = heading_of(dx, dy)
    assert 0.0 <= heading < 2 * math.pi
    assert math.degrees(heading) == pytest.approx(degrees, abs=1e-6)


@pytest.mark.parametrize("degrees", [0, 10, 89, 135, 200, 359])
def test_heading_of_inverts_heading_vector(degrees):
    assert math.degrees(heading_of(*heading_vector(math.radians(degrees)))) == pytest.approx(degrees)


@pytest.mark.parametrize(("angle", "wrapped"), [(0.0, 0.0), (math.pi / 2, math.pi / 2), (1.5 * math.pi, -math.pi / 2),
                                                (-1.5 * math.pi, math.pi / 2), (math.pi, -math.pi),
                                                (5 * math.pi + 0.1, -math.pi + 0.1), (-0.1, -0.1)])
def test_wrap_pi_gives_the_signed_shortest_turn(angle, wrapped):
    result = wrap_pi(angle)
    assert -math.pi <= result < math.pi
    assert result == pytest.approx(wrapped, abs=1e-12)
