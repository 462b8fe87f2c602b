"""The world a simulated vehicle moves in: a VRML97 file as one triangle mesh, with colours and a start.

Frame: right-handed, Z-up, metres, x east, y north. The Blender exports we meet are already Z-up, so
coordinates are used as they are; VRML's Y-up only shows in the local frames of primitives and
ElevationGrid, which the file's own transforms place. Triangles are kept as the file gives them
(trimesh `process=False`): sensors cast rays into them, and merging or dropping faces would change
what they see. Parsing is in `vehicle.world.vrml`; this module interprets the node tree.
"""

import functools
import math
import os
from collections import Counter
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import mapbox_earcut
import numpy as np

from vehicle.world.vrml import MAX_DEPTH, Node, SceneError, decode, parse

__all__ = ["Scene", "SceneError", "load_scene", "parse_scene"]

DEFAULT_COLOR = (204, 204, 204, 255)  # VRML's default diffuseColor 0.8
SEGMENTS = 24  # around a Cylinder or Cone
MAX_INSTANCES = 1_000_000  # node visits after DEF/USE expansion: refuses exponential USE chains
MAX_TRIANGLES = 20_000_000

# Standard VRML97 nodes that never carry geometry: ignored without a warning.
_NON_GEOMETRIC = frozenset(
    """AudioClip Background ColorInterpolator CoordinateInterpolator CylinderSensor DirectionalLight
    Fog FontStyle NavigationInfo NormalInterpolator OrientationInterpolator PlaneSensor PointLight
    PositionInterpolator ProximitySensor ScalarInterpolator Sound SphereSensor SpotLight TimeSensor
    TouchSensor VisibilitySensor WorldInfo""".split()
)
_WITHOUT_TRIANGLES = frozenset({"IndexedLineSet", "PointSet"})
_NO_FACES = np.zeros((0, 3), dtype=np.int64)
_ZERO = 1e-12  # a cross product shorter than this has no direction (trimesh's tolerance)
T = TypeVar("T")


