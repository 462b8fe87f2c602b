"""Simulated seconds per wall second: one copter with one sonar at a 0.05 s step in castle.wrl.

The vehicle flies a GUIDED leg back and forth across the scene (physics,
collision checks and a sonar reading every step). Target: at least 500x.
Run: python bench/sim.py
"""

from __future__ import annotations

import time

from common import CASTLE, castle_or_default, table

from vehicle.sim.simulation import Simulation
from vehicle.world.scene import load_scene
from vehicle.world.sonar import Sonar


def main(sim_seconds: float = 600.0) -> None:
    scene_path = castle_or_default()
    scene = load_scene(scene_path)
    start = (-40.0, 0.0) if scene_path == CASTLE else None
    world = Simulation(scene, "copter", start=start, sensors=[Sonar()], sonar_rate=20.0)  # a reading every step
    autopilot = world.autopilot
    autopilot.arm()
    autopilot.takeoff(4.0)
    x, y = world.home[0], world.home[1]
    legs = [(x, y + 30.0), (x, y - 30.0)]
    started = time.perf_counter()
    readings = 0
    while world.time < sim_seconds and world.collision is None:
        if world.steps % 400 == 0:
            autopilot.goto(*legs[(world.steps // 400) % 2], 4.0)
        readings += len(world.step())
    wall = time.perf_counter() - started
    print(f"scene: {scene_path.name}; step {world.dt} s; {readings} sonar readings")
    print(table(["simulated s", "wall s", "speed-up", "target"],
                [[f"{world.time:.0f}", f"{wall:.2f}", f"{world.time / wall:,.0f}x", ">= 500x"]]))


if __name__ == "__main__":
    main()
