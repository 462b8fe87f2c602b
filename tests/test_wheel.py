"""The wheel: built from the checkout, installed into a fresh virtualenv, it runs the demo from anywhere.

``pip install .`` (not editable) must give a package that carries the operator
page and the scenes. The wheel is built with pip, installed with ``--no-deps``
into a new virtualenv, and given the test environment's dependencies through a
``.pth`` path (installing numpy, numba and viser afresh would take minutes and
prove nothing about our package); the project itself then comes from the wheel
only, which the test checks. ``groundstation demo`` runs in an empty folder.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import httpx
import pytest
from harness import free_port, read_until, wait_wall

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a clean copy of the checkout (a ``build/`` folder left in it could add stale files)."""
    source, out = tmp_path_factory.mktemp("source") / "scanstation", tmp_path_factory.mktemp("wheel")
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".*", "build", "dist", "*.egg-info", "__pycache__",
                                                                  "recordings", "tests"))
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(source)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return next(out.glob("scanstation-*.whl"))


def test_the_wheel_holds_every_module_the_page_and_the_scenes(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    sources = {str(p.relative_to(ROOT)) for package in ("vehicle", "groundstation")
               for p in (ROOT / package).rglob("*.py")}
    assert sources - names == set()
    for page in (ROOT / "static").iterdir():  # every file the page may ask for (not an editor's hidden ones)
        assert page.name.startswith(".") or f"groundstation/static/{page.name}" in names
    for scene in ("default.wrl", "house.wrl", "trees.wrl", "apartment.wrl"):
        assert f"vehicle/scenes/{scene}" in names


def test_the_installed_wheel_serves_the_demo_from_an_unrelated_folder(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, timeout=300)  # this pip, working on the new environment
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # numpy, viser, ... only
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = subprocess.run([str(python), "-c", "import vehicle, groundstation; print(vehicle.__file__); "
                            "print(groundstation.__file__)"], capture_output=True, text=True, check=True,
                           cwd=elsewhere).stdout.split()
    assert all(Path(p).is_relative_to(site) for p in where), where  # the wheel's code, not the checkout's

    port, mavlink_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    demo = subprocess.Popen([str(env_dir / "bin" / "groundstation"), "demo", "--port", str(port), "--mavlink-port",
                             str(mavlink_port), "--speedup", "4", "--record-dir", "", "--quiet"],
                            cwd=elsewhere, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = read_until(demo, r"http://127\.0\.0\.1:\d+/#token=", timeout=120)
        match = re.search(r"(http://127\.0\.0\.1:\d+)/#token=", out)
        assert match, f"the demo exited or printed no address: {out}"
        address = match.group(1)
        assert address == f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=address, timeout=10) as http:
            assert "<html" in http.get("/").text.lower()
            assert http.get("/static/app.js").status_code == 200
            scene = http.get("/api/health").json()["scene"]
            assert scene["name"] == "default.wrl" and scene["triangles"] > 300

            def vehicle():
                vehicles = http.get("/api/vehicles").json()
                return vehicles[0] if vehicles else None

            flying = wait_wall(vehicle, 120, "the simulated copter, flying its mission", period=0.2,
                               done=lambda v: v and v["position"] and v["armed"] and v["position"]["alt"] > 1.0)
            assert flying["armed"] and flying["position"]["alt"] > 1.0, flying
    finally:
        demo.terminate()
        demo.wait(timeout=20)
    assert not list(elsewhere.iterdir())  # nothing written where it was run (recording is off)
