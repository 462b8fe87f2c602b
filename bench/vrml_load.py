"""Time VRML loading: the castle scene (when ../shared is there) and a synthesised 250 KB file.

Usage: /work/venv/bin/python bench/vrml_load.py
Target: a 250 KB file loads in well under 0.2 s. "parse" is text -> node tree (vehicle.vrml);
"load" adds triangulation and transforms (vehicle.scene). Best of several runs.
"""

import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # run as a plain script from anywhere

from vehicle.world import vrml  # noqa: E402
from vehicle.world.scene import load_scene, parse_scene  # noqa: E402

CASTLE = REPO.parent / "shared" / "scenes" / "castle.wrl"
GRID = 10  # points per side of each synthetic shape


def best_of(run: Callable[[], object], repeat: int = 7) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def synthetic_shape(index: int, rng: np.random.Generator) -> str:
    """A Blender-style Transform > Shape > IndexedFaceSet: a bumpy grid of quads and one U-shaped wall."""
    x, y = np.meshgrid(np.arange(GRID, dtype=float), np.arange(GRID, dtype=float))
    points = np.column_stack((x.ravel(), y.ravel(), rng.normal(0, 0.2, GRID * GRID)))
    u_shape = [[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]]
    points = np.vstack((points, [[px, 0.0, pz] for px, pz in u_shape]))
    point_text = "\n".join(" ".join(f"{v:.6f}" for v in p) + "," for p in points)
    quads = [
        f"{j * GRID + i} {j * GRID + i + 1} {(j + 1) * GRID + i + 1} {(j + 1) * GRID + i} -1,"
        for j in range(GRID - 1)
        for i in range(GRID - 1)
    ]
    quads.append(" ".join(str(GRID * GRID + k) for k in range(len(u_shape))) + " -1")
    return (
        f"DEF OB_{index} Transform {{\n"
        f"translation {index % 10 * 12} {index // 10 * 12} 0\nrotation 0 0 1 {0.1 * index:.3f}\n"
        "children [ Shape {\n"
        "appearance Appearance { material Material { diffuseColor 0.6 0.5 0.4 } }\n"
        f"geometry IndexedFaceSet {{ coord Coordinate {{ point [\n{point_text}\n] }}\n"
        f"coordIndex [\n" + "\n".join(quads) + "\n] }\n} ]\n}\n"
    )


def synthetic_scene(size: int = 250_000) -> str:
    rng = np.random.default_rng(0)
    parts = [vrml.HEADER + "\n"]
    total = len(parts[0])
    while total < size:
        parts.append(synthetic_shape(len(parts), rng))
        total += len(parts[-1])
    return "".join(parts)


def report(name: str, data: bytes, load: Callable[[], object]) -> None:
    parse = best_of(lambda: vrml.parse(vrml.decode(data, name), name))
    loaded = best_of(load)
    scene = load()
    print(
        f"{name} ({len(data) / 1000:.0f} KB): parse {parse * 1e3:.1f} ms, load {loaded * 1e3:.1f} ms"
        f" -> {len(scene.faces)} triangles, {scene.objects} objects"
    )


def main() -> None:
    if CASTLE.exists():
        report(CASTLE.name, CASTLE.read_bytes(), lambda: load_scene(CASTLE))
    else:
        print(f"skipped castle: {CASTLE} is absent (a bare clone has no ../shared)")
    data = synthetic_scene().encode()
    report("synthetic", data, lambda: parse_scene(data, "synthetic.wrl"))


if __name__ == "__main__":
    main()
