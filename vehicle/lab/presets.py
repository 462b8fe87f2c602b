"""Named sweeps (``vehicle sweep --preset``) and the thesis's Table 1 they are compared with.

Kept apart from the sweep runner so that the command line lists them without loading the simulation.
"""

from __future__ import annotations

from pathlib import Path

from vehicle.world.bundled import scenes_dir

# the thesis's castle, where a checkout sits beside the shared test material (else the default scene stands in)
CASTLE = Path(__file__).resolve().parents[3] / "shared" / "scenes" / "castle.wrl"

# Table 1 of the thesis: best memory-map counts (the Square runs all collided)
THESIS_TABLE = {
    "square": {"castle": 6, "trees": 7, "house": 11},
    "browse": {"castle": 13, "trees": 49, "house": 68},
    "search": {"castle": 140, "trees": 65, "house": 258},
    "pathfind": {"castle": 74, "trees": 37, "house": 109},
}


def _thesis_scenes() -> list[str]:
    castle = f"{CASTLE}@-40,0" if CASTLE.exists() else str(scenes_dir() / "default.wrl")
    return [castle, str(scenes_dir() / "trees.wrl"), str(scenes_dir() / "house.wrl")]


THESIS_GRID = {"padding": [0.1, 2, 4], "resolution": [1, 10], "space_size": [10, 100],
               "closeness": [0.1, 2], "monitor_period": [0.25, 0.5]}

PRESETS = {
    "thesis": {
        "help": "the thesis's sweep: 48 settings x 4 missions x 3 scenes = 576 runs",
        "missions": ["square", "browse", "search", "pathfind"],
        "scenes": _thesis_scenes,
        "grid": THESIS_GRID,
    },
    "indoor": {
        "help": "the thesis's 48 settings x 4 missions in the project's indoor scenes (house, apartment) = 384 runs",
        "missions": ["square", "browse", "search", "pathfind"],
        "scenes": lambda: [str(scenes_dir() / "house.wrl"), str(scenes_dir() / "apartment.wrl")],
        "grid": THESIS_GRID,
    },
    "quick": {
        "help": "a small smoke sweep: 2 missions x the default scene x 2 paddings",
        "missions": ["browse", "pathfind"],
        "scenes": lambda: [str(scenes_dir() / "default.wrl")],
        "grid": {"padding": [0.1, 0.5]},
    },
}
