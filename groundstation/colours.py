"""Each vehicle's colour, by system id, in one place: the 3D view, its trail and the page's panel agree."""

from __future__ import annotations

PALETTE = [(64, 156, 255), (255, 140, 40), (80, 210, 110), (230, 90, 220), (70, 220, 225), (250, 110, 130),
           (180, 150, 255), (200, 220, 60), (255, 190, 150), (150, 200, 255)]


def colour(sysid: int) -> tuple[int, int, int]:
    """The same sysid always gets the same colour, however many vehicles come and go."""
    return PALETTE[(int(sysid) - 1) % len(PALETTE)]

