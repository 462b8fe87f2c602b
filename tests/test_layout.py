"""The architecture's rules (the README's "Layout"), checked on the code itself.

Every import statement of the project, at module level or inside a function, is
read from the source; each package may import only the packages below it:

- ``vehicle.protocol`` (what both ends of a link share) imports nothing above it;
- ``vehicle.mapping`` and ``vehicle.world`` build on the protocol (and the world on mapping, to draw maps);
- the simulator (``vehicle.sim``) never imports the agent, and the agent never the simulator: it reaches
  its vehicle only through its flight-controller interface; the agent plans radio tomography missions
  with ``vehicle.tomography``, which imports only the protocol (numpy and scipy);
- ``groundstation`` imports only what both ends share (protocol, mapping, world), never the simulator,
  the agent or the lab; nothing in ``vehicle`` imports ``groundstation``.

And at run time: importing every module of the ground station leaves numba and the simulator unloaded.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {  # package -> what it may import from the project (itself always)
    "vehicle.protocol": {"vehicle"},
    "vehicle.mapping": {"vehicle", "vehicle.protocol"},
    "vehicle.world": {"vehicle", "vehicle.protocol", "vehicle.mapping"},
    "vehicle.sim": {"vehicle", "vehicle.protocol", "vehicle.mapping", "vehicle.world"},
    "vehicle.agent": {"vehicle", "vehicle.protocol", "vehicle.mapping", "vehicle.world", "vehicle.tomography"},
    "vehicle.tomography": {"vehicle", "vehicle.protocol"},
    "vehicle.lab": {"vehicle", "vehicle.protocol", "vehicle.mapping", "vehicle.world", "vehicle.sim",
                    "vehicle.agent", "vehicle.tomography"},
    "groundstation": {"vehicle", "vehicle.protocol", "vehicle.mapping", "vehicle.world", "vehicle.tomography"},
}


def package_of(module: str) -> str:
    """The layer a module belongs to: ``vehicle.sim.autopilot`` -> ``vehicle.sim``; ``vehicle`` itself and
    ``vehicle.cli`` (the command line, which may use everything) -> ``vehicle``."""
    parts = module.split(".")
    if parts[0] == "groundstation":
        return "groundstation"
    if len(parts) > 2 or (len(parts) == 2 and (ROOT / "vehicle" / parts[1]).is_dir()):
        return ".".join(parts[:2])
    return "vehicle"


def project_imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import of a project module in a file, wherever it stands."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
    return [(line, name) for line, name in found if name.split(".")[0] in ("vehicle", "groundstation")]


def modules(package: str) -> list[tuple[str, Path]]:
    folder = ROOT.joinpath(*package.split("."))
    return [(".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"), p)
            for p in sorted(folder.rglob("*.py"))]


def test_the_layers_are_where_the_rules_expect_them():
    found = {package_of(name) for name, _ in modules("vehicle")} | {"groundstation"}
    assert found == set(ALLOWED) | {"vehicle"}


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_each_package_imports_only_the_packages_below_it(package):
    checked, broken = 0, []
    for _, path in modules(package):
        for line, imported in project_imports(path):
            checked += 1
            target = package_of(imported)
            if target != package and target not in ALLOWED[package]:
                broken.append(f"{path.relative_to(ROOT)}:{line} imports {imported}")
    assert checked > 0
    assert not broken, "\n".join(broken)


def test_nothing_in_vehicle_imports_the_ground_station():
    checked = 0
    for _, path in modules("vehicle"):
        for line, imported in project_imports(path):
            checked += 1
            assert not imported.startswith("groundstation"), f"{path}:{line} imports {imported}"
    assert checked > 100


def test_the_agent_reaches_its_vehicle_only_through_the_flight_controller_interface():
    """No agent module touches the simulator's objects, even by a name it got passed (a type hint, an attribute)."""
    touched = []
    for _, path in modules("vehicle.agent"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            inner = node.value if isinstance(node, ast.Attribute) else None  # x.autopilot.mode, x.body.pose ...
            if isinstance(inner, ast.Attribute) and inner.attr in ("autopilot", "body", "simulation", "world"):
                touched.append(f"{path.relative_to(ROOT)}:{node.lineno} .{inner.attr}.{node.attr}")
            elif isinstance(node, ast.Name) and node.id in ("Autopilot", "Simulation", "Body", "SimController"):
                touched.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.id}")
    assert not touched, "\n".join(touched)


def test_importing_the_whole_ground_station_loads_neither_numba_nor_the_simulator():
    names = [name for name, _ in modules("groundstation")]
    script = (f"import sys\nfor name in {names!r}:\n    __import__(name)\n"
              "loaded = [m for m in sys.modules if m == 'numba' or m.startswith(('numba.', 'vehicle.sim', "
              "'vehicle.agent', 'vehicle.lab', 'vehicle.mapping.tracing', 'vehicle.mapping.planning'))]\n"
              "print(sorted(loaded))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("command", [["vehicle", "--help"], ["vehicle", "scene", "--help"],
                                     ["vehicle", "experiment", "--help"], ["vehicle", "sweep", "--help"],
                                     ["groundstation", "--help"], ["groundstation", "demo", "--help"]])
def test_help_loads_no_mission_geometry_or_compiled_code(command):
    """Asking for help answers at once: it loads no mission, no numpy, trimesh or scipy, and nothing compiled
    (the settings' map bounds once brought numpy in: 0.1 s and 12 MB more)."""
    script = (f"import sys\nfrom {command[0]}.cli import main\ntry:\n    main({command[1:]!r})\n"
              "except SystemExit:\n    pass\n"
              "heavy = ('numpy', 'numba', 'trimesh', 'scipy', 'embreex', 'viser', 'fastapi',\n"
              "         'vehicle.agent.missions.')\n"
              "print(sorted({m.split('.')[0] if not m.startswith('vehicle') else m for m in sys.modules "
              "if m.startswith(heavy)}), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout
    assert done.stderr.strip() == "[]"
