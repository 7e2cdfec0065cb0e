"""Shared test fixtures: the real data folder ../shared/data beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("TAVF_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_path(*parts: str) -> Path:
    """Path of a file under ../shared/data; skips the test if the folder is absent (fails under CI=true)."""
    path = SHARED_DATA.joinpath(*parts)
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"shared data folder {SHARED_DATA} is missing in CI")
        pytest.skip(f"shared data folder {SHARED_DATA} not present")
    if not path.exists():
        pytest.fail(f"expected shared data file {path} is missing")
    return path


def peer(getter):
    """What ``getter()`` returns for an independent oracle of benchmarks/peers (a program, a venv's Python);
    skips the test with the reason when the peer is not installed here, fails under CI=true (.ci/run installs
    every peer before the tests)."""
    from benchmarks.peers import PeerUnavailable

    try:
        return getter()
    except PeerUnavailable as error:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{error} -- in CI, .ci/run installs the peers first")
        pytest.skip(str(error))


@pytest.fixture(scope="session", autouse=True)
def route_plan_cache(tmp_path_factory):
    """Drives keep their route plans in $MAPKIT_CACHE (twin/planning/route_cache.py): the tests' in a folder of
    their own, never the user's ~/.cache, so no test finds a plan an earlier run left (subprocesses inherit it)."""
    previous = os.environ.get("MAPKIT_CACHE")
    os.environ["MAPKIT_CACHE"] = str(tmp_path_factory.mktemp("mapkit-cache"))
    yield
    if previous is None:
        os.environ.pop("MAPKIT_CACHE", None)
    else:
        os.environ["MAPKIT_CACHE"] = previous


@pytest.fixture
def shared():
    """``shared('xodr', 'esmini', 'e6mini.xodr')`` -> Path, skipping or failing as shared_path does."""
    return shared_path


def netconvert_binary() -> str:
    """The netconvert shipped by the eclipse-sumo wheel."""
    import shutil
    import sys

    candidate = Path(sys.executable).parent / "netconvert"
    if candidate.exists():
        return str(candidate)
    found = shutil.which("netconvert")
    if found:
        return found
    import sumo  # the eclipse-sumo wheel

    return str(Path(sumo.SUMO_HOME) / "bin" / "netconvert")


@pytest.fixture(scope="session")
def tavf_xodr(tmp_path_factory) -> Path:
    """DLR's TAVF SUMO network converted to OpenDRIVE by netconvert (once per test session)."""
    import subprocess

    net = shared_path("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")
    out = tmp_path_factory.mktemp("tavf") / "tavf.xodr"
    subprocess.run([netconvert_binary(), "-s", str(net), "--opendrive-output", str(out)], check=True,
                   capture_output=True)
    return out


def _build(tmp_path_factory, name: str, source: Path) -> Path:
    """Run ``mapkit build SOURCE`` with the default stages into a fresh folder; return the build folder."""
    from click.testing import CliRunner

    from tavf_mapkit.cli.main import cli

    out = tmp_path_factory.mktemp(f"build-{name}") / name
    result = CliRunner().invoke(cli, ["build", str(source), "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def sample_build_dir(tmp_path_factory) -> Path:
    """The quickstart build of sample_data/tavf_synthetic.osm (default stages), once per session."""
    return _build(tmp_path_factory, "sample", REPO / "sample_data" / "tavf_synthetic.osm")


@pytest.fixture(scope="session")
def jungfernstieg_build(tmp_path_factory) -> Path:
    """A build of the real OSM extract of Jungfernstieg (default stages), once per session."""
    return _build(tmp_path_factory, "jungfernstieg",
                  shared_path("hamburg", "jungfernstieg_osm", "jungfernstieg_2023-03-10.osm"))


@pytest.fixture(scope="session")
def perth_build(tmp_path_factory) -> Path:
    """A build of the zoo's Perth roundabouts (left-hand traffic, 81 roads; default stages), once per session."""
    return _build(tmp_path_factory, "perth", shared_path("zoo", "osm", "AU_perth_peanut_roundabout_LHT.osm.gz"))


@pytest.fixture(scope="session")
def tavf_dlr_build(tmp_path_factory) -> Path:
    """A build of DLR's TAVF SUMO network (default stages), once per session."""
    return _build(tmp_path_factory, "tavf-dlr", shared_path("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz"))
