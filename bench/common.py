"""Helpers shared by the benchmark scripts: where the scenes are, and a Markdown table printer."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASTLE = ROOT.parent / "shared" / "scenes" / "castle.wrl"
DEFAULT_SCENE = ROOT / "scenes" / "default.wrl"


def castle_or_default() -> Path:
    """castle.wrl when ../shared is there (as in CI), else the project's default scene."""
    return CASTLE if CASTLE.exists() else DEFAULT_SCENE


def table(header: list[str], rows: list[list[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def code_state() -> str:
    """The commit the benches ran on, and the files under vehicle/ changed since (runs depend on them)."""
    import subprocess

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout.rstrip()
        except (OSError, subprocess.CalledProcessError):
            return ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    changed = [line[3:] for line in git("status", "--porcelain", "--", "vehicle").splitlines() if line.strip()]
    return f"commit {commit}" + (f", with local changes in {', '.join(changed)}" if changed else "")
