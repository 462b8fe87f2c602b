"""Mutation testing of the modules where a silent bug is dangerous (issue 14); ``scripts/mutants.sh`` runs it.

For each module below: a scratch copy of the project in ``out/mutants/NAME/`` (so that
runs never touch the work tree, and each module gets its own test selection), mutmut's
settings written into the copy's pyproject.toml, then ``mutmut run`` there, and a
score: the share of mutants some test kills (a timeout counts as killed: the mutant
hung the code). Surviving mutants are written, as diffs, to
``out/mutants/NAME/survivors.txt``; every one of them is either killed by a test or
listed with the reason it is equivalent in ``scripts/equivalent-mutants/MODULE.md``.

What mutmut needs help with here:
- mutmut mutates undecorated functions and methods only. The compiled loops carry
  ``@numba.njit``, which ``NUMBA_DISABLE_JIT=1`` turns into a no-op anyway, so in the
  copy those decorator lines are taken off and the loops run (and are mutated) as
  plain Python.
- Planning is mutated where a wrong answer is dangerous: ``astar`` and what it relies on (the corner
  cuts, closing pinches, the four-connected fallback, the escape from inside the clearance); the
  autopilot in its modes and their transitions (arming, modes, take-off, missions, return, landing).
  Mutating all of both takes well over an hour on 2 cores.
- Planning keeps its JIT: run as plain Python, the compiled A* (``_astar_cells`` and its heap) makes the
  module's tests take over an hour under mutation. Its compiled loops are therefore not mutated; they
  are checked instead against the very paths pyastar2d returned on 200 seeded grids
  (``test_search_returns_pyastar2d_paths``) and against 4-connectivity on noisy grids; what
  ``astar`` does around them (its checks, corner cuts, pinches, the fallback, the escape) is mutated.
- Tests that start the station or a vehicle as a subprocess are left out: the mutated code runs
  only under mutmut's own process.
- Each module names the functions it mutates (``focus``); in the copy every other function and
  class gets ``# pragma: no mutate block`` on its header line, which mutmut 3.8 honours for the
  whole body (a per-line pragma does not hold it).

Usage: python scripts/mutants.py [NAME ...] [--jobs N]; no names runs every module.
"""

from __future__ import annotations

import argparse
import ast
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tokenize
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "out" / "mutants"
EQUIVALENT = ROOT / "scripts" / "equivalent-mutants"  # per module: surviving mutants shown equivalent, with why
COPIED = ["vehicle", "groundstation", "tests", "static", "scenes", "docs", "pyproject.toml", "README.md"]
NUMBA_DECORATOR = re.compile(r"^\s*@numba\.n?jit\b.*$")
KILLED = {"killed", "timeout", "caught by type check", "segfault"}


@dataclass
class Module:
    name: str
    files: list[str]
    tests: list[str]  # pytest arguments: the fast, relevant subset that is the runner's test command
    focus: dict[str, list[str]] = field(default_factory=dict)  # file: the functions mutated (default: all)
    jit: bool = True  # False: NUMBA_DISABLE_JIT=1 (the module's compiled loops run as Python)
    jobs: int = 0  # mutants tested at once (0: --jobs); more than the cores where the tests wait on sockets


