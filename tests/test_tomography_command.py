"""``groundstation rti reconstruct``: the contract's JSON and PNG, bad input, and the two real basement walks."""

import gzip
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from groundstation.cli import main
from vehicle.tomography.synthetic import Network, square, write_csv

SHARED = Path(__file__).resolve().parents[2] / "shared" / "rti"
HEADER = "t,tx,rx,tx_x,tx_y,rx_x,rx_y,rssi,channel\n"


@pytest.fixture(scope="module")
def walk_file(tmp_path_factory):
    """A 6.4 m square of 12 radios: 5 s empty, then a person standing at (4.0, 2.0) for 5 s."""
    net = Network(square(12), channels=2, seed=5)
    empty = net.sweeps(np.arange(10) * 0.5)
    person = net.sweeps(5 + np.arange(10) * 0.5, lambda t: [(4.0, 2.0)])
    records = empty.select(np.ones(len(empty), bool))
    for name in ("t", "rssi", "channel"):
        setattr(records, name, np.concatenate([getattr(empty, name), getattr(person, name)]))
    records.tx, records.rx = np.vstack([empty.tx, person.tx]), np.vstack([empty.rx, person.rx])
    path = tmp_path_factory.mktemp("rti") / "links.csv"
    write_csv(records, path)
    return path


