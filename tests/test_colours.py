"""Each vehicle keeps its colour by system id (the 3D view, its trail and the panel use the same)."""

from groundstation.colours import PALETTE, colour


def test_a_colour_per_system_id_repeating_after_ten():
    assert colour(1) == (64, 156, 255) and colour(2) == (255, 140, 40)
    assert len({colour(sysid) for sysid in range(1, 11)}) == 10 == len(PALETTE)
    assert colour(11) == colour(1) and colour(255) == colour(5)
