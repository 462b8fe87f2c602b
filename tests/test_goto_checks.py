"""Which closed solid of a scene holds a Go here target: named as the scene names it, at the vehicle's height."""

from __future__ import annotations

from harness import load_default_scene

from groundstation.commands import solid_at
from vehicle.world.scene import parse_scene


def test_a_target_inside_a_building_of_the_demo_scene_is_named_by_its_def():
    scene = load_default_scene()
    assert solid_at(scene, -25.0, -22.0, 0.5) == "Office"  # the Office spans x -30..-20, y -28..-16, 9 m high
    assert solid_at(scene, -25.0, -22.0, 10.0) is None  # over its roof
    assert solid_at(scene, -20.01, -16.01, 0.5) == "Office"  # inside, a hair from two walls
    assert solid_at(scene, -19.9, -22.0, 0.5) is None  # a hand's width outside
    assert solid_at(scene, 0.0, 0.0, 0.5) is None  # the open ground at the start


def test_a_roof_alone_or_a_floor_alone_is_no_closed_solid():
    scene = parse_scene("""#VRML V2.0 utf8
DEF Shelter Transform { translation 0 0 3 children Shape { geometry IndexedFaceSet {
  coord Coordinate { point [ -2 -2 0, 2 -2 0, 2 2 0, -2 2 0 ] } coordIndex [ 0 1 2 3 -1 ] } } }
DEF Hut Transform { translation 10 0 1 children Shape { geometry Box { size 2 2 2 } } }
""")
    assert solid_at(scene, 0.0, 0.0, 1.0) is None  # under the shelter's roof
    assert solid_at(scene, 0.0, 0.0, 5.0) is None  # over it
    assert solid_at(scene, 10.0, 0.0, 1.0) == "Hut"  # on the diagonals of the box's faces, exactly