def run(capsys, *args):
    code = main(["rti", "reconstruct", *map(str, args)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_the_command_writes_the_contract_json_and_a_picture(walk_file, tmp_path, capsys):
    out, png = tmp_path / "out.json", tmp_path / "out.png"
    code, said, err = run(capsys, walk_file, "--calibration-seconds", 4.9, "--json", out, "--png", png, "--peaks", 2)
    assert code == 0, err
    result = json.loads(out.read_text())
    assert result["window"] is None and len(result["frames"]) == 1 and result["cell"] > 0
    assert result["bounds"] == [0.0, 0.0, 6.4, 6.4]  # the radios' bounding box
    frame = result["frames"][0]
    assert frame["t"] == pytest.approx(4.9)  # the image starts after the calibration
    assert 1 <= len(frame["peaks"]) <= 2 and frame["peaks"][0]["value"] >= frame["peaks"][-1]["value"]
    assert np.hypot(frame["peaks"][0]["x"] - 4.0, frame["peaks"][0]["y"] - 2.0) < 0.5
    assert "1 frame(s)" in said
    picture = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert ((picture[..., 0] > 200) & (picture[..., 1] < 50) & (picture[..., 2] < 50)).sum() > 20  # the red peak
    assert (picture == 255).all(axis=2).sum() > 1000  # white: margins and the radios


def test_windows_give_frames_with_a_track(walk_file, tmp_path, capsys):
    out = tmp_path / "out.json"
    code, _, err = run(capsys, walk_file, "--window", 1, "--json", out, "--peaks", 1, "--images")
    assert code == 0, err
    result = json.loads(out.read_text())
    frames = result["frames"]
    assert [f["t"] for f in frames] == pytest.approx(np.arange(10) * 1.0)
    assert all(len(f["peaks"]) <= 1 and "track" in f for f in frames)
    nx, ny = result["grid"]
    image = np.array(frames[-1]["image"])  # rows of values: the person's frame, brightest at its peak
    assert image.shape == (ny, nx)
    peak = frames[-1]["peaks"][0]
    row, col = np.unravel_index(image.argmax(), image.shape)
    cell = result["cell"]
    assert abs((col + 0.5) * cell - peak["x"]) <= cell and abs((row + 0.5) * cell - peak["y"]) <= cell


def test_bad_rows_are_skipped_counted_and_named(tmp_path, capsys):
    path = tmp_path / "links.csv"
    rows = [f"{t},1,2,0,0,4,{y},-50,1" for t in range(6) for y in (1, 3)]
    rows[3] = "2,1,2,0,0,4"  # malformed: too few fields (line 5)
    rows[5] = "3,1,2,0,0,4,3,nan,1"  # NaN (line 7)
    rows[7] = "4,1,2,1,1,1,1,-50,1"  # same point (line 9)
    rows.insert(9, "0.5,1,2,0,0,4,1,-50,1")  # out of time order (line 11)
    rows.insert(10, "2,1,2,0,0,4,abc,-50,1")  # malformed (line 12)
    path.write_text(HEADER + "\n".join(rows) + "\n")
    out = tmp_path / "out.json"
    code, _, err = run(capsys, path, "--json", out)
    assert code == 0, err
    assert json.loads(out.read_text())["skipped"] == {"malformed": 2, "not_finite": 1, "same_point": 1,
                                                      "out_of_order": 1}
    for line, what in ((5, "malformed"), (7, "NaN"), (9, "same point"), (11, "out of time order")):
        assert f"{path}:{line}: skipped" in err and what in err


@pytest.mark.parametrize("content, message", [
    ("", ":1: empty file"),
    (HEADER, ":2: no usable link records"),
    ("t,tx,rx,rssi\n1,2,3,4\n", ":1: the header lacks tx_x, tx_y, rx_x, rx_y, channel"),
    (HEADER + "1,1,2,0,0,0,0,-50,1\n", "1 whose two ends are the same point"),
])
def test_unusable_files_are_a_one_line_error_naming_file_and_line(tmp_path, capsys, content, message):
    path = tmp_path / "links.csv"
    path.write_text(content)
    code, _, err = run(capsys, path, "--json", tmp_path / "out.json")
    assert code == 2
    assert err.count("\n") == 1 and f"{path}" in err and message in err, err
    assert "Traceback" not in err and not (tmp_path / "out.json").exists()


def test_bad_gzip_and_bad_options_exit_2(walk_file, tmp_path, capsys):
    broken = tmp_path / "links.csv.gz"
    packed = gzip.compress((HEADER + "".join(f"{i},1,2,0,0,4,4,-{i % 97},1\n" for i in range(5000))).encode())
    broken.write_bytes(packed[:len(packed) // 2])  # cut short
    code, _, err = run(capsys, broken, "--json", tmp_path / "o.json")
    assert code == 2 and str(broken) in err and "Traceback" not in err
    code, _, err = run(capsys, walk_file, "--bounds", "1,1,1,5", "--json", tmp_path / "o.json")
    assert code == 2 and "zero area" in err
    code, _, err = run(capsys, walk_file, "--bounds", "-1,-1,-1,5", "--json", tmp_path / "o.json")
    assert code == 2 and "zero area" in err  # a west or south edge below 0 is a value, not an option
    for bad in (["--bounds", "1,2,3"], ["--cell", "0"], ["--window", "nan"]):
        with pytest.raises(SystemExit) as stop:
            main(["rti", "reconstruct", str(walk_file), "--json", str(tmp_path / "o.json"), *bad])
        assert stop.value.code == 2
    capsys.readouterr()


def test_gzip_is_read_transparently(walk_file, tmp_path, capsys):
    packed = tmp_path / "links.csv.gz"
    packed.write_bytes(gzip.compress(walk_file.read_bytes()))
    plain, zipped = tmp_path / "a.json", tmp_path / "b.json"
    assert run(capsys, walk_file, "--json", plain)[0] == 0
    assert run(capsys, packed, "--json", zipped)[0] == 0
    assert json.loads(plain.read_text())["frames"] == json.loads(zipped.read_text())["frames"]


@pytest.mark.parametrize("case", ["basement_walk1", "basement_walk2"])
@pytest.mark.parametrize("measure, line", [("kernel", 1.2), ("variance", 1.65)])
def test_the_real_walks_with_the_defaults_and_their_cli_options(case, measure, line, tmp_path, capsys):
    """The README's figures: the data set author's own RTI scores 1.655 / 1.627 m on these walks, his VRTI
    1.424 / 1.379 m. The kernel distance (the default: with --window against the file's long-term histogram,
    each path above its floor) scores 1.133 / 1.199 m, the issue's goal of under 1.2 m (1.221 / 1.2 m without
    the floor); the variance 1.529 / 1.528 m, held with a margin."""
    directory = SHARED / case
    if not directory.exists():
        pytest.skip("needs ../shared/rti (the basement walks; absent in a bare clone)")
    sys.path.insert(0, str(SHARED))
    try:
        from score import score_walk
    finally:
        sys.path.remove(str(SHARED))
    truth = json.loads((directory / "truth.json").read_text())
    cli = truth["cli"]
    out = tmp_path / "out.json"
    code, _, err = run(capsys, directory / "links.csv.gz", "--calibration", directory / cli["calibration"],
                       "--bounds", ",".join(map(str, cli["bounds"])), "--cell", cli["cell"], "--window",
                       cli["window"], "--peaks", cli["peaks"], "--measure", measure, "--json", out)
    assert code == 0, err
    score = score_walk(truth, json.loads(out.read_text()))
    assert score["frames_missing"] == 0 and score["frames_without_peak"] == 0
    assert score["rmse_m"] < line, score
