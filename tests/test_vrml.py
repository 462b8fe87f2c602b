"""VRML97 loading: node semantics, geometry and the real castle scene (vehicle.vrml, vehicle.scene)."""

import gzip
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vehicle.world.scene import load_scene, parse_scene
from vehicle.world.vrml import parse

HEADER = "#VRML V2.0 utf8\n"
DATA = Path(__file__).parent / "data" / "vrml"
CASTLE = Path(__file__).parents[1].parent / "shared" / "scenes" / "castle.wrl"


def scene(body: str):
    return parse_scene(HEADER + body)


def triangle(points: str = "0 0 0, 1 0 0, 0 1 0") -> str:
    return f"Shape {{ geometry IndexedFaceSet {{ coord Coordinate {{ point [ {points} ] }} coordIndex [ 0 1 2 ] }} }}"


def shape(geometry: str, appearance: str = "") -> str:
    return f"Shape {{ {appearance} geometry {geometry} }}"


def face_normals(s) -> np.ndarray:
    return s.mesh.face_normals


# --- transforms --------------------------------------------------------------------------------


def test_rotation_turns_about_center():
    s = scene(f"Transform {{ rotation 0 0 1 {math.pi / 2} center 1 0 0 children {triangle('2 0 0, 2 1 0, 3 0 0')} }}")
    np.testing.assert_allclose(s.mesh.vertices, [[1, 1, 0], [0, 1, 0], [1, 2, 0]], atol=1e-12)


def test_scale_orientation_scales_along_turned_axes():
    # scale x2 along the diagonal (1, 1, 0): (1, 1, 0) doubles, (1, -1, 0) stays
    tri = triangle("1 1 0, 1 -1 0, 0 0 1")
    body = f"Transform {{ scale 2 1 1 scaleOrientation 0 0 1 {math.pi / 4} children {tri} }}"
    np.testing.assert_allclose(scene(body).mesh.vertices, [[2, 2, 0], [1, -1, 0], [0, 0, 1]], atol=1e-12)


def _vrml_matrix(translation, center, rotation, scale, scale_orientation) -> np.ndarray:
    """T * C * R * SR * S * SR^-1 * C^-1, composed independently with scipy."""

    def rotate(axis_angle):
        m = np.eye(4)
        axis = np.array(axis_angle[:3], float)
        m[:3, :3] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * axis_angle[3]).as_matrix()
        return m

    def move(v):
        m = np.eye(4)
        m[:3, 3] = v
        return m

    sr = rotate(scale_orientation)
    scaling = np.diag([*scale, 1.0])
    return move(translation) @ move(center) @ rotate(rotation) @ sr @ scaling @ np.linalg.inv(sr) @ move(
        np.negative(center)
    )


def test_transform_composes_all_fields_in_vrml_order():
    t, c, r, s, so = (3, -2, 5), (1, 2, 0.5), (1, 2, 3, 0.7), (2, 0.5, 3), (-1, 0, 2, 1.1)
    body = (
        f"Transform {{ translation {' '.join(map(str, t))} center {' '.join(map(str, c))}"
        f" rotation {' '.join(map(str, r))} scale {' '.join(map(str, s))}"
        f" scaleOrientation {' '.join(map(str, so))} children {triangle('1 2 3, -4 0.5 2, 0 0 -1')} }}"
    )
    points = np.array([[1, 2, 3, 1], [-4, 0.5, 2, 1], [0, 0, -1, 1]], float)
    expected = (_vrml_matrix(t, c, r, s, so) @ points.T).T[:, :3]
    np.testing.assert_allclose(scene(body).mesh.vertices, expected, atol=1e-9)


def test_nested_transforms_apply_child_first():
    inner = f"Transform {{ rotation 0 0 1 {math.pi / 2} children {triangle('1 0 0, 2 0 0, 1 0 1')} }}"
    s = scene(f"Transform {{ translation 10 0 0 children [ {inner} ] }}")
    np.testing.assert_allclose(s.mesh.vertices, [[10, 1, 0], [10, 2, 0], [10, 1, 1]], atol=1e-12)


# --- DEF/USE, grouping nodes ------------------------------------------------------------------------


