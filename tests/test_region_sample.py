"""sample_data/make_region.py: synthetic regions of any size, deterministic, connected, and buildable."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import osmium
import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli

REPO = Path(__file__).resolve().parents[1]
GENERATOR = REPO / "sample_data" / "make_region.py"


def generate(tmp_path: Path, *arguments: str) -> tuple[Path, str]:
    tmp_path.mkdir(parents=True, exist_ok=True)
    output = tmp_path / "region.osm"
    done = subprocess.run([sys.executable, str(GENERATOR), *arguments, "-o", str(output)], check=True,
                          capture_output=True, text=True)
    return output, done.stdout


def read_osm(path: Path):
    nodes, ways = {}, {}
    for element in osmium.FileProcessor(str(path), osmium.osm.NODE | osmium.osm.WAY):
        if element.is_node():
            nodes[element.id] = (element.location.lat, element.location.lon)
        else:
            ways[element.id] = ([node.ref for node in element.nodes], dict(element.tags))
    return nodes, ways


def test_same_arguments_give_the_same_file_and_another_seed_another(tmp_path):
    first, _ = generate(tmp_path / "a", "--grid", "4")
    again, _ = generate(tmp_path / "b", "--grid", "4")
    other, _ = generate(tmp_path / "c", "--grid", "4", "--seed", "1")
    assert first.read_bytes() == again.read_bytes()
    assert first.read_bytes() != other.read_bytes()


def test_region_is_one_connected_street_network_of_the_asked_size(tmp_path):
    path, said = generate(tmp_path, "--grid", "7")
    nodes, ways = read_osm(path)
    assert "7 x 7 crossings, 3.0 km x 3.0 km" in said
    assert all(ref in nodes for refs, _ in ways.values() for ref in refs)
    # 2 * 7 * 6 blocks, a few missing by design; every way a street with a shaped middle
    assert 0.85 * 84 <= len(ways) <= 84 and all(len(refs) == 4 for refs, _ in ways.values())
    assert all(tags["note"].startswith("SYNTHETIC") for _, tags in ways.values())
    parent = {node: node for node in nodes}

    def root(node):
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    for refs, _ in ways.values():
        for a, b in zip(refs, refs[1:]):
            parent[root(a)] = root(b)
    assert len({root(node) for refs, _ in ways.values() for node in refs}) == 1
    lats = [lat for lat, _ in nodes.values()]
    lons = [lon for _, lon in nodes.values()]
    assert 52.24 < min(lats) < max(lats) < 52.30 and 10.47 < min(lons) < max(lons) < 10.57


def test_roads_option_picks_a_grid_and_bad_sizes_are_refused(tmp_path):
    _, said = generate(tmp_path, "--roads", "50000")
    assert said.split(": ", 1)[1].startswith("60 x 60 crossings")
    refused = subprocess.run([sys.executable, str(GENERATOR), "--grid", "1", "-o", str(tmp_path / "x.osm")],
                             capture_output=True, text=True)
    assert refused.returncode == 2 and "--grid must be at least 2 (got 1)" in refused.stderr
    assert not (tmp_path / "x.osm").exists()


@pytest.mark.slow
def test_small_region_builds_clean(tmp_path):
    path, _ = generate(tmp_path, "--grid", "5")
    result = CliRunner().invoke(cli, ["build", str(path), "-o", str(tmp_path / "region"), "-q"])
    assert result.exit_code == 0, result.output
    stages = json.loads((tmp_path / "region" / "manifest.json").read_text())["stages"]
    check = next(stage for stage in stages if stage["name"] == "check")["facts"]
    assert check["status"] == "pass" and check["validate_errors"] == 0