@dataclass
class Scene:
    """A loaded scene: its triangles, a colour and a Shape instance per triangle, and its start.

    The triangles are plain arrays: the simulation casts rays into them and sweeps the body against
    them without trimesh, whose import alone costs a command-line run half a second. ``mesh`` builds
    the trimesh (for display, and for the ray caster's pure-numpy fallback) on first use.
    """

    path: Path | None
    vertices: np.ndarray  # (n, 3) float64, scene metres
    faces: np.ndarray  # (n_faces, 3) int64 indices into vertices
    face_colors: np.ndarray  # (n_faces, 4) uint8 RGBA
    face_object: np.ndarray  # (n_faces,) int32 index of the Shape instance
    objects: int
    warnings: list[str] = field(default_factory=list)
    start: tuple[float, float, float] | None = None  # Viewpoint "Start": x, y and the height of the eye
    start_heading: float | None = None  # compass degrees of its view direction; None if vertical
    hints: dict[str, str] = field(default_factory=dict)  # "name=value" strings of a WorldInfo's info
    object_names: list[str] = field(default_factory=list)  # per Shape instance: the nearest DEF name ("": none)
    _prepared: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @functools.cached_property
    def triangles(self) -> np.ndarray:
        """(n_faces, 3, 3) corners of every triangle."""
        return self.vertices[self.faces]

    @functools.cached_property
    def face_normals(self) -> np.ndarray:
        """(n_faces, 3) unit normals (by the right-hand rule), zero for a triangle without area; the same
        floating-point values trimesh gives."""
        corners = self.triangles
        crosses = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1])
        norm = np.sqrt(np.dot(crosses * crosses, [1.0, 1.0, 1.0]))
        valid = norm > _ZERO
        norm[valid] **= -1
        return np.where(valid[:, None], crosses * norm.reshape((-1, 1)), 0.0)

    @functools.cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest corner of the triangles; zeros for an empty scene. Kept (read-only): the
        3D view's every frame and the station's health ask for it."""
        if not len(self.faces):
            box = np.zeros((2, 3))
        else:
            corners = self.triangles.reshape(-1, 3)
            box = np.array([corners.min(axis=0), corners.max(axis=0)])
        box.flags.writeable = False
        return box

    @functools.cached_property
    def mesh(self):
        """The scene as a ``trimesh.Trimesh`` with its face colours (built, and trimesh loaded, on first use)."""
        import trimesh

        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)
        if len(self.faces):
            mesh.visual.face_colors = self.face_colors
        return mesh

    def prepared(self, key: Hashable, build: Callable[[], T]) -> T:
        """What ``build()`` makes from the triangles (a ray caster's BVH, a collision grid), made once
        per scene and shared by every run in it: a scene does not change after loading."""
        if key not in self._prepared:
            self._prepared[key] = build()
        return self._prepared[key]

    def __getstate__(self) -> dict:
        """Pickled (to a worker process) without what was prepared or derived: an Embree scene does not
        pickle, and the rest is quicker made again."""
        derived = ("triangles", "face_normals", "mesh")
        return {**{k: v for k, v in self.__dict__.items() if k not in derived}, "_prepared": {}}


def load_scene(path: str | Path) -> Scene:
    """Load a VRML97 file (gzipped or not); any problem raises SceneError."""
    path = Path(path)
    data = _read(path)
    return _Builder(path).build(data, scene_path=path)


def parse_scene(text: str | bytes, path: str | Path = "<string>") -> Scene:
    """Build a scene from VRML text; `path` names it in errors and anchors relative Inline URLs."""
    return _Builder(Path(path)).build(text, scene_path=None)


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except (OSError, ValueError) as e:
        raise SceneError(f"cannot read file: {getattr(e, 'strerror', None) or e}", str(path)) from None


class _Builder:
    """Walks the node tree, instancing USE and Inline again each time, collecting Shape triangles."""

    def __init__(self, path: Path):
        self.path = path
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.colors: list[tuple[int, ...]] = []
        self.names: list[str] = []  # of the DEF'd nodes being walked, innermost last
        self.object_names: list[str] = []
        self.skipped: Counter[str] = Counter()
        self.files = [_absolute(path)]  # the Inline chain being walked, to refuse cycles
        self.parsed: dict[Path, list[Node]] = {}
        self.instances = 0
        self.triangles = 0
        self.start: tuple[float, float] | None = None
        self.start_heading: float | None = None
        self.hints: dict[str, str] = {}
        self.handlers: dict[str, Callable[[Node, np.ndarray, int], None]] = {
            "Transform": self._transform,
            "Group": self._group,
            "Collision": self._group,
            "Anchor": self._group,
            "Billboard": self._group,
            "Switch": self._switch,
            "LOD": self._lod,
            "Inline": self._inline,
            "Shape": self._shape,
            "Viewpoint": self._viewpoint,
            "WorldInfo": self._world_info,
        }

    def build(self, data: str | bytes, scene_path: Path | None) -> Scene:
        self._walk_all(self._parse(data, str(self.path)), np.eye(4), 0)
        return self._scene(scene_path)

    def _parse(self, data: str | bytes, file: str) -> list[Node]:
        nodes, skipped = parse(decode(data, file) if isinstance(data, bytes) else data, file)
        self.skipped.update(skipped)
        return nodes

    def _walk_all(self, nodes: list[Node], matrix: np.ndarray, depth: int) -> None:
        for node in nodes:
            self._walk(node, matrix, depth + 1)

    def _walk(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        if depth > MAX_DEPTH:
            raise node.error(f"scene nested more than {MAX_DEPTH} levels deep")
        self.instances += 1
        if self.instances > MAX_INSTANCES:
            raise node.error(f"more than {MAX_INSTANCES} node instances after DEF/USE expansion")
        handler = self.handlers.get(node.type)
        if handler is not None:
            if node.name:  # what a person calls the shapes inside (a DEF'd Transform: "Office")
                self.names.append(node.name)
            try:
                handler(node, matrix, depth)
            finally:
                if node.name:
                    self.names.pop()
        elif node.type not in _NON_GEOMETRIC:
            self.skipped[f"unsupported node {node.type}"] += 1

    # --- grouping nodes ----------------------------------------------------------------------

    def _group(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        self._walk_all(_nodes(node, "children"), matrix, depth)

    def _transform(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        self._walk_all(_nodes(node, "children"), matrix @ _transform_matrix(node), depth)

    def _switch(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        choices = _nodes(node, "choice") or _nodes(node, "children")  # VRML97 or X3D naming
        which = _int(node, "whichChoice", -1)
        if 0 <= which < len(choices):
            self._walk(choices[which], matrix, depth + 1)

    def _lod(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        levels = _nodes(node, "level") or _nodes(node, "children")
        self._walk_all(levels[:1], matrix, depth)

    def _inline(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        path = self._inline_target(node)
        if path in self.files:
            chain = [p.name for p in self.files[self.files.index(path) :]] + [path.name]
            raise node.error(f"Inline cycle: {' -> '.join(chain)}", "url")
        if path not in self.parsed:
            self.parsed[path] = self._parse(_read(path), str(path))
        self.files.append(path)
        self._walk_all(self.parsed[path], matrix, depth)
        self.files.pop()

    def _inline_target(self, node: Node) -> Path:
        """The first url naming an existing file, relative to the including file."""
        urls = _strings(node, "url")
        for url in urls:
            try:
                candidate = _absolute(self.files[-1].parent / url)
                if candidate.is_file():
                    return candidate
            except (OSError, ValueError):  # unusable as a path: try the next url
                continue
        raise node.error(f"Inline target not found: {urls}", "url")

    # --- leaves ------------------------------------------------------------------------------

    def _shape(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        geometry = _node(node, "geometry")
        if geometry is None or geometry.type in _WITHOUT_TRIANGLES:
            return
        build = _GEOMETRY.get(geometry.type)
        if build is None:
            self.skipped[f"unsupported node {geometry.type}"] += 1
            return
        vertices, faces, *dropped = build(geometry)
        if dropped and dropped[0]:
            self.skipped["faces whose coordIndex points past their coordinates"] += dropped[0]
        if len(faces):
            self._add(node, vertices, faces, matrix)

    def _add(self, shape: Node, vertices: np.ndarray, faces: np.ndarray, matrix: np.ndarray) -> None:
        self.triangles += len(faces)
        if self.triangles > MAX_TRIANGLES:
            raise shape.error(f"scene has more than {MAX_TRIANGLES} triangles")
        with np.errstate(over="ignore", invalid="ignore"):
            world = vertices @ matrix[:3, :3].T + matrix[:3, 3]
        if not np.isfinite(world).all():
            raise shape.error("coordinates overflow once transformed")
        self.vertices.append(world)
        self.faces.append(faces)
        self.colors.append(_color(_node(shape, "appearance")))
        self.object_names.append(self.names[-1] if self.names else "")

    def _viewpoint(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        """The first Viewpoint DEF'd as Start gives the default start position and heading."""
        if node.name != "Start" or self.start is not None:
            return
        x, y, z = matrix[:3, :3] @ _vector(node, "position", (0, 0, 10)) + matrix[:3, 3]
        view = matrix[:3, :3] @ _rotation(_vector(node, "orientation", (0, 0, 1, 0))) @ (0, 0, -1)
        self.start = (float(x), float(y), float(z))
        if math.hypot(view[0], view[1]) > 1e-6 * np.linalg.norm(view):
            self.start_heading = math.degrees(math.atan2(view[0], view[1])) % 360

    def _world_info(self, node: Node, matrix: np.ndarray, depth: int) -> None:
        """``info ["altitude=1.2"]``: settings the scene suggests for missions flown in it."""
        for text in _strings(node, "info"):
            name, sep, value = text.partition("=")
            if sep and name.strip():
                self.hints.setdefault(name.strip(), value.strip())

    def _scene(self, path: Path | None) -> Scene:
        counts = [len(f) for f in self.faces]
        offsets = np.cumsum([0] + [len(v) for v in self.vertices])[:-1]
        vertices = np.concatenate(self.vertices) if self.vertices else np.zeros((0, 3))
        faces = np.concatenate([f + o for f, o in zip(self.faces, offsets, strict=True)] or [_NO_FACES])
        colors = np.repeat(np.array(self.colors, dtype=np.uint8).reshape(-1, 4), counts, axis=0)
        warnings = [f"skipped {what}" + (f" ({n} times)" if n > 1 else "") for what, n in self.skipped.items()]
        if not len(faces):
            warnings.append("scene has no geometry")
        return Scene(
            path=path,
            vertices=np.asarray(vertices, dtype=np.float64),
            faces=np.asarray(faces, dtype=np.int64),
            face_colors=colors,
            face_object=np.repeat(np.arange(len(counts), dtype=np.int32), counts),
            objects=len(counts),
            warnings=warnings,
            start=self.start,
            start_heading=self.start_heading,
            hints=self.hints,
            object_names=self.object_names,
        )


def _absolute(path: Path) -> Path:
    return Path(os.path.realpath(path))


# --- transforms and colours ----------------------------------------------------------------------


def _transform_matrix(node: Node) -> np.ndarray:
    """A Transform's 4x4 matrix, T * C * R * SR * S * SR^-1 * C^-1 as VRML97 defines it."""
    center = _vector(node, "center", (0, 0, 0))
    orientation = _rotation(_vector(node, "scaleOrientation", (0, 0, 1, 0)))
    scale = np.diag(_vector(node, "scale", (1, 1, 1)))
    linear = _rotation(_vector(node, "rotation", (0, 0, 1, 0))) @ orientation @ scale @ orientation.T
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    matrix[:3, 3] = _vector(node, "translation", (0, 0, 0)) + center - linear @ center
    return matrix


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    """3x3 matrix of a VRML rotation (axis x y z, angle in radians); a zero axis means none."""
    axis, angle = axis_angle[:3], axis_angle[3]
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3)
    axis = axis / np.sqrt(np.dot(axis, axis))  # Rodrigues' formula, as trimesh.transformations writes it
    sin, cos = np.sin(angle), np.cos(angle)
    matrix = np.diag([cos, cos, cos]) + np.outer(axis, axis) * (1.0 - cos)
    x, y, z = axis * sin
    return matrix + np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _color(appearance: Node | None) -> tuple[int, ...]:
    material = None if appearance is None else _node(appearance, "material")
    if material is None:
        return DEFAULT_COLOR
    rgb = _vector(material, "diffuseColor", (0.8, 0.8, 0.8))
    alpha = 1.0 - _float(material, "transparency", 0.0)
    return tuple(int(c) for c in np.round(np.clip([*rgb, alpha], 0, 1) * 255))