def test_use_instantiates_again_under_the_current_transform():
    s = scene(
        f"DEF Tri Transform {{ translation 1 0 0 children DEF Face {triangle()} }}\n"
        "Transform { translation 0 10 0 children USE Tri }\n"
        "Transform { translation 0 20 0 children USE Face }\n"
    )
    assert s.objects == 3 and len(s.mesh.faces) == 3
    assert s.face_object.tolist() == [0, 1, 2]
    np.testing.assert_allclose(s.mesh.vertices[[0, 3, 6]], [[1, 0, 0], [1, 10, 0], [0, 20, 0]])


def test_use_refers_to_the_same_node_object():
    nodes, _ = parse(HEADER + "DEF A Group { }\nTransform { children [ USE A USE A ] }")
    children = nodes[1].fields["children"]
    assert children[0] is nodes[0] and children[1] is nodes[0]
    assert nodes[0].name == "A"


@pytest.mark.parametrize(("which", "size"), [(0, 1), (1, 2), (2, 3)])
def test_switch_draws_only_the_chosen_child(which, size):
    boxes = " ".join(shape(f"Box {{ size {n} {n} {n} }}") for n in (1, 2, 3))
    s = scene(f"Switch {{ whichChoice {which} choice [ {boxes} ] }}")
    assert s.objects == 1
    np.testing.assert_allclose(s.bounds, [[-size / 2] * 3, [size / 2] * 3])


@pytest.mark.parametrize("which", ["whichChoice -1", "whichChoice 7", ""])
def test_switch_without_a_valid_choice_draws_nothing(which):
    s = scene(f"Switch {{ {which} choice [ {shape('Box { }')} ] }}")
    assert len(s.mesh.faces) == 0
    assert "scene has no geometry" in s.warnings


def test_lod_draws_its_first_level_only():
    s = scene(f"LOD {{ range [ 10 ] level [ {shape('Box { size 4 4 4 }')} {shape('Box { }')} ] }}")
    assert s.objects == 1
    np.testing.assert_allclose(s.bounds, [[-2] * 3, [2] * 3])


def test_grouping_nodes_all_draw_their_children():
    groups = ["Group", "Collision", "Anchor", "Billboard"]
    s = scene("\n".join(f"{g} {{ children [ {shape('Box { }')} ] }}" for g in groups))
    assert s.objects == len(groups)


# --- IndexedFaceSet ---------------------------------------------------------------------------------

SQUARE = "0 0 0, 1 0 0, 1 1 0, 0 1 0"


def face_set(points: str, index: str, extra: str = "") -> str:
    return shape(f"IndexedFaceSet {{ {extra} coord Coordinate {{ point [ {points} ] }} coordIndex [ {index} ] }}")


def test_last_face_needs_no_trailing_separator():
    with_end = scene(face_set(SQUARE, "0 1 2 -1 0 2 3 -1"))
    without_end = scene(face_set(SQUARE, "0 1 2 -1 0 2 3"))
    assert with_end.mesh.faces.tolist() == without_end.mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_faces_keep_file_order_and_winding():
    s = scene(face_set(SQUARE, "0 1 2 3 -1 3 2 1 -1 0 1 3"))
    assert s.mesh.faces[-1].tolist() == [0, 1, 3]
    assert face_normals(s)[0] @ [0, 0, 1] > 0.99 and face_normals(s)[2] @ [0, 0, -1] > 0.99


def test_ccw_false_flips_winding():
    front = scene(face_set(SQUARE, "0 1 2 3"))
    back = scene(face_set(SQUARE, "0 1 2 3", "ccw FALSE solid FALSE"))
    np.testing.assert_allclose(face_normals(back), -face_normals(front))


def test_faces_with_fewer_than_three_distinct_vertices_are_skipped():
    s = scene(face_set(SQUARE, "0 1 1 -1 2 2 2 -1 0 1 2 -1 3 3 0 0 -1 0 1 -1 2"))
    assert s.mesh.faces.tolist() == [[0, 1, 2]]


def _inside(point, polygon) -> bool:
    """Even-odd rule."""
    x, y = point
    inside = False
    for (x1, y1), (x2, y2) in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


U_SHAPE = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], float)  # area 7
L_SHAPE = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], float)  # area 6


