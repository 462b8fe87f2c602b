"""The simulated radios (vehicle.world.radio): walls, targets, noise, loss, quantisation and the slot schedule."""

from __future__ import annotations

import math

import numpy as np
import pytest
from harness import WALL_Y, small_scene

from vehicle.cli import main as vehicle_main
from vehicle.world.radio import RadioChannel, RadioModel, parse_nodes, parse_targets
from vehicle.world.scene import parse_scene

QUIET = dict(shadowing_sigma_db=0.0, noise_sigma_db=0.0, rss_step_db=0.0, packet_loss=0.0)


def test_a_wall_costs_what_the_setting_says():
    """The same 7 m, through the small scene's wall (0.5 m thick: one wall, two faces) and in the open."""
    for loss in (5.0, 12.5):
        channel = RadioChannel(small_scene(), RadioModel(wall_loss_db=loss, **QUIET))
        through = channel.mean_rss((0, WALL_Y - 3, 2), [(0, WALL_Y + 4, 2)], [])[0]
        open_air = channel.mean_rss((-5, -3, 2), [(-5, 4, 2)], [])[0]
        assert channel.walls((0, WALL_Y - 3, 2), (0, WALL_Y + 4, 2)) == 1
        assert open_air - through == pytest.approx(loss)
        assert open_air == pytest.approx(-40.0 - 20 * math.log10(7))  # log-distance, exponent 2, -40 dBm at 1 m


def test_a_closed_building_is_two_walls_and_the_line_over_it_none():
    scene = parse_scene("#VRML V2.0 utf8\nTransform { translation 0 0 1.5 children Shape { geometry Box "
                        "{ size 4 4 3 } } }")
    channel = RadioChannel(scene, RadioModel(**QUIET))
    assert channel.walls((-5, 0, 1), (5, 0, 1)) == 2  # in and out
    assert channel.walls((5, 0, 1), (-5, 0, 1)) == 2
    assert channel.walls((-5, 0, 4), (5, 0, 4)) == 0  # over the roof
    assert channel.walls((0, 0, 1), (5, 0, 1)) == 1  # from inside, out
    assert channel.walls((-5, 0, 1), (-3, 0, 1)) == 0  # short of it


def test_a_target_near_the_line_attenuates_one_far_does_not():
    model = RadioModel(target_loss_db=6.0, target_radius_m=0.3, target_fringe_m=0.2, **QUIET)
    channel = RadioChannel(None, model)
    a, b = (0, 0, 1), [(10, 0, 1)]
    empty = channel.mean_rss(a, b, [])[0]

    def loss(target):
        return empty - channel.mean_rss(a, b, [target])[0]

    assert loss((5, 0)) == pytest.approx(6.0)  # on the line
    assert loss((5, 0.29)) == pytest.approx(6.0)  # within the radius
    assert loss((5, 0.5)) == pytest.approx(6.0 * math.exp(-0.5))  # one fringe past it
    assert 0 < loss((5, 0.7)) < loss((5, 0.5))
    assert loss((5, 3.0)) < 1e-6  # far
    assert loss((-2, 0)) < 1e-6  # on the line's extension, behind a radio: not between them
    assert loss((5, 0), ) + loss((5, 0)) == pytest.approx(empty - channel.mean_rss(a, b, [(4, 0), (6, 0)])[0])


def _packets(model: RadioModel, seconds: float = 200.0, seed: int = 3) -> list:
    channel = RadioChannel(None, model, seed)
    return channel.measure(0.0, seconds, {1: (0, 0, 1), 2: (6, 0, 1)}, [])


def test_noise_loss_and_quantisation_have_the_stated_statistics():
    sent = 200.0 * 5 * 2  # seconds x rounds a second x radios (each heard by the other)
    plain = _packets(RadioModel(shadowing_sigma_db=0.0, rss_step_db=0.0, packet_loss=0.0))
    rss = np.array([r.rssi for r in plain])
    assert len(rss) == sent
    assert rss.std() == pytest.approx(0.7, rel=0.05)
    assert rss.mean() == pytest.approx(-40 - 20 * math.log10(6), abs=0.05)

    lossy = _packets(RadioModel())  # the defaults: 6 % lost, whole dBm
    assert 1 - len(lossy) / sent == pytest.approx(0.06, abs=0.012)
    values = np.array([r.rssi for r in lossy])
    assert np.all(values == np.round(values))
    assert len(set(values.tolist())) >= 4  # the noise still shows through the steps

    coarse = _packets(RadioModel(rss_step_db=2.5, packet_loss=0.0))
    assert np.allclose(np.array([r.rssi for r in coarse]) / 2.5, np.round(np.array([r.rssi for r in coarse]) / 2.5))