MODULES = [
    Module(
        "collision",
        ["vehicle/world/collision.py"],
        ["tests/test_collision.py"],
        focus={
            "vehicle/world/collision.py": [
                "_squared_distance",
                "_segment_segment_distance",
                "_segment_crosses_triangle",
                "_point_triangle_distance",
                "point_triangle_distance",
                "segment_triangle_distance",
                "_to_segment",
                "Collider.sweep",
                "Collider.clearance",
                "Collider.touches",
                "TriangleGrid.candidates",
            ]
        },
        jit=False,
    ),
    Module(
        "memory map",
        ["vehicle/mapping/memory_map.py", "vehicle/mapping/tracing.py"],
        ["tests/test_memory_map.py"],
        focus={
            "vehicle/mapping/memory_map.py": [
                "MemoryMap.add_readings",
                "MemoryMap.mark_body",
                "MemoryMap._note_changes",
                "MemoryMap.take_changes",
                "states_of",
            ],
            "vehicle/mapping/tracing.py": ["project", "free_cells", "_add_line", "_trace", "_clip", "_cell"],
        },
        jit=False,
    ),
    Module(
        "map stream",
        ["vehicle/protocol/mapstream.py"],
        ["tests/test_mapstream.py"],
        focus={
            "vehicle/protocol/mapstream.py": [
                "MapStreamer.tick",
                "MapStreamer.deltas",
                "MapStreamer.snapshot",
                "MapStreamer.snapshot_parts",
                "_unpack_cells",
                "_inflate",
                "_varint",
                "_varint_codes",
                "_read_varints",
                "_nonzero_box",
                "_chunks",
                "MapReceiver.feed",
                "MapReceiver._delta",
                "MapReceiver._apply",
                "MapReceiver._snapshot_chunk",
            ]
        },
    ),
    Module(
        "planning",
        ["vehicle/mapping/planning.py"],
        ["tests/test_planning.py"],
        focus={
            "vehicle/mapping/planning.py": [
                "astar",
                "_search",
                "corner_cuts",
                "_close_pinches",
                "_connected",
                "_cell",
                "_mask",
                "_escape",
            ]
        },
        jit=True,  # see the docstring: its compiled A* is checked against pyastar2d, not mutated
    ),
    Module(
        "autopilot modes",
        ["vehicle/sim/autopilot.py"],
        ["tests/test_autopilot.py"],
        focus={
            "vehicle/sim/autopilot.py": [
                f"Autopilot.{name}"
                for name in (
                    "arm",
                    "disarm",
                    "set_mode",
                    "takeoff",
                    "_guided_ready",
                    "start_mission",
                    "set_current",
                    "step",
                    "_touchdown",
                    "_return_home",
                    "_land_here",
                    "_advance",
                )
            ]
        },
    ),
    Module(
        "GCS failsafe",
        ["vehicle/sim/endpoint.py"],
        ["tests/test_vehicle_mavlink.py", "-k", "failsafe"],
        focus={"vehicle/sim/endpoint.py": ["Endpoint._gcs_heard", "Endpoint._check_failsafe"]},
        jobs=8,
    ),
    Module(
        "command ACK",
        ["groundstation/link.py", "vehicle/agent/mavlink_controller.py"],
        [
            "tests/test_command_ack.py",
            "tests/test_companion.py",
            "-k",
            "test_command_ack or refused or never_answered or in_progress or unsupported",
        ],
        focus={
            "groundstation/link.py": ["Link.request", "Link.command", "Link.command_int"],
            "vehicle/agent/mavlink_controller.py": ["MavlinkController._acknowledged"],
        },
        jobs=6,
    ),
    Module(
        "authentication",
        ["groundstation/security.py"],
        [
            "tests/test_hostile_web.py",
            "tests/test_groundstation_api.py",
            "-m",
            "not browser",
            "-k",
            # "host" alone would match the file name and select every test in it (3x slower, no more kills)
            "(token or auth or host_name or allowed_host or origin or loopback or session or body or nosniff"
            " or watching or cookie) and not lax_truths and not payloads and not without_tls_warns",
        ],
        focus={
            "groundstation/security.py": [
                "is_loopback",
                "_same",
                "Access.for_host",
                "Access.is_operator",
                "Access.may_view",
                "Access.session_value",
                "Access.grants_session",
                "Access.host_allowed",
                "same_origin",
                "_cookie",
                "Gate.__call__",
                "Gate._refusal",
                "Gate._body",
                "_replay",
            ]
        },
        jobs=4,
    ),
    Module(
        "replay seek",
        ["groundstation/replay.py"],
        [
            "tests/test_recording_replay.py",
            "-k",
            "experiment_log or backwards or after_a_seek or lost_snapshot "
            "or truncated or cut_in or corrupt or is_refused or index_is_exact or foreign_plane or player_plays "
            "or raw_reads or during_a_players_tick or controls_apply",
        ],
        focus={
            "groundstation/replay.py": [
                "Replay.seek",
                "Replay._needed",
                "Replay._whole_start",
                "Replay._chunk_header",
                "Replay._payload",
                "Replay._heartbeat_kind",
                "Replay.sensor_id",
                "Replay.control",
                "Replay._apply",
                "Replay.advance",
                "Replay.step",
            ]
        },
    ),
    Module(
        "hostile-input guards",
        ["vehicle/protocol/links.py"],
        ["tests/test_links.py", "tests/test_hostile_mavlink.py", "-k", "not two_byte_datagram_flood and not the_page"],
        focus={
            "vehicle/protocol/links.py": [
                "_Signed._admit",
                "_restart",
                "UdpLink.recv_msg",
                "UdpLink._read",
                "UdpLink._forget",
                "UdpLink.write",
                "StreamLink._open",
                "StreamLink._down",
                "StreamLink.recv_msg",
            ]
        },
        jobs=4,
    ),
]