@pytest.mark.parametrize(("outline", "area"), [(U_SHAPE, 7.0), (L_SHAPE, 6.0)])
def test_non_convex_polygon_is_triangulated_inside_its_outline(outline, area):
    tilt = Rotation.from_rotvec([0.4, -0.9, 0.3])  # in a tilted plane, not just z = 0
    points = tilt.apply(np.column_stack((outline, np.zeros(len(outline))))) + [5, -2, 7]
    text = ", ".join(" ".join(f"{v:.17g}" for v in p) for p in points)
    s = scene(face_set(text, " ".join(map(str, range(len(outline))))))
    assert len(s.mesh.faces) == len(outline) - 2
    assert s.mesh.area_faces.sum() == pytest.approx(area, rel=1e-9)
    local = tilt.inv().apply(s.mesh.triangles_center - [5, -2, 7])
    assert all(_inside(c[:2], outline) for c in local)
    assert np.allclose(local[:, 2], 0, atol=1e-9)
    assert (face_normals(s) @ tilt.apply([0, 0, 1]) > 0.999).all()  # same winding as the outline


def test_closed_l_shaped_house_has_the_right_volume():
    s = load_scene(DATA / "yard.wrl")
    house = s.mesh.submesh([np.flatnonzero(s.face_object == 1)], append=True)
    assert len(house.faces) == 20
    assert house.volume == pytest.approx(60.0)  # L floor of 20 m2, 3 m high, faces outward


# --- primitives -----------------------------------------------------------------------------------

RING_AREA = 12 * math.sin(math.pi / 12)  # the 24-gon inscribed in the unit circle


def test_box():
    s = scene(shape("Box { size 2 3 4 }"))
    assert len(s.mesh.faces) == 12
    np.testing.assert_allclose(s.bounds, [[-1, -1.5, -2], [1, 1.5, 2]])
    assert s.mesh.area == pytest.approx(52) and s.mesh.volume == pytest.approx(24)


def test_sphere():
    s = scene(shape("Sphere { radius 2 }"))
    np.testing.assert_allclose(s.bounds, [[-2] * 3, [2] * 3], rtol=0.05)
    assert s.mesh.area == pytest.approx(16 * math.pi, rel=0.03)
    assert s.mesh.volume == pytest.approx(32 * math.pi / 3, rel=0.05)


def test_cylinder_stands_on_local_y():
    s = scene(shape("Cylinder { radius 1 height 4 }"))
    assert len(s.mesh.faces) == 4 * 24
    np.testing.assert_allclose(s.bounds, [[-1, -2, -1], [1, 2, 1]], atol=1e-12)
    assert s.mesh.volume == pytest.approx(RING_AREA * 4)  # positive: faces point outward


@pytest.mark.parametrize(
    ("flags", "faces"),
    [("top FALSE", 72), ("bottom FALSE top FALSE", 48), ("side FALSE", 48), ("side FALSE bottom FALSE", 24)],
)
def test_cylinder_flags_drop_parts(flags, faces):
    assert len(scene(shape(f"Cylinder {{ {flags} }}")).mesh.faces) == faces


def test_cylinder_without_any_part_produces_no_object():
    s = scene(shape("Cylinder { side FALSE top FALSE bottom FALSE }"))
    assert s.objects == 0 and len(s.mesh.faces) == 0


def test_cone_points_up_local_y():
    s = scene(shape("Cone { bottomRadius 1 height 3 }"))
    assert len(s.mesh.faces) == 48
    np.testing.assert_allclose(s.bounds, [[-1, -1.5, -1], [1, 1.5, 1]], atol=1e-12)
    apex = s.mesh.vertices[s.mesh.vertices[:, 1] > 1.4]
    np.testing.assert_allclose(apex[:, [0, 2]], 0, atol=1e-12)
    assert s.mesh.volume == pytest.approx(RING_AREA * 3 / 3)
    assert len(scene(shape("Cone { bottom FALSE }")).mesh.faces) == 24


def test_elevation_grid():
    heights = " ".join(str(h) for h in range(12))
    s = scene(shape(f"ElevationGrid {{ xDimension 3 zDimension 4 xSpacing 2 zSpacing 0.5 height [ {heights} ] }}"))
    assert len(s.mesh.faces) == 2 * (3 - 1) * (4 - 1)
    assert [4.0, 5.0, 0.5] in s.mesh.vertices.tolist()  # x index 2, z index 1: height[1 * 3 + 2]
    np.testing.assert_allclose(s.bounds, [[0, 0, 0], [4, 11, 1.5]])


