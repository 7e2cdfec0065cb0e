"""mapkit compare: self comparison, a shifted copy, a build against its own SUMO source, areas, errors."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner

from tavf_mapkit.accuracy.compare import compare_networks
from tavf_mapkit.cli.main import cli
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import load_opendrive


def shifted_copy(source, target, dx, dy):
    """The same file with every planView geometry moved by (dx, dy) in local coordinates."""
    text = source.read_text(encoding="utf-8")

    def move(match):
        x, y = float(match.group(2)), float(match.group(4))
        return f'{match.group(1)}{x + dx!r}{match.group(3)}{y + dy!r}"'

    moved, count = re.subn(r'(<geometry [^>]*?\bx=")([-0-9.e]+)(" y=")([-0-9.e]+)"', move, text)
    assert count > 100
    target.write_text(moved, encoding="utf-8")
    return target


@pytest.fixture(scope="module")
def dlr_xodr(tavf_dlr_build):
    return tavf_dlr_build / "tavf-dlr.xodr"


@pytest.mark.slow
def test_network_against_itself(dlr_xodr):
    report = compare_networks(dlr_xodr, dlr_xodr).to_dict()
    assert report["precision"] == report["recall"] == {"0.5": 1.0, "1": 1.0, "2": 1.0, "3": 1.0, "5": 1.0}
    assert report["hausdorff_m"] == {"lanes": 0.0, "roads": 0.0}
    assert report["offset"]["median_m"] == report["offset"]["p95_m"] == 0.0
    fit = report["fitted_transform"]
    assert abs(fit["dx"]) < 1e-3 and abs(fit["dy"]) < 1e-3 and abs(fit["rotation_deg"]) < 1e-4
    assert fit["scale"] == pytest.approx(1.0, abs=1e-6)
    assert report["topology"]["junctions"]["build"] == report["topology"]["junctions"]["reference"] > 300


@pytest.mark.slow
def test_shifted_copy_is_found_by_the_fitted_transform(dlr_xodr, tmp_path):
    moved = shifted_copy(dlr_xodr, tmp_path / "moved.xodr", 2.0, -1.0)
    report = compare_networks(moved, dlr_xodr).to_dict()
    # (2, -1) in the map's local frame is, east/north, that vector turned by the grid convergence between the
    # build's projection and the comparison frame: compute the expectation through the georeference
    georef = load_opendrive(dlr_xodr).georeference
    lon, lat = georef.local_to_wgs84(np.array([0.0, 2.0]), np.array([0.0, -1.0]))
    from tavf_mapkit.accuracy.networks import CommonFrame

    frame = CommonFrame(*_frame_centre(report))
    x, y = frame.from_lonlat(lon, lat)
    expected = (x[1] - x[0], y[1] - y[0])
    fit = report["fitted_transform"]
    assert math.hypot(fit["dx"] - expected[0], fit["dy"] - expected[1]) < 0.05
    assert abs(fit["rotation_deg"]) < 0.01 and fit["scale"] == pytest.approx(1.0, abs=1e-4)
    # offsets are across the lines: between the shift's components and its length
    assert 0.5 < report["offset"]["median_m"] < math.hypot(2, 1)
    assert report["precision"]["0.5"] < 0.5 < report["precision"]["5"]


def _frame_centre(report):
    parameters = dict(re.findall(r"\+(lon_0|lat_0)=(\S+)", report["crs"]))
    return float(parameters["lon_0"]), float(parameters["lat_0"])


@pytest.mark.slow
def test_build_against_its_own_sumo_source(dlr_xodr, shared):
    """netconvert's OpenDRIVE of DLR's net, placed by our georeference, lies on the net's lanes placed by its
    own <location>: an end-to-end check of both georeference chains."""
    net = shared("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")
    report = compare_networks(dlr_xodr, net).to_dict()
    assert report["reference_kind"] == "sumo"
    assert report["offset"]["median_m"] < 0.05 and report["recall"]["3"] > 0.99
    fit = report["fitted_transform"]
    assert math.hypot(fit["dx"], fit["dy"]) < 0.05


def test_bbox_restricts_and_far_box_is_an_error(sample_build_dir, tmp_path):
    xodr = sample_build_dir / "sample.xodr"
    odr = load_opendrive(xodr)
    west, south, east, north = odr.bounds()
    lon, lat = odr.georeference.local_to_wgs84(np.array([west, 0.5 * (west + east)]), np.array([south, north]))
    runner = CliRunner()
    whole = json.loads(runner.invoke(cli, ["compare", str(xodr), str(xodr), "--json"]).output)
    part = runner.invoke(cli, ["compare", str(xodr), str(xodr), "--json",
                               "--bbox", f"{lon[0]},{lat[0]},{lon[1]},{lat[1]}", "--plot", str(tmp_path / "c.png")])
    assert part.exit_code == 0, part.output
    part = json.loads(part.output)
    assert 0.2 * whole["lengths_m"]["build"] < part["lengths_m"]["build"] < 0.8 * whole["lengths_m"]["build"]
    assert part["recall"]["0.5"] == 1.0
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    far = runner.invoke(cli, ["compare", str(xodr), str(xodr), "--bbox", "10.2,53.0,10.3,53.1"])
    assert far.exit_code == 2
    assert far.output.strip().endswith("do not overlap inside the given area")


def test_inputs_that_cannot_be_compared(tmp_path):
    plain = tmp_path / "plain.xodr"
    plain.write_text('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>'
                     '<road id="1" length="10" junction="-1"><planView><geometry s="0" x="0" y="0" hdg="0" '
                     'length="10"><line/></geometry></planView><lanes><laneSection s="0"><center>'
                     '<lane id="0" type="none"/></center><right><lane id="-1" type="driving"><width sOffset="0" '
                     'a="3" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road></OpenDRIVE>')
    with pytest.raises(InputError, match="has no geoReference"):
        compare_networks(plain, plain)
    result = CliRunner().invoke(cli, ["compare", str(tmp_path / "missing.xodr"), str(plain)])
    assert result.exit_code == 2 and "missing.xodr: file not found" in result.output
    net = tmp_path / "x.net.xml"
    result = CliRunner().invoke(cli, ["compare", str(net), str(plain)])
    assert result.exit_code == 2 and "the build must be an OpenDRIVE file" in result.output
