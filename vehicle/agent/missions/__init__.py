"""Missions, one module each, named as on the command line.

``MISSIONS`` lists them with a line of help each, so that the command line can
offer them without importing any (a mission pulls in the planner and its
compiled loops); ``mission_class`` imports the one asked for. Adding a mission
means adding a module with a ``Mission`` subclass and a line here (a test
checks that the two agree).
"""

from __future__ import annotations

import importlib

MISSIONS = {
    "browse": "turn in place at home in yaw_step increments, scanning one full circle",
    "pathfind": "visit waypoints in order (a square around home by default), replanning with A* when blocked",
    "rti": "radio tomography: a team (or one vehicle with fixed radio nodes) stops at paired spots round a region, "
           "waiting for each other while the radios measure; the next spots go where the image is least sure",
    "search": "scan, move towards far detections with open space beside them at a stand-off distance, repeat",
    "square": "fly preplanned AUTO waypoints in a square around home (or the given waypoints)",
}


def mission_class(name: str):
    """The ``Mission`` subclass of a mission name (lowercase, as on the command line)."""
    if name.lower() not in MISSIONS:
        raise ValueError(f"unknown mission {name!r}; missions: {', '.join(MISSIONS)}")
    from vehicle.agent.missions.base import Mission

    name = name.lower()
    module = importlib.import_module(f"{__name__}.{name}")
    return next(value for value in vars(module).values()
                if isinstance(value, type) and issubclass(value, Mission) and getattr(value, "name", None) == name)