def test_elevation_grid_faces_up_unless_ccw_false():
    grid = "xDimension 2 zDimension 2 height [ 0 0 0 0 ]"
    up = scene(shape(f"ElevationGrid {{ {grid} }}"))
    down = scene(shape(f"ElevationGrid {{ {grid} ccw FALSE }}"))
    np.testing.assert_allclose(face_normals(up), [[0, 1, 0]] * 2, atol=1e-12)
    np.testing.assert_allclose(face_normals(down), [[0, -1, 0]] * 2, atol=1e-12)


def test_line_and_point_sets_add_nothing_silently():
    s = scene(
        shape("IndexedLineSet { coord Coordinate { point [ 0 0 0, 1 0 0 ] } coordIndex [ 0 1 ] }")
        + shape("PointSet { coord Coordinate { point [ 0 0 0 ] } }")
    )
    assert s.warnings == ["scene has no geometry"]


# --- files: Inline, gzip ---------------------------------------------------------------------------


def test_inline_urls_are_relative_to_the_including_file():
    s = load_scene(DATA / "inline" / "main.wrl")
    # two walls (main.wrl -> parts/wall.wrl), each with its post (parts/wall.wrl -> parts/post.wrl)
    assert s.objects == 4 and len(s.mesh.faces) == 4 * 12
    np.testing.assert_allclose(s.bounds, [[-12, -0.1, -1], [12, 0.1, 2.1]])


@pytest.mark.parametrize("name", ["yard.wrl.gz", "yard.wrz", "yard.wrl"])
def test_gzip_is_detected_by_its_magic_bytes(tmp_path, name):
    plain = load_scene(DATA / "yard.wrl")
    (tmp_path / name).write_bytes(gzip.compress((DATA / "yard.wrl").read_bytes()))
    packed = load_scene(tmp_path / name)
    np.testing.assert_array_equal(packed.mesh.faces, plain.mesh.faces)
    np.testing.assert_allclose(packed.mesh.vertices, plain.mesh.vertices)


def test_load_scene_keeps_its_path(tmp_path):
    shutil.copy(DATA / "yard.wrl", tmp_path / "y.wrl")
    assert load_scene(tmp_path / "y.wrl").path == tmp_path / "y.wrl"
    assert parse_scene(HEADER).path is None


# --- syntax --------------------------------------------------------------------------------------


def test_comments_and_commas_are_whitespace():
    s = scene(
        "Shape { # a comment with { [ \" in it\n"
        "  geometry IndexedFaceSet {\n"
        "    coord Coordinate { point [ 0 0 0, 1 0 0,, # inside a list ]\n"
        "                               0,1,0 ] }\n"
        "    coordIndex [ 0, 1, 2, -1, ]\n"
        "  }\n"
        "}\n"
        'WorldInfo { title "a # inside a string" }'
    )
    assert len(s.mesh.faces) == 1 and s.warnings == []


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_any_line_ending(newline):
    text = newline.join(["#VRML V2.0 utf8 exported by hand", "# comment", "Shape { geometry Box { } }"])
    assert len(parse_scene(text).mesh.faces) == 12


def test_values_parse_by_syntax_alone():
    nodes, skipped = parse(
        HEADER + 'Thing { n [ 1 -2 +3 .5 -0.25e1 1E2 0x1F -0xA ] s "say \\"hi\\" \\\\" b FALSE '
        'v 1 2 3 k Sub { } e [ ] m [ "a", "b" ] z NULL }'
    )
    fields = nodes[0].fields
    assert fields["n"].tolist() == [1, -2, 3, 0.5, -2.5, 100, 31, -10]
    assert fields["s"] == ['say "hi" \\']
    assert fields["b"] is False and fields["z"] is None and fields["e"] == []
    assert fields["v"].tolist() == [1, 2, 3] and fields["k"].type == "Sub"
    assert fields["m"] == ["a", "b"] and not skipped


def test_unknown_fields_on_known_nodes_are_ignored():
    s = scene('Shape { foo 1 2 3 bar "x" baz [ TRUE FALSE ] appearance NULL geometry Box { qux Group { } } }')
    assert len(s.mesh.faces) == 12 and s.warnings == []


