"""mapkit info / export on every shared file, and the export CSV contract."""

from __future__ import annotations

import csv
import glob
import io
import json

import numpy as np
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tests.conftest import SHARED_DATA, shared_path


def test_info_on_every_shared_file():
    shared_path("xodr")
    files = sorted(glob.glob(str(SHARED_DATA / "xodr" / "*" / "*.xodr")))
    assert len(files) == 11
    for path in files:
        result = CliRunner().invoke(cli, ["info", "--json", path])
        assert result.exit_code == 0, result.output
        summary = json.loads(result.output)
        assert summary["counts"]["roads"] > 0 and summary["total_length_m"] > 0
    town = json.loads(CliRunner().invoke(cli, ["info", "--json", str(shared_path("xodr", "libopendrive", "test.xodr"))]).output)
    assert town["counts"]["roads"] == 234


def test_info_human_output_names_the_contradiction():
    result = CliRunner().invoke(cli, ["info", str(shared_path("xodr", "esmini", "soderleden.xodr"))])
    assert result.exit_code == 0
    assert "plausible: NO" in result.output and "contradicts itself" in result.output


def test_lane_border_csv_contract_matches_reference_sampling():
    path = shared_path("xodr", "esmini", "crest-curve.xodr")
    result = CliRunner().invoke(cli, ["export", str(path), "--layer", "lane-border", "--format", "csv", "--step", "0.5"])
    assert result.exit_code == 0
    rows = list(csv.reader(io.StringIO(result.output)))
    assert rows[0] == ["road", "section_s0", "lane", "s", "x", "y", "z"]
    data = np.array([[float(v) for v in row[1:]] for row in rows[1:]])
    assert 0 not in data[:, 1]
    # samples at s0, s0+0.5, ... and the section end itself
    lane = data[data[:, 1] == data[0, 1]]
    assert np.allclose(np.diff(lane[:-1, 2]), 0.5)
    assert lane[-1, 2] == 0.0 or lane[-1, 2] > lane[-2, 2]


def test_lane_center_csv_columns_and_wgs84_geojson(tavf_xodr):
    runner = CliRunner()
    result = runner.invoke(cli, ["export", str(tavf_xodr), "--layer", "lane-center", "--format", "csv", "--step", "5"])
    assert result.exit_code == 0
    header = result.output.splitlines()[0]
    assert header == "road,section_s0,lane,type,s,x,y,z"
    result = runner.invoke(cli, ["export", str(tavf_xodr), "--layer", "lane", "--step", "5"])
    collection = json.loads(result.output)
    coords = np.array([c for f in collection["features"] for c in f["geometry"]["coordinates"][0]])
    # the TAVF lies in central Hamburg
    assert 9.95 < coords[:, 0].min() and coords[:, 0].max() < 10.02
    assert 53.54 < coords[:, 1].min() and coords[:, 1].max() < 53.571


def test_export_without_georeference_refuses_wgs84(tmp_path):
    path = shared_path("xodr", "esmini", "crest-curve.xodr")
    result = CliRunner().invoke(cli, ["export", str(path), "--layer", "lane", "--crs", "wgs84"])
    assert result.exit_code == 2 and "has no <geoReference>" in result.output
    out = tmp_path / "lanes.csv"
    result = CliRunner().invoke(cli, ["export", str(path), "--layer", "road-mark", "--format", "csv", "-o", str(out)])
    assert result.exit_code == 0 and out.read_text().startswith("feature,road,lane,type")


def test_every_layer_exports(tmp_path):
    path = shared_path("xodr", "esmini", "straight_500m_signs.xodr")
    for layer in ("reference-line", "lane-border", "lane-center", "lane", "road-mark", "object", "signal"):
        result = CliRunner().invoke(cli, ["export", str(path), "--layer", layer, "--crs", "local"])
        assert result.exit_code == 0, (layer, result.output)
        assert json.loads(result.output)["features"], layer