# --- geometry: each returns (vertices (n, 3) float, faces (m, 3) int) in the node's local frame -----


def _indexed_face_set(node: Node) -> tuple[np.ndarray, np.ndarray, int]:
    """Its points and triangles, and how many faces it dropped for naming a point it does not have (as VRML
    browsers do, the rest of the shape stands)."""
    points = _coordinates(node)
    index = _integers(node, "coordIndex")
    bad = (index < -1) | (index >= len(points))
    dropped = 0
    if bad.any():
        face = np.cumsum(index == -1) - (index == -1)  # the face each entry belongs to (a -1 ends its own)
        broken = np.unique(face[bad])
        dropped = len(broken)
        index = index[~np.isin(face, broken)]
    with np.errstate(over="ignore", invalid="ignore"):  # polygons too huge for their normal are dropped
        faces = _triangulate(points, index)
    return points, faces if _bool(node, "ccw", True) else faces[:, ::-1], dropped


def _coordinates(node: Node) -> np.ndarray:
    coord = _node(node, "coord")
    if coord is None:
        return np.zeros((0, 3))
    if coord.type != "Coordinate":
        raise coord.error(f"expected a Coordinate node, found {coord.type}")
    point = _numbers(coord, "point", ())
    if point.size % 3:
        raise coord.error(f"point has {point.size} numbers, not a multiple of 3", "point")
    return point.reshape(-1, 3)


