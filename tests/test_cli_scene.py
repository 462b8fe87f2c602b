"""``vehicle scene FILE [--json] [--top-view PNG]`` (vehicle.cli).

The main cases run ``python -m vehicle.cli`` as real subprocesses, started together once per module
(each pays about a second of imports); the rest call ``main()`` in-process.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vehicle.cli import main

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "scenes" / "default.wrl"
CASTLE = ROOT.parent / "shared" / "scenes" / "castle.wrl"
BROKEN = "#VRML V2.0 utf8\nShape {\n  geometry Box {"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    """Run the CLI cases concurrently; each result also carries ``path`` and ``out`` (the files involved)."""
    folder = tmp_path_factory.mktemp("cli")
    broken = folder / "broken.wrl"
    broken.write_text(BROKEN)
    top = folder / "top.png"
    cases = {
        "default": [str(DEFAULT), "--json", "--top-view", str(top)],
        "broken": [str(broken), "--json"],
    }
    if CASTLE.exists():
        cases["castle"] = [str(CASTLE), "--json"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    started = {name: subprocess.Popen([sys.executable, "-m", "vehicle.cli", "scene", *args], cwd=ROOT, env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for name, args in cases.items()}
    results = {}
    for name, process in started.items():
        stdout, stderr = process.communicate(timeout=60)
        results[name] = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
    results["default"].out = top
    results["broken"].path = broken
    return results


def test_scene_json_describes_the_default_scene(runs):
    result = runs["default"]
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert {"triangles", "objects", "bounds", "warnings"} <= set(report)
    assert report["triangles"] > 300 and report["objects"] == 26
    (x0, y0, z0), (x1, y1, z1) = report["bounds"]
    assert (x0, y0, x1, y1) == (-60.0, -60.0, 60.0, 60.0) and z0 == 0.0 and z1 == 12.0
    assert report["warnings"] == []
    assert report["start"] == [0.0, 0.0, 1.7]  # x, y and the eye height of the Start viewpoint


def test_scene_json_of_the_castle(runs, castle_path):
    result = runs["castle"]
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["triangles"] == 1066
    assert report["objects"] > 0 and report["warnings"] == []
    assert report["bounds"][0][0] < -100 and report["bounds"][1][0] > 100


def test_scene_top_view_writes_a_png(runs):
    assert runs["default"].returncode == 0, runs["default"].stderr
    with Image.open(runs["default"].out) as image:
        assert image.format == "PNG"
        assert min(image.size) > 100
        colours = image.convert("RGB").getcolors(maxcolors=1 << 20)
    assert len(colours) > 5  # a picture, not a blank canvas


def test_the_top_view_shows_where_the_origin_the_start_and_round_coordinates_are():
    """The picture had no coordinates, no north and no origin: nothing to read a ``--start`` off."""
    from vehicle.mapping.picture import BACKGROUND, POSITION, TEXT
    from vehicle.world.scene import load_scene
    from vehicle.world.topview import LEFT, ORIGIN, draw_top_view

    scene = load_scene(ROOT / "scenes" / "house.wrl")  # 16 x 12 m, its Start at (-3, -1.5)
    view = draw_top_view(scene, start=scene.start)
    image = view.image.convert("RGB")

    def at(x: float, y: float, dx: int = 0, dy: int = 0) -> tuple[int, int, int]:
        column, row = view.pixel(x, y)
        return image.getpixel((round(column) + dx, round(row) + dy))

    assert at(0.0, 0.0, 4, 0) == ORIGIN and at(0.0, 0.0, 0, -4) == ORIGIN  # a cross at 0,0
    assert POSITION in (at(-3.0, -1.5, 5, 0), at(-3.0, -1.5, 6, 0)) and at(-3.0, -1.5) != POSITION  # the start
    left, top, right, bottom = view.map_box
    west, south, east, north = view.window
    assert view.pixel(east, south) == pytest.approx((right, bottom))  # the window is what is drawn
    assert west < -8 and east > 8 and south < -6 and north > 6  # the whole house
    lighter = 0
    for x in (-6.0, -4.0, 4.0, 6.0):  # lines every 2 m (a quarter of the longer side, rounded down), lighter
        # than the floor a pixel beside them
        lighter += sum(at(x, -1.0)) > sum(at(x, -1.0, 3, 0)) and sum(at(x, -1.0)) > sum(at(x, -1.0, -3, 0))
    assert lighter == 4  # faint lines, over the scene

    def ink(box) -> int:  # pixels that are not the background
        part = np.asarray(image.crop(box))
        return int(np.any(part != BACKGROUND, axis=2).sum())

    column = round(view.pixel(0.0, 0.0)[0])
    assert ink((column - 8, bottom + 3, column + 8, bottom + 18)) > 5  # "0" under the x = 0 line
    row = round(view.pixel(0.0, 0.0)[1])
    assert ink((left - 20, row - 7, left - 4, row + 7)) > 5  # "0" left of the y = 0 line
    assert ink((left - 20, row + 12, left - 4, row + 26)) == 0  # and nothing between two labels
    assert image.getpixel((LEFT + 3, bottom + 24 + 8)) == TEXT  # the scale bar
    assert ink((image.width - 40, 0, image.width, top - 4)) > 10  # the north arrow


def test_a_start_off_the_scene_and_a_map_larger_than_it_stay_in_their_place():
    """A start outside the scene's bounds fell off the picture, and a memory map larger than a small scene
    covered the labels around it."""
    from vehicle.mapping.memory_map import MemoryMap
    from vehicle.mapping.picture import POSITION
    from vehicle.world.scene import load_scene
    from vehicle.world.topview import draw_top_view

    scene = load_scene(ROOT / "scenes" / "house.wrl")
    memory_map = MemoryMap((0.0, 0.0), space_size=40.0)
    memory_map.grid[:] = 20  # occupied everywhere: red over the whole 80 x 80 m
    view = draw_top_view(scene, memory_map=memory_map, start=(-30.0, 5.0))
    image = view.image.convert("RGB")
    left, top, right, bottom = view.map_box
    column, row = (round(v) for v in view.pixel(-30.0, 5.0))
    assert left <= column < right and top <= row < bottom
    assert POSITION in [image.getpixel((column + dx, row)) for dx in (5, 6)]
    red = image.getpixel(((left + right) // 2, (top + bottom) // 2))
    assert red[0] > 150 and red[1] < 80  # the map is drawn over the scene
    outside = [image.getpixel((x, y)) for x in range(0, image.width, 7) for y in (top - 10, bottom + 40)]
    outside += [image.getpixel((x, y)) for x in (left - 30, right + 5) for y in range(top, bottom, 7)]
    assert not any(p[0] > 150 and p[1] < 80 for p in outside)  # and nowhere around it


def test_a_broken_file_exits_2_with_file_line_and_column(runs):
    result = runs["broken"]
    assert result.returncode == 2
    assert result.stdout == ""
    assert f"{result.path}:3:17:" in result.stderr
    assert "expected '}'" in result.stderr
    assert "Traceback" not in result.stderr


def test_scene_json_lists_warnings_for_unsupported_nodes(tmp_path, capsys):
    path = tmp_path / "warn.wrl"
    path.write_text('#VRML V2.0 utf8\nShape { geometry Box { size 2 4 6 } }\nScript { }\n'
                    'Shape { geometry Text { string "hi" } }\n')
    assert main(["scene", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["triangles"] == 12 and report["objects"] == 1
    assert report["bounds"] == [[-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]]
    assert len(report["warnings"]) == 2
    assert any("Script" in w for w in report["warnings"]) and any("Text" in w for w in report["warnings"])
    assert "start" not in report


def test_scene_without_json_prints_a_summary(capsys):
    assert main(["scene", str(DEFAULT)]) == 0
    out = capsys.readouterr().out
    assert "triangles" in out and "26 objects" in out and "bounds:" in out and "start:" in out


def test_a_missing_file_exits_2_with_a_message(tmp_path, capsys):
    assert main(["scene", str(tmp_path / "nope.wrl")]) == 2
    err = capsys.readouterr().err
    assert "nope.wrl" in err and "cannot read" in err


@pytest.mark.parametrize("args", [["scene"], ["scene", "x.wrl", "--bogus"]])
def test_bad_arguments_are_usage_errors(args, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    assert "usage:" in capsys.readouterr().err
