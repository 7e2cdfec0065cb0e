"""A normal (non-editable) install works: build the wheel, install it into a fresh venv, build the sample
from another folder. This is what a user gets from `pip install .`; an editable install hides missing
package data because the checkout is beside it."""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"


def run(command: list, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    environment = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    completed = subprocess.run([str(part) for part in command], cwd=cwd, env=environment, capture_output=True,
                               text=True, timeout=timeout, check=False)
    assert completed.returncode == 0, f"{command}:\n{completed.stdout}\n{completed.stderr}"
    return completed


def copy_sources(destination: Path) -> Path:
    """The files a wheel is built from, copied: setuptools writes build/ and *.egg-info next to its sources,
    and build/ in the checkout is where mapkit puts users' builds."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    destination.mkdir()
    shutil.copy2(REPO / "pyproject.toml", destination)
    shutil.copy2(REPO / project["project"]["readme"], destination)
    for pattern in project["tool"]["setuptools"]["packages"]["find"]["include"]:
        package = pattern.rstrip("*")
        shutil.copytree(REPO / package, destination / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info"))
    return destination


def fresh_venv(folder: Path) -> Path:
    """A new venv that imports the dependencies from the current environment without downloading them: a
    .pth file lists this interpreter's site-packages (``--system-site-packages`` would reach the base
    interpreter's, not those of a venv we run in). Its own site-packages comes first, so the installed
    wheel is what it imports; .pth files of the listed folders (the checkout's editable finder) are not
    run."""
    run([sys.executable, "-m", "venv", "--without-pip", folder], cwd=folder.parent)
    python = folder / "bin" / "python"
    purelib = run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                  cwd=folder).stdout.strip()
    Path(purelib, "parent-environment.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    return python


@pytest.mark.slow
def test_the_wheel_installs_and_builds_the_sample_from_another_folder(tmp_path):
    sources = copy_sources(tmp_path / "src")
    wheels = tmp_path / "wheels"
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
         "-w", wheels, sources], cwd=tmp_path)
    (wheel,) = wheels.glob("tavf_mapkit-*.whl")

    python = fresh_venv(tmp_path / "venv")
    # pip itself comes from the listed environment; it installs into the venv it runs in
    run([python, "-m", "pip", "install", "--no-deps", "--no-index", "-q", wheel], cwd=tmp_path)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    imported = run([python, "-c", "import tavf_mapkit; print(tavf_mapkit.__file__)"], cwd=elsewhere).stdout
    assert Path(imported.strip()).is_relative_to(tmp_path / "venv"), imported

    mapkit = tmp_path / "venv" / "bin" / "mapkit"
    result = run([mapkit, "build", SAMPLE, "-o", "out"], cwd=elsewhere)
    assert "built " in result.stdout and "Traceback" not in result.stderr
    folder = elsewhere / "out"
    for relative in ("out.xodr", "out.net.xml", "source/out.osm", "report/summary.json", "report/check.json",
                     "logs/netconvert.log", "mesh/mesh.json", "mesh/labelled/index.json",
                     "report/mesh_preview.png", "collision/world.json"):
        assert (folder / relative).is_file(), relative
    manifest = json.loads((folder / "manifest.json").read_text())
    stages = ("extract", "netconvert", "opendrive", "mesh", "collision", "check", "report")
    assert [(record["name"], record["status"]) for record in manifest["stages"]] == \
        [(name, "ran") for name in stages]
    assert manifest["stages"][1]["options"]["profile"] == "carla"
    assert sorted(p.name for p in elsewhere.iterdir()) == [".out.lock", "out"]  # no staging folder left

    # the view's package data: the report page inlines the vendored Leaflet and the map script; the live page
    # of mapkit view loads three.js from the package
    page = (folder / "report" / "index.html").read_text()
    assert "window.MAPKIT_DATA = {" in page and "Leaflet 1.9.4" in page
    import zipfile

    names = set(zipfile.ZipFile(wheel).namelist())
    for relative in ("static/index.html", "static/app.js", "static/scene3d.js", "static/vendor/leaflet/LICENSE",
                     "static/vendor/three/build/three.module.min.js", "static/vendor/three/LICENSE",
                     "static/vendor/three/examples/jsm/loaders/GLTFLoader.js"):
        assert f"tavf_mapkit/view/{relative}" in names, relative

    # the other package data: both profiles and the accuracy baselines
    run([mapkit, "build", SAMPLE, "-o", "full", "--profile", "full", "-q"], cwd=elsewhere)
    shown = run([mapkit, "baseline", "show"], cwd=elsewhere).stdout
    assert "compare/jungfernstieg/dlr-net" in shown