def _triangulate(points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Triangles of the -1 separated polygons in `index`, in file order.

    Polygons are handled in batches of equal size; those with fewer than 3 distinct vertices are
    skipped, as VRML says.
    """
    ends = np.flatnonzero(index == -1)
    starts = np.concatenate(([0], ends + 1))
    sizes = np.append(ends, len(index)) - starts  # a last polygon without -1 counts too
    triangles, owners = [_NO_FACES], [np.zeros(0, dtype=np.int64)]
    for size in np.unique(sizes[sizes >= 3]):
        ids = np.flatnonzero(sizes == size)
        polygons = index[starts[ids, None] + np.arange(size)]
        keep = (np.diff(np.sort(polygons, axis=1), axis=1) != 0).sum(axis=1) >= 2  # 3 distinct
        found, rows = _triangulate_polygons(points, polygons[keep])
        triangles.append(found)
        owners.append(ids[keep][rows])
    order = np.argsort(np.concatenate(owners), kind="stable")
    return np.concatenate(triangles)[order]


def _triangulate_polygons(points: np.ndarray, polygons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of k polygons of one size, and the polygon row each came from.

    Convex polygons (the common case) are fanned in one numpy step; the others go through earcut.
    """
    count, size = polygons.shape
    if size == 3:
        return polygons, np.arange(count)
    corners = points[polygons]
    normals = _newell_normals(corners)
    convex = _is_convex(corners, normals)
    fan = np.column_stack((np.zeros(size - 2, dtype=np.int64), np.arange(1, size - 1), np.arange(2, size)))
    triangles = [polygons[convex][:, fan].reshape(-1, 3)]
    rows = [np.repeat(np.flatnonzero(convex), size - 2)]
    for row in np.flatnonzero(~convex):
        local = _earcut(corners[row], normals[row])
        triangles.append(polygons[row][local])
        rows.append(np.full(len(local), row))
    return np.concatenate(triangles), np.concatenate(rows)


def _newell_normals(corners: np.ndarray) -> np.ndarray:
    """Normals of the best-fit planes of (k, n, 3) polygons, with length twice their area."""
    centred = corners - corners.mean(axis=1, keepdims=True)
    return np.cross(centred, np.roll(centred, -1, axis=1)).sum(axis=1)


def _is_convex(corners: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Whether each polygon turns the same way (about its normal) at every corner."""
    edges = np.roll(corners, -1, axis=1) - corners
    turns = np.einsum("kij,kj->ki", np.cross(edges, np.roll(edges, -1, axis=1)), normals)
    tolerance = 1e-9 * np.einsum("kj,kj->k", normals, normals)
    return (turns >= -tolerance[:, None]).all(axis=1)


def _earcut(corners: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Triangulate one polygon projected onto its plane; triangles wind like the polygon."""
    length = np.linalg.norm(normal)
    unit = normal / length if length > 0 else np.array([0.0, 0.0, 1.0])
    u = np.cross(unit, np.eye(3)[np.argmin(np.abs(unit))])
    u /= np.linalg.norm(u)
    flat = np.column_stack((corners @ u, corners @ np.cross(unit, u)))  # (u, v, normal) right-handed
    if not np.isfinite(flat).all():
        return _NO_FACES
    rings = np.array([len(flat)], dtype=np.uint32)
    triangles = mapbox_earcut.triangulate_float64(flat, rings).astype(np.int64).reshape(-1, 3)
    ab = flat[triangles[:, 1]] - flat[triangles[:, 0]]
    ac = flat[triangles[:, 2]] - flat[triangles[:, 0]]
    clockwise = ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0] < 0
    triangles[clockwise] = triangles[clockwise][:, ::-1]
    return triangles


def _elevation_grid(node: Node) -> tuple[np.ndarray, np.ndarray]:
    """Heights over the local XZ plane (x fastest), two triangles per square, facing +Y."""
    nx, nz = _int(node, "xDimension", 0), _int(node, "zDimension", 0)
    heights = _numbers(node, "height", ())
    if nx < 0 or nz < 0 or heights.size != nx * nz:
        raise node.error(f"height has {heights.size} values for a {nx} x {nz} grid", "height")
    if nx < 2 or nz < 2:
        return np.zeros((0, 3)), _NO_FACES
    i, j = np.meshgrid(np.arange(nx), np.arange(nz))
    spacing = _float(node, "xSpacing", 1.0), _float(node, "zSpacing", 1.0)
    vertices = np.column_stack((i.ravel() * spacing[0], heights, j.ravel() * spacing[1]))
    a = (j[:-1, :-1] * nx + i[:-1, :-1]).ravel()
    b, c = a + 1, a + nx
    faces = np.stack((np.column_stack((a, c, b)), np.column_stack((b, c, c + 1))), axis=1).reshape(-1, 3)
    return vertices, faces if _bool(node, "ccw", True) else faces[:, ::-1]


def _box(node: Node) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces = _unit_mesh("box")
    return vertices * _vector(node, "size", (2, 2, 2)), faces


def _sphere(node: Node) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces = _unit_mesh("sphere")
    return vertices * _float(node, "radius", 1.0), faces


_BOX_VERTICES = np.array([[-0.5, -0.5, -0.5], [-0.5, -0.5, 0.5], [-0.5, 0.5, -0.5], [-0.5, 0.5, 0.5],
                          [0.5, -0.5, -0.5], [0.5, -0.5, 0.5], [0.5, 0.5, -0.5], [0.5, 0.5, 0.5]])
_BOX_FACES = np.array([[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4], [5, 7, 1], [3, 7, 2],
                       [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]], dtype=np.int64)


@functools.cache
def _unit_mesh(kind: str) -> tuple[np.ndarray, np.ndarray]:
    """A unit cube (trimesh's ``creation.box``, written out), or a unit sphere (trimesh's ``icosphere(2)``,
    loaded with trimesh only when a scene has a sphere)."""
    if kind == "box":
        vertices, faces = _BOX_VERTICES.copy(), _BOX_FACES.copy()
    else:
        import trimesh

        mesh = trimesh.creation.icosphere(2)
        vertices, faces = np.array(mesh.vertices), np.array(mesh.faces, dtype=np.int64)
    vertices.flags.writeable = faces.flags.writeable = False  # shared by every instance
    return vertices, faces


def _cylinder(node: Node) -> tuple[np.ndarray, np.ndarray]:
    radius = _float(node, "radius", 1.0)
    parts = {part: _bool(node, part, True) for part in ("bottom", "top", "side")}
    return _frustum(radius, radius, _float(node, "height", 2.0), **parts)


def _cone(node: Node) -> tuple[np.ndarray, np.ndarray]:
    parts = {part: _bool(node, part, True) for part in ("bottom", "side")}
    return _frustum(_float(node, "bottomRadius", 1.0), 0.0, _float(node, "height", 2.0), top=False, **parts)


def _frustum(
    bottom_radius: float, top_radius: float, height: float, *, bottom: bool, top: bool, side: bool
) -> tuple[np.ndarray, np.ndarray]:
    """A Cylinder, or a Cone when top_radius is 0: axis +Y, centred on the origin, faces outward."""
    n = SEGMENTS
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.column_stack((np.cos(angles), np.zeros(n), np.sin(angles)))
    half = np.array([0.0, height / 2, 0.0])
    vertices = np.concatenate((ring * bottom_radius - half, ring * top_radius + half, [-half, half]))
    k = np.arange(n)
    k1 = (k + 1) % n
    parts = [_NO_FACES]
    if side:
        parts.append(np.column_stack((k, n + k, k1)))
        if top_radius > 0:
            parts.append(np.column_stack((k1, n + k, n + k1)))
    if bottom:
        parts.append(np.column_stack((np.full(n, 2 * n), k, k1)))
    if top:
        parts.append(np.column_stack((np.full(n, 2 * n + 1), n + k1, n + k)))
    return vertices, np.concatenate(parts)


_GEOMETRY: dict[str, Callable[[Node], tuple[np.ndarray, np.ndarray]]] = {
    "IndexedFaceSet": _indexed_face_set,
    "ElevationGrid": _elevation_grid,
    "Box": _box,
    "Sphere": _sphere,
    "Cylinder": _cylinder,
    "Cone": _cone,
}


# --- typed field access: a value of the wrong kind is a SceneError at that field -----------------


def _node(node: Node, name: str) -> Node | None:
    value = node.fields.get(name)
    if value is None or isinstance(value, Node):
        return value
    raise node.error(f"{name} must be a node or NULL", name)


def _nodes(node: Node, name: str) -> list[Node]:
    value = node.fields.get(name)
    if value is None:
        return []
    if isinstance(value, Node):
        return [value]
    if isinstance(value, list) and all(isinstance(v, Node) for v in value):
        return value
    raise node.error(f"{name} must be a list of nodes", name)


def _numbers(node: Node, name: str, default: tuple) -> np.ndarray:
    if name not in node.fields:
        return np.array(default, dtype=np.float64)
    value = node.fields[name]
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, list) and not value:
        return np.zeros(0)
    raise node.error(f"{name} must be numbers", name)


def _vector(node: Node, name: str, default: tuple) -> np.ndarray:
    values = _numbers(node, name, default)
    if len(values) != len(default):
        raise node.error(f"{name} needs {len(default)} numbers, found {len(values)}", name)
    return values


def _float(node: Node, name: str, default: float) -> float:
    return float(_vector(node, name, (default,))[0])


def _int(node: Node, name: str, default: int) -> int:
    value = _float(node, name, default)
    if not (value.is_integer() and abs(value) < 2**31):
        raise node.error(f"{name} must be a 32-bit integer", name)
    return int(value)


def _integers(node: Node, name: str) -> np.ndarray:
    values = _numbers(node, name, ())
    if not ((np.abs(values) < 2**31) & (values == np.round(values))).all():
        raise node.error(f"{name} must be 32-bit integers", name)
    return values.astype(np.int64)


def _bool(node: Node, name: str, default: bool) -> bool:
    value = node.fields.get(name, default)
    if isinstance(value, bool):
        return value
    raise node.error(f"{name} must be TRUE or FALSE", name)


def _strings(node: Node, name: str) -> list[str]:
    value = node.fields.get(name, [])
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return value
    raise node.error(f"{name} must be strings", name)