# ---- the scratch copy --------------------------------------------------------------------------------
def prepare(module: Module, python: str) -> Path:
    work = OUT / slug(module.name)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    for name in COPIED:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, work / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(source, work / name)
    for name in module.files:
        path = work / name
        text = path.read_text()
        if not module.jit:
            text = "\n".join("" if NUMBA_DECORATOR.match(line) else line for line in text.split("\n"))
        if name in module.focus:
            text = only_mutate_in(text, module.focus[name])
        path.write_text(text)
    settings = {
        "source_paths": ["vehicle", "groundstation"],
        "also_copy": ["static", "scenes", "docs", "README.md"],  # served or read by the tests
        "only_mutate": module.files,
        "pytest_add_cli_args": ["-p", "no:cacheprovider", "-q", "-p", "no:randomly"],
        "pytest_add_cli_args_test_selection": module.tests,
        "timeout_multiplier": 5.0,
        "timeout_constant": 10.0,
    }
    with open(work / "pyproject.toml", "a") as handle:
        handle.write("\n[tool.mutmut]\n")
        for key, value in settings.items():
            handle.write(f"{key} = {json.dumps(value)}\n")
    return work


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def only_mutate_in(text: str, functions: list[str]) -> str:
    """``text`` with ``# pragma: no mutate block`` on the header of every function and class that neither is
    nor holds one of the named functions (``Class.method``, ``outer.inner``): mutmut then skips them whole."""
    lines = text.split("\n")
    found = set()
    colons = {}  # a compound statement's first line -> the line of the colon that opens its body
    tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))

    def header_end(node) -> int:
        body_line = node.body[0].lineno
        return max(
            t.start[0]
            for t in tokens
            if t.type == tokenize.OP
            and t.string == ":"
            and node.lineno <= t.start[0] <= body_line
            and t.start < (body_line, node.body[0].col_offset)
        )

    def visit(node, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                visit(child, prefix)
                continue
            name = f"{prefix}{child.name}"
            if name in functions:
                found.add(name)
            elif any(f.startswith(f"{name}.") for f in functions):
                visit(child, f"{name}.")
            else:
                colons[child.lineno] = header_end(child)

    visit(ast.parse(text), "")
    missing = sorted(set(functions) - found)
    if missing:
        raise SystemExit(f"focus: {missing} not found")
    for number in colons.values():
        lines[number - 1] += " # pragma: no mutate block" if "#" in lines[number - 1] else "  # pragma: no mutate block"
    return "\n".join(lines)


# ---- running and scoring --------------------------------------------------------------------------------
def run(module: Module, python: str, jobs: int) -> dict:
    work = prepare(module, python)
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    env.pop("CI", None)  # skipped tests (castle.wrl is not beside the copy) are no failures here
    if not module.jit:
        env["NUMBA_DISABLE_JIT"] = "1"
    mutmut = [python, "-c", "import sys; from mutmut.__main__ import cli; sys.argv[0] = 'mutmut'; cli()"]
    started = time.monotonic()
    with open(work / "mutmut.log", "w") as log:
        subprocess.run(
            mutmut + ["run", "--max-children", str(module.jobs or jobs)],
            cwd=work,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            check=False,
        )
    seconds = time.monotonic() - started
    statuses = results(work)
    survivors = sorted(name for name, status in statuses.items() if status not in KILLED)
    show = (
        "import json, sys\nfrom mutmut.mutation.diff_apply import get_diff_for_mutant\n"
        "for name, status in json.load(sys.stdin).items():\n"
        "    print(f'## {name} ({status})'); print(get_diff_for_mutant(name)); print()\n"
    )
    with open(work / "survivors.txt", "w") as out:
        subprocess.run(
            [python, "-c", show],
            cwd=work,
            env=env,
            input=json.dumps({n: statuses[n] for n in survivors}),
            stdout=out,
            text=True,
            check=False,
        )
    killed = sum(status in KILLED for status in statuses.values())
    listed = equivalent_names()
    return {
        "module": module.name,
        "mutants": len(statuses),
        "killed": killed,
        "survivors": survivors,
        "equivalent": [n for n in survivors if n in listed],
        "open": [n for n in survivors if n not in listed],
        "seconds": seconds,
        "work": str(work),
    }


def report(module: Module) -> dict:
    """The row of the module's last run, read back from its scratch copy (its time from mutmut.log's mtime)."""
    work = OUT / slug(module.name)
    if not (work / "mutants").is_dir():
        raise SystemExit(f"{module.name}: not run yet (python scripts/mutants.py {slug(module.name)})")
    statuses = results(work)
    survivors = sorted(name for name, status in statuses.items() if status not in KILLED)
    listed = equivalent_names()
    log = work / "mutmut.log"
    return {
        "module": module.name,
        "mutants": len(statuses),
        "killed": sum(status in KILLED for status in statuses.values()),
        "survivors": survivors,
        "equivalent": [n for n in survivors if n in listed],
        "open": [n for n in survivors if n not in listed],
        "seconds": log.stat().st_mtime - (work / "pyproject.toml").stat().st_mtime,
        "work": str(work),
    }


def equivalent_names() -> set[str]:
    """The mutant names listed in scripts/equivalent-mutants/*.md (names change when their function does: a
    listed mutant that no longer survives under its name shows up as open again)."""
    text = "".join(path.read_text() for path in sorted(EQUIVALENT.glob("*.md")))
    return set(re.findall(r"[\w.\u01c1]+__mutmut_\d+", text))


def results(work: Path) -> dict[str, str]:
    """Each mutant's status from mutmut's .meta files."""
    sys.path.insert(0, str(Path(sys.executable).parent))
    from mutmut.stats import status_by_exit_code

    statuses = {}
    for meta in (work / "mutants").rglob("*.meta"):
        for name, code in json.loads(meta.read_text())["exit_code_by_key"].items():
            statuses[name] = status_by_exit_code[code]
    return statuses


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "names", nargs="*", help="modules to run (default: all): " + ", ".join(slug(m.name) for m in MODULES)
    )
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 2)
    parser.add_argument(
        "--report", action="store_true", help="only print the table of the last run (out/mutants/), running nothing"
    )
    args = parser.parse_args()
    by_slug = {slug(m.name): m for m in MODULES}
    unknown = [name for name in args.names if name not in by_slug]
    if unknown:
        raise SystemExit(f"no such module: {', '.join(unknown)} (modules: {', '.join(by_slug)})")
    chosen = [by_slug[name] for name in args.names] or MODULES
    rows = []
    for module in chosen:
        row = report(module) if args.report else run(module, sys.executable, args.jobs)
        rows.append(row)
        print(f"{module.name}: {row['killed']}/{row['mutants']} killed in {row['seconds']:.0f} s", flush=True)
    print("\n| module | mutants | killed | survived | equivalent (listed) | open | score | time |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        score = row["killed"] / row["mutants"] if row["mutants"] else float("nan")
        print(
            f"| {row['module']} | {row['mutants']} | {row['killed']} | {len(row['survivors'])} | "
            f"{len(row['equivalent'])} | "
            f"{len(row['open'])} | {score:.1%} | {row['seconds'] / 60:.1f} min |"
        )
    total = sum(r["mutants"] for r in rows)
    killed = sum(r["killed"] for r in rows)
    print(
        f"| all | {total} | {killed} | {sum(len(r['survivors']) for r in rows)} | "
        f"{sum(len(r['equivalent']) for r in rows)} | "
        f"{sum(len(r['open']) for r in rows)} | {killed / max(total, 1):.1%} | "
        f"{sum(r['seconds'] for r in rows) / 60:.1f} min |"
    )
    print(
        "\nscore: killed / mutants (a timeout counts as killed); survived: no test failed;"
        " equivalent: survivors listed with a reason in scripts/equivalent-mutants/;"
        " open: survivors neither killed nor listed"
    )
    for row in rows:
        if row["open"]:
            print(f"\n{row['module']}: {len(row['open'])} open, diffs in {row['work']}/survivors.txt")
            for name in row["open"]:
                print(f"  {name}")
    if not all(r["mutants"] for r in rows):
        raise SystemExit("a module made no mutants (see its mutmut.log)")


if __name__ == "__main__":
    main()
