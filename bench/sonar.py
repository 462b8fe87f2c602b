"""Rays per second into castle.wrl, with Embree and with the pure-numpy fallback.

Batches of 100,000 rays, of one reading of the default sonars (as the simulation
casts them), and the numpy fallback. Target: at least 1,000,000 rays/s on one core
with Embree.
Run: python bench/sonar.py
"""

from __future__ import annotations

import time

import numpy as np
from common import castle_or_default, table

from vehicle.world.raycast import RayCaster, embree_available
from vehicle.world.scene import load_scene
from vehicle.world.suites import DEFAULT_SUITE, sensor_suite


def rays_per_second(caster: RayCaster, origins: np.ndarray, directions: np.ndarray, seconds: float = 1.0) -> float:
    done, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        caster.cast(origins, directions)
        done += len(origins)
    return done / (time.perf_counter() - started)


def main() -> None:
    scene_path = castle_or_default()
    scene = load_scene(scene_path)
    rng = np.random.default_rng(1)
    centre = scene.bounds.mean(axis=0)
    rows = []
    one_read = sum(len(sonar._local_rays) for sonar in sensor_suite(DEFAULT_SUITE))  # the default suite's rays
    for backend, batch in (("embree", 100_000), ("embree", one_read), ("numpy", 2_000)):
        if backend == "embree" and not embree_available():
            continue
        origins = centre + rng.uniform(-40, 40, (batch, 3)) * (1, 1, 0.1)
        directions = rng.normal(size=(batch, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        caster = RayCaster(scene, backend)
        rate = rays_per_second(caster, origins, directions)
        target = ">= 1,000,000" if (backend, batch) == ("embree", 100_000) else "-"
        rows.append([backend, f"{batch:,}", f"{rate:,.0f}", target])
    print(f"scene: {scene_path.name}, {len(scene.faces)} triangles")
    print(table(["backend", "rays per call", "rays/s", "target"], rows))


if __name__ == "__main__":
    main()
