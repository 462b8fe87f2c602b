"""The scenes that ship with the project: the demo's default scene and our test scenes.

They live in the top-level ``scenes/`` folder of a checkout and are package
data (``vehicle/scenes``) in an installed wheel; this finds them either way.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]  # vehicle/


def scenes_dir() -> Path:
    installed = _PACKAGE / "scenes"
    return installed if installed.is_dir() else _PACKAGE.parent / "scenes"


def default_scene() -> Path:
    return scenes_dir() / "default.wrl"
