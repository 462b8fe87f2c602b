"""Malformed scenes: one SceneError with file, line and column, and never any other exception."""

import gzip
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vehicle.world import vrml
from vehicle.world.scene import SceneError, load_scene, parse_scene
from vehicle.world.vrml import MAX_DEPTH

HEADER = "#VRML V2.0 utf8\n"
DATA = Path(__file__).parent / "data" / "vrml"
CASTLE = Path(__file__).parents[1].parent / "shared" / "scenes" / "castle.wrl"

FACE_SET = "Shape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0, 1 0 0, 0 1 0 ] }\n"

# (text after the header line, line, column, message start); the header is line 1
CASES = {
    "truncated node": ("Shape {\n  geometry Box {", 3, 17, "expected '}' but found end of file"),
    "truncated list": ("Coordinate { point [ 0 0 0, 1", 2, 30, "expected ']' but found end of file"),
    "truncated string": ('WorldInfo { title "abc', 2, 19, "unterminated string"),
    "truncated after field": ("Transform { translation", 2, 24, "expected a value for translation"),
    "bracket closed by brace": ("Group { children [ Shape { } } ]", 2, 30, "expected ']' but found '}'"),
    "brace closed by bracket": ("Group { children [ Shape { ] ] }", 2, 28, "expected a field name or '}'"),
    "stray closing brace": ("Group { }\n}", 3, 1, "expected a node but found '}'"),
    "nested list": ("Coordinate { point [ [ 0 ] ] }", 2, 22, "expected ']' but found '['"),
    "bad number": ("Box { size 1 2.3.4 5 }", 2, 14, "bad number '2.3.4'"),
    "bad number in a list": ("Coordinate { point [ 0 0 0,\n 1 1e 0 ] }", 3, 4, "bad number '1e'"),
    "number too large": ("Sphere { radius 1e999 }", 2, 17, "number out of range '1e999'"),
    "letter in a number list": ("Coordinate { point [ 0 0 x ] }", 2, 28, "expected '{' after x but found ']'"),
    "mixed list": ('WorldInfo { info [ "a" 1 ] }', 2, 18, "list mixes values of different types"),
    "unexpected character": ("Group { }\n\x01", 3, 1, "unexpected character '\\x01'"),
    "undefined USE": ("Transform {\n  children USE Nope }", 3, 16, "USE of undefined name 'Nope'"),
    "USE inside its own DEF": ("DEF A Group { children USE A }", 2, 28, "USE of undefined name 'A'"),
    "fractional index": (FACE_SET + "  coordIndex [ 0 1 1.5 ] } }", 3, 3, "coordIndex must be 32-bit integers"),
    "short vector": ("Transform { translation 1 2 }", 2, 13, "translation needs 3 numbers, found 2"),
    "node where numbers belong": ("Transform { scale Group { } }", 2, 13, "scale must be numbers"),
    "numbers where nodes belong": ("Group { children [ 1 2 ] }", 2, 9, "children must be a list of nodes"),
    "ragged points": (FACE_SET.replace("0 1 0 ]", "0 1 ]") + "} }", 2, 54, "point has 8 numbers"),
    "elevation grid size": ("Shape { geometry ElevationGrid { xDimension 2 zDimension 2 height [ 0 0 0 ] } }",
                            2, 60, "height has 3 values for a 2 x 2 grid"),  # fmt: skip
}


@pytest.mark.parametrize(("body", "line", "column", "message"), CASES.values(), ids=CASES.keys())
def test_malformed_text_raises_located_scene_error(body, line, column, message):
    with pytest.raises(SceneError) as caught:
        parse_scene(HEADER + body, path="bad.wrl")
    assert (caught.value.file, caught.value.line, caught.value.column) == ("bad.wrl", line, column)
    assert caught.value.message.startswith(message)


@pytest.mark.parametrize(
    "text", ["#VRML V1.0 ascii\nSeparator { }", "Shape { }", "", "\n#VRML V2.0 utf8", "#X3D V3.0 utf8"]
)
def test_wrong_header(text):
    with pytest.raises(SceneError, match="expected header '#VRML V2.0 utf8'") as caught:
        parse_scene(text)
    assert (caught.value.line, caught.value.column) == (1, 1)


