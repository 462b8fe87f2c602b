"""Missions, one module each: adding a mission means adding a module with a ``Mission`` subclass.

The registry finds every ``Mission`` subclass with a ``name`` in this package's
modules, so the command line, the sweep and the MAVLink side list them without
being told.
"""

from __future__ import annotations

import importlib
import pkgutil

from vehicle.agent.missions.base import Mission

_SHARED = {"base", "routines"}


def missions() -> dict[str, type[Mission]]:
    """Mission name (lowercase, as on the command line) -> class, in alphabetical order."""
    found: dict[str, type[Mission]] = {}
    for module in pkgutil.iter_modules(__path__):
        if module.name in _SHARED:
            continue
        loaded = importlib.import_module(f"{__name__}.{module.name}")
        for value in vars(loaded).values():
            if isinstance(value, type) and issubclass(value, Mission) and getattr(value, "name", None):
                found[value.name] = value
    return dict(sorted(found.items()))


def mission_class(name: str) -> type[Mission]:
    known = missions()
    try:
        return known[name.lower()]
    except KeyError:
        raise ValueError(f"unknown mission {name!r}; missions: {', '.join(known)}") from None