def test_unsupported_things_are_skipped_with_one_warning_each():
    s = scene(
        "PROTO Lamp [ field SFFloat h 1 ] { Group { children [ Shape { geometry Box { } } ] } }\n"
        "PROTO Sign [ ] { Group { } }\n"
        'EXTERNPROTO Tree [ field SFFloat h ] [ "trees.wrl#Tree" "http://x/trees.wrl#Tree" ]\n'
        "Lamp { h 2 } Lamp { }\n"
        'DEF Logic Script { eventIn SFBool go field SFNode n NULL url "javascript: function go() { }" }\n'
        "DEF Clock TimeSensor { }\n"
        "ROUTE Clock.isActive TO Logic.go\n"
        "Group { children [ Shape { geometry Text { string \"A\" } } ] ROUTE Clock.isActive TO Logic.go }\n"
        + shape("Text { string [ \"B\" ] }")
        + shape("Box { }")
    )
    assert len(s.mesh.faces) == 12
    assert sorted(s.warnings) == [
        "skipped EXTERNPROTO declaration",
        "skipped PROTO declaration (2 times)",
        "skipped ROUTE statement (2 times)",
        "skipped unsupported node Lamp (2 times)",
        "skipped unsupported node Script",
        "skipped unsupported node Text (2 times)",
    ]


def test_empty_scene_is_allowed_with_a_warning():
    s = parse_scene(HEADER + "WorldInfo { }")
    assert len(s.mesh.faces) == 0 and s.objects == 0
    assert s.warnings == ["scene has no geometry"]
    np.testing.assert_array_equal(s.bounds, np.zeros((2, 3)))


# --- colours, start ------------------------------------------------------------------------------


def test_face_colors_come_from_each_shapes_material():
    s = scene(
        shape("Box { }", "appearance Appearance { material Material { diffuseColor 1 0 0 } }")
        + shape("Box { }", "appearance Appearance { material Material { diffuseColor 0 0 1 transparency 0.25 } }")
        + shape("Box { }", "appearance Appearance { }")
        + shape("Box { }")
    )
    expected = [[255, 0, 0, 255]] * 12 + [[0, 0, 255, 191]] * 12 + [[204, 204, 204, 255]] * 24
    assert s.face_colors.dtype == np.uint8 and s.face_colors.tolist() == expected
    np.testing.assert_array_equal(s.mesh.visual.face_colors, s.face_colors)


def test_start_comes_from_the_viewpoint_named_start():
    s = scene(
        "Viewpoint { position 1 1 1 }\n"
        f"Transform {{ translation 100 0 0 rotation 0 0 1 {-math.pi / 2} children [\n"
        f"  DEF Start Viewpoint {{ position 0 10 2 orientation 1 0 0 {math.pi / 2} }} ] }}"
    )
    assert s.start == pytest.approx((110, 0, 2))  # the eye height comes too
    assert s.start_heading == pytest.approx(90)  # looks north, turned clockwise a quarter: east


def test_start_heading_is_none_when_looking_straight_down():
    s = scene("DEF Start Viewpoint { position 3 4 50 }")  # default orientation looks along -z
    assert s.start == pytest.approx((3, 4, 50)) and s.start_heading is None


def test_no_start_without_a_viewpoint_named_start():
    s = scene("DEF Gate Viewpoint { position 3 4 50 }")
    assert s.start is None and s.start_heading is None


def test_yard_fixture():
    s = load_scene(DATA / "yard.wrl")
    assert len(s.mesh.faces) == 184 and s.objects == 5
    assert s.start == pytest.approx((5, -10, 1.7)) and s.start_heading == pytest.approx(0, abs=1e-6)
    assert s.face_colors[s.face_object == 2][0].tolist() == [255, 255, 255, 128]


# --- the real scene --------------------------------------------------------------------------------


def test_castle():
    if not CASTLE.exists():
        pytest.skip("needs ../shared/scenes/castle.wrl (absent in a bare clone)")
    s = load_scene(CASTLE)
    # 438 quads + 190 triangles; 10 Shapes in the text plus 4 USE of the tower mesh (ME_MeshWieza)
    assert len(s.mesh.faces) == 2 * 438 + 190
    assert s.objects == 14
    np.testing.assert_allclose(s.bounds, [[-127.795, -98.448, -1.98], [128.362, 104.928, 64.0]], atol=1e-3)
    assert s.warnings == [] and s.start is None