@pytest.mark.parametrize("header", ["#VRML V2.0 utf8\r\n", "#VRML  V2.0\tutf8 \n", "  #VRML V2.0 utf8\n",
                                    "#VRML V2.0 UTF8 exported by some tool\n", "#VRML V2.0 utf8"])
def test_headers_real_browsers_accept_load(header):
    scene = parse_scene(header + ("Shape { geometry Box { } }" if header.endswith("\n") else ""))
    assert scene.warnings in ([], ["scene has no geometry"])


@pytest.mark.parametrize(("index", "faces"), [("0 1 3 -1 0 1 2", 1), ("0 1 2 -1 0 7 1 -1 2 1 0", 2),
                                              ("0 1 -2 -1 2 1 0 -1", 1), ("5 6 7", 0)])
def test_faces_naming_points_they_do_not_have_are_skipped_with_one_warning(index, faces):
    scene = parse_scene(HEADER + FACE_SET + f"  coordIndex [ {index} ] }} }}\n" + FACE_SET
                        + "  coordIndex [ 9 9 9 -1 0 1 2 ] } }")
    assert len(scene.mesh.faces) == faces + 1  # the good faces of both shapes stand
    skipped = [w for w in scene.warnings if "coordIndex" in w]
    assert len(skipped) == 1
    assert skipped[0].startswith("skipped faces whose coordIndex points past their coordinates")


def test_str_is_file_line_column_message():
    with pytest.raises(SceneError) as caught:
        parse_scene(HEADER + "Group {\n  children [ Shape {\n", path="castle.wrl")
    assert str(caught.value) == "castle.wrl:4:1: expected '}' but found end of file"


def test_scene_error_is_shared_by_both_modules():
    assert SceneError is vrml.SceneError


def test_absurd_nesting_is_refused_clearly():
    body = "Group { children [\n" * (MAX_DEPTH + 50) + "]}" * (MAX_DEPTH + 50)
    with pytest.raises(SceneError, match=f"nested more than {MAX_DEPTH}") as caught:
        parse_scene(HEADER + body)
    assert (caught.value.line, caught.value.column) == (MAX_DEPTH + 2, 1)


def test_nesting_within_the_limit_loads():
    depth = MAX_DEPTH - 2
    body = "Group { children [\n" * depth + "Shape { geometry Box { } }" + "]}" * depth
    assert len(parse_scene(HEADER + body).mesh.faces) == 12


def test_deep_inline_chain_is_refused_clearly(tmp_path):
    for i in range(MAX_DEPTH + 5):
        (tmp_path / f"{i}.wrl").write_text(HEADER + f'Group {{ children Inline {{ url "{i + 1}.wrl" }} }}')
    with pytest.raises(SceneError, match=f"nested more than {MAX_DEPTH}"):
        load_scene(tmp_path / "0.wrl")


def test_exponential_use_expansion_is_refused():
    doubling = (f"DEF L{i + 1} Group {{ children [ USE L{i} USE L{i} ] }}\n" for i in range(24))
    body = "DEF L0 Group { }\n" + "".join(doubling)  # 2 ** 24 instances
    with pytest.raises(SceneError, match="node instances after DEF/USE expansion"):
        parse_scene(HEADER + body)


# --- files ---------------------------------------------------------------------------------------


def test_missing_inline_target_points_at_the_inline():
    with pytest.raises(SceneError, match=r"Inline target not found: \['nowhere.wrl'\]") as caught:
        load_scene(DATA / "inline" / "missing.wrl")
    assert caught.value.file.endswith("missing.wrl")
    assert (caught.value.line, caught.value.column) == (3, 21)


def test_inline_cycle_is_refused():
    with pytest.raises(SceneError, match="Inline cycle: cycle_a.wrl -> cycle_b.wrl -> cycle_a.wrl") as caught:
        load_scene(DATA / "inline" / "cycle_a.wrl")
    assert caught.value.file.endswith("cycle_b.wrl")
    assert (caught.value.line, caught.value.column) == (3, 23)


def test_inline_of_itself_is_refused(tmp_path):
    (tmp_path / "self.wrl").write_text(HEADER + 'Inline { url "self.wrl" }')
    with pytest.raises(SceneError, match="Inline cycle: self.wrl -> self.wrl"):
        load_scene(tmp_path / "self.wrl")