def test_weak_packets_are_lost():
    far = RadioChannel(None, RadioModel(**QUIET, sensitivity_dbm=-60.0))
    assert far.measure(0, 1, {1: (0, 0, 1), 2: (200, 0, 1)}, []) == []  # -86 dBm at 200 m
    assert len(far.measure(0, 1, {1: (0, 0, 1), 2: (5, 0, 1)}, [])) == 10


def test_static_shadowing_is_per_link_both_ways_and_a_property_of_the_place():
    model = RadioModel(noise_sigma_db=0.0, rss_step_db=0.0, packet_loss=0.0, shadowing_sigma_db=3.0)
    one, other = RadioChannel(None, model, seed=1), RadioChannel(None, model, seed=99)
    offsets = [one.shadowing(1, k) for k in range(2, 300)]
    assert np.std(offsets) == pytest.approx(3.0, rel=0.15)
    assert one.shadowing(1, 2) == one.shadowing(2, 1) == other.shadowing(1, 2)
    assert RadioChannel(None, model.model_copy(update={"shadowing_seed": 5})).shadowing(1, 2) != one.shadowing(1, 2)


def test_radios_transmit_in_turn_in_their_slots():
    model = RadioModel(**QUIET, slots_per_round=4, rounds_per_second=5)  # 50 ms slots, 200 ms rounds
    channel = RadioChannel(None, model)
    radios = {7: (0, 0, 1), 3: (4, 0, 1), 201: (0, 4, 1)}
    records = channel.measure(0.0, 1.0, radios, [])
    assert len(records) == 5 * 3 * 2  # 5 rounds, 3 senders, 2 receivers each
    for r in records:
        k = sorted(radios).index(r.tx)
        assert (r.t - 0.05 * k) / 0.2 == pytest.approx(round((r.t - 0.05 * k) / 0.2))  # slot k of a round
        assert r.rx != r.tx and (r.tx_x, r.tx_y) == radios[r.tx][:2] and (r.rx_x, r.rx_y) == radios[r.rx][:2]
    halves = channel.measure(0.0, 0.5, radios, []) + channel.measure(0.5, 1.0, radios, [])
    assert [(r.t, r.tx, r.rx) for r in halves] == [(r.t, r.tx, r.rx) for r in records]  # no slot twice or lost
    with pytest.raises(ValueError, match="5 radios, but a round has 4 slots"):
        channel.measure(0, 1, {k: (k, 0, 1) for k in range(5)}, [])


def test_targets_and_nodes_parse_or_say_what_is_wrong(tmp_path):
    assert parse_targets("1,2;-3.5,4") == [(1.0, 2.0), (-3.5, 4.0)]
    for bad, words in (("1", "is not X,Y"), ("1,nan", "is not X,Y"), ("", "no target"), ("1,2,3", "is not X,Y"),
                       ("a,b", "is not X,Y"), ("1e9,0", "over 100 km")):
        with pytest.raises(ValueError, match=words):
            parse_targets(bad)
    nodes = tmp_path / "nodes.txt"
    nodes.write_text("# two nodes\n-5,0\n5,0,2.5\n\n", encoding="utf-8")
    assert parse_nodes(f"@{nodes}") == [(-5.0, 0.0, 1.0), (5.0, 0.0, 2.5)]
    assert parse_nodes("1,2") == [(1.0, 2.0, 1.0)]
    with pytest.raises(ValueError, match="none.txt: No such file or directory$"):
        parse_nodes(f"@{tmp_path / 'none.txt'}")


def test_radio_options_are_checked_before_anything_flies(capsys):
    with pytest.raises(SystemExit) as exit_:
        vehicle_main(["experiment", "--mission", "rti", "--targets", "1;2"])
    assert exit_.value.code == 2
    assert "target '1' is not X,Y" in capsys.readouterr().err
    assert vehicle_main(["experiment", "--mission", "rti", "--radio", "wall_loss_db=-3"]) == 2
    assert "radio wall_loss_db" in capsys.readouterr().err
    assert vehicle_main(["experiment", "--mission", "rti", "--radio", "walls=3"]) == 2
    assert "unknown radio setting walls" in capsys.readouterr().err
