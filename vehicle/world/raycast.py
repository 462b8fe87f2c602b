"""First-hit ray casting into the scene mesh.

Embree (through ``embreex``) answers a small batch of rays in a few microseconds
when called directly, while trimesh's wrapper costs about 90 us per call, which
would dominate a simulation step; so the Embree scene is driven directly here.
trimesh's pure-numpy intersector is the fallback where embreex is missing
(about 5,000 rays/s); both backends return the same distances (Embree's are
float32, so they agree to a fraction of a millimetre).
"""

from __future__ import annotations

import numpy as np

try:  # embreex ships wheels for x86_64 only
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh
except ImportError:  # pragma: no cover - exercised on machines without embreex
    rtcore_scene = None

MISS = np.inf


def embree_available() -> bool:
    return rtcore_scene is not None


class RayCaster:
    """Casts batches of rays and returns, per ray, the distance to the first hit and the face hit.

    ``cast(origins, directions)`` takes (n, 3) arrays of origins and unit directions and
    returns ``(distance, face)``: distance is ``inf`` and face is -1 where a ray hits nothing
    (float32 and int32 arrays from Embree, float64 and int64 from the numpy fallback).
    """

    def __init__(self, geometry, backend: str = "auto"):
        """``geometry``: a Scene or a trimesh (anything with ``triangles`` and ``face_normals``)."""
        if backend == "auto":
            backend = "embree" if embree_available() else "numpy"
        if backend not in ("embree", "numpy"):
            raise ValueError(f"unknown ray-casting backend {backend!r}")
        if backend == "embree" and not embree_available():
            raise RuntimeError("the embree backend needs the embreex package")
        self.backend = backend
        # plain arrays: trimesh's cached properties re-hash the mesh on every access
        self.triangles = np.asarray(geometry.triangles, dtype=np.float64).reshape(-1, 3, 3)
        self.face_normals = np.asarray(geometry.face_normals, dtype=np.float64).reshape(-1, 3)
        self._empty = len(self.triangles) == 0
        self.top = float(self.triangles[..., 2].max()) if not self._empty else 0.0
        self._origins: dict[int, np.ndarray] = {}  # cast_from's float32 origin buffers, by ray count
        self._down_origin = np.zeros((1, 3), dtype=np.float32)
        self._down = np.array([[0.0, 0.0, -1.0]], dtype=np.float32)
        if self._empty:
            return
        if backend == "embree":
            self._scene = rtcore_scene.EmbreeScene()
            TriangleMesh(self._scene, self.triangles.astype(np.float32))
        else:
            import trimesh  # the pure-numpy fallback is trimesh's

            mesh = trimesh.Trimesh(self.triangles.reshape(-1, 3), np.arange(3 * len(self.triangles)).reshape(-1, 3),
                                   process=False, validate=False)
            self._intersector = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        n = len(origins)
        if self._empty or n == 0:
            return np.full(n, MISS), np.full(n, -1, dtype=np.int64)
        if self.backend == "embree":
            return self._cast_embree(origins, directions)
        return self._cast_numpy(origins, directions)

    def cast_from(self, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cast`` for rays that share one origin (a sensor), without the broadcasting overhead."""
        if self.backend != "embree" or self._empty:
            return self.cast(np.broadcast_to(origin, directions.shape), directions)
        origins = self._origins.get(len(directions))
        if origins is None:
            origins = self._origins[len(directions)] = np.empty(directions.shape, dtype=np.float32)
        origins[:] = origin  # Embree only reads it: the buffer is reused, the float32 values are the same
        return self._cast_embree(origins, directions)

    def cast_down(self, x: float, y: float, z: float) -> tuple[float, int]:
        """One ray straight down from (x, y, z): (distance, face), (inf, -1) where it hits nothing. ``cast``
        without the array conversions, for the ground check a low copter or a rover makes every step."""
        if self.backend != "embree" or self._empty:
            distance, face = self.cast(np.array([[x, y, z]]), np.array([[0.0, 0.0, -1.0]]))
            return float(distance[0]), int(face[0])
        origin = self._down_origin
        origin[0, 0], origin[0, 1], origin[0, 2] = x, y, z
        result = self._scene.run(origin, self._down, output=1)
        face = int(result["primID"][0])
        return (float(result["tfar"][0]) if face >= 0 else MISS), face

    def _cast_embree(self, origins, directions):
        result = self._scene.run(origins.astype(np.float32, copy=False), directions.astype(np.float32, copy=False),
                                 output=1)
        face, distance = result["primID"], result["tfar"]  # int32 and float32, as Embree gives them
        distance[face < 0] = MISS
        return distance, face

    def _cast_numpy(self, origins, directions):
        face, ray, points = self._intersector.intersects_id(
            origins, directions, multiple_hits=False, return_locations=True
        )
        distance = np.full(len(origins), MISS)
        faces = np.full(len(origins), -1, dtype=np.int64)
        if len(ray):
            distance[ray] = np.einsum("ij,ij->i", points - origins[ray], directions[ray])
            faces[ray] = face
        return distance, faces

    def ground_height(self, x: float, y: float, default: float = 0.0, below: float | None = None) -> float:
        """Height of the highest surface a vertical ray from above meets at (x, y); with ``below``, the highest
        surface below that height (the floor of a roofed room, not its roof). ``default`` where there is none."""
        if self._empty:
            return default
        top = self.top + 10.0 if below is None else below
        distance, _ = self.cast(np.array([[x, y, top]]), np.array([[0.0, 0.0, -1.0]]))
        return default if not np.isfinite(distance[0]) else top - float(distance[0])