def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match="cannot read file") as caught:
        load_scene(tmp_path / "absent.wrl")
    assert caught.value.file == str(tmp_path / "absent.wrl")


@pytest.mark.parametrize(
    "data",
    [b"\x1f\x8bnot really gzip", gzip.compress(HEADER.encode() + b"Group { }" * 100)[:40]],
    ids=["garbage", "truncated"],
)
def test_bad_gzip(tmp_path, data):
    (tmp_path / "bad.wrz").write_bytes(data)
    with pytest.raises(SceneError, match="corrupt gzip data") as caught:
        load_scene(tmp_path / "bad.wrz")
    assert (caught.value.line, caught.value.column) == (1, 1)


def test_invalid_utf8_is_located_in_characters():
    data = HEADER.encode() + 'WorldInfo {\n  title "Château '.encode() + b'\xff" }'
    with pytest.raises(SceneError, match="invalid UTF-8 byte 0xff") as caught:
        parse_scene(data)
    assert (caught.value.line, caught.value.column) == (3, 18)


def test_invalid_utf8_inside_gzip(tmp_path):
    (tmp_path / "bad.wrl.gz").write_bytes(gzip.compress(HEADER.encode() + b"\xc3("))
    with pytest.raises(SceneError, match="invalid UTF-8") as caught:
        load_scene(tmp_path / "bad.wrl.gz")
    assert (caught.value.line, caught.value.column) == (2, 1)


def test_binary_garbage():
    with pytest.raises(SceneError):
        parse_scene(bytes(range(256)) * 4)
    with pytest.raises(SceneError, match="unexpected character"):
        parse_scene(HEADER.encode() + b"\x00\x01\x02\x03")


# --- properties: mutated real files load or fail cleanly -----------------------------------------

INSERTS = [b"{", b"}", b"[", b"]", b'"', b"#", b",", b"-", b".", b"e", b"0x", b"\n", b"\x00", b"\xff", b"DEF ", b"USE "]


@st.composite
def mutations(draw, original: bytes) -> bytes:
    """Up to four byte deletions, insertions, truncations, bracket swaps or digit -> letter changes.

    The header line is left alone (test_wrong_header covers it): hypothesis favours small offsets.
    """
    data = bytearray(original)
    body = len(HEADER)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(body, max(len(data) - 1, body)))
        kind = draw(st.sampled_from(["delete", "insert", "truncate", "bracket", "digit"]))
        if kind == "delete":
            del data[at : at + draw(st.integers(1, 16))]
        elif kind == "insert":
            data[at:at] = draw(st.sampled_from(INSERTS) | st.binary(min_size=1, max_size=3))
        elif kind == "truncate":
            del data[at:]
        else:
            pattern, replacements = (rb"[][{}]", b"[]{}") if kind == "bracket" else (rb"[0-9]", b"xeEOlZ")
            spots = [m.start() for m in re.compile(pattern).finditer(data, body)]
            if spots:
                data[draw(st.sampled_from(spots))] = draw(st.sampled_from(replacements))
    return bytes(data)


def _loads_or_raises_scene_error(data: bytes, path: Path) -> None:
    try:
        parse_scene(data, path=path)
    except SceneError as e:
        assert e.line >= 1 and e.column >= 1 and e.message


FIXTURE = DATA / "yard.wrl"


@settings(max_examples=500, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=mutations(FIXTURE.read_bytes()))
def test_mutated_fixture_loads_or_raises_scene_error(data):
    _loads_or_raises_scene_error(data, FIXTURE)


@pytest.mark.skipif(not CASTLE.exists(), reason="needs ../shared/scenes/castle.wrl (absent in a bare clone)")
@settings(max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=mutations(CASTLE.read_bytes() if CASTLE.exists() else b""))
def test_mutated_castle_loads_or_raises_scene_error(data):
    _loads_or_raises_scene_error(data, CASTLE)


@settings(max_examples=300, deadline=None, database=None)
@given(body=st.binary(max_size=64))
def test_random_bytes_after_the_header_load_or_raise_scene_error(body):
    _loads_or_raises_scene_error(HEADER.encode() + body, FIXTURE)
