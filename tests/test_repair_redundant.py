"""Redundant records merged (opendrive/repair_redundant.py): the validator's geometry.redundant-record finds them,
the repair leaves none, moves no lane border, and changes nothing on a second pass."""

from __future__ import annotations

import numpy as np
import pytest

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.repair_redundant import MERGED_RECORDS, repair_redundant
from tavf_mapkit.opendrive.writer import to_xml, write_opendrive
from tavf_mapkit.validate import validate_file
from tests.xodr_factory import document, road_xml

HEADING = 0.3
DIRECTION = np.array([np.cos(HEADING), np.sin(HEADING)])


def _line(s: float, length: float, hdg: float = HEADING, shift: float = 0.0) -> str:
    x, y = (float(v) for v in s * DIRECTION + shift * np.array([-DIRECTION[1], DIRECTION[0]]))
    return f'<geometry s="{s!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}"><line/></geometry>'


def _redundant_document() -> str:
    """Road 1: a line split in three at s = 10 and 25 (collinear to the bit), a lane width record at sOffset 12
    continuing the record before it, two elevation records of one polynomial. Road 2: two lines of one heading
    whose second starts 1 mm off the first's end (a gap, not one line: not merged, still reported)."""
    lanes = """
        <laneSection s="0">
          <left><lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0.01" c="0" d="0"/>
            <width sOffset="12" a="3.62" b="0.01" c="0" d="0"/></lane></left>
          <center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
        </laneSection>"""
    elevation = """<elevationProfile><elevation s="0" a="1" b="0.02" c="0" d="0"/>
        <elevation s="20" a="1.4" b="0.02" c="0" d="0"/></elevationProfile>"""
    first = road_xml(_line(0, 10) + _line(10, 15) + _line(25, 15), 40.0, lanes=lanes, extra=elevation)
    second = road_xml(_line(0, 10) + _line(10, 10, shift=0.001), 20.0, road_id="2")
    return document(first, second, _nearly_collinear())


def _nearly_collinear() -> str:
    """Road 3: netconvert's collinear lines as Milan's build has them, headings written to 8 decimals (1.4e-7 rad
    apart) and each line starting where the one before ends."""
    geometries, x, y, s = [], 0.0, 50.0, 0.0
    for length, hdg in ((25.72873514, 0.30000014), (13.89, 0.3), (5.50034251, 0.30000013)):
        geometries.append(f'<geometry s="{s!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}"><line/></geometry>')
        x, y, s = float(x + length * np.cos(hdg)), float(y + length * np.sin(hdg)), s + length
    return road_xml("".join(geometries), s, road_id="3")


def _borders(odr, step: float = 0.5) -> dict:
    out = {}
    for road in odr.roads:
        s = np.arange(0.0, road.length + 1e-9, step)
        for k, _section in enumerate(road.lane_sections):
            for lane_id, t in road.lane_borders(k, s).items():
                out[road.id, lane_id] = road.surface_point(s, t)
    return out


def test_validator_finds_the_redundant_records(tmp_path):
    path = tmp_path / "redundant.xodr"
    path.write_text(_redundant_document())
    found = validate_file(path, rules="geometry.redundant-record").findings
    assert [(f.road, f.lane, round(f.s, 3)) for f in found] == [
        ("1", None, 10.0), ("1", None, 25.0), ("1", None, 20.0), ("1", 1, 12.0), ("2", None, 10.0),
        ("3", None, 25.729), ("3", None, 39.619)]
    assert str(found[0]).endswith("road 1, s=10.00: line at s=10 continues the line before it (same heading)")


def test_repair_merges_them_without_moving_a_border_and_is_idempotent(tmp_path):
    path = tmp_path / "redundant.xodr"
    path.write_text(_redundant_document())
    before = load_opendrive(path)
    repaired, repairs = repair_redundant(before)
    assert [(r.action, r.road) for r in repairs] == [(MERGED_RECORDS, "1"), (MERGED_RECORDS, "3")]
    assert "2 line geometries, 1 elevation records, 1 lane width records merged" in repairs[0].detail
    road = repaired.road_by_id["1"]
    assert [(g.s, g.length) for g in road.reference_line.geometries] == [(0.0, 40.0)]
    assert len(repaired.road_by_id["2"].reference_line.geometries) == 2  # 1 mm apart: a gap, not one line
    [merged] = repaired.road_by_id["3"].reference_line.geometries
    assert merged.length == pytest.approx(45.11907765, abs=1e-12) and abs(merged.hdg - 0.3) < 2e-7

    out = tmp_path / "repaired.xodr"
    write_opendrive(repaired, out)
    after = load_opendrive(out)
    old, new = _borders(before), _borders(after)
    assert old.keys() == new.keys()
    # lines of one heading merge exactly; nearly collinear ones move no border by more than 10 micrometres
    assert max(float(np.abs(new[k] - old[k]).max()) for k in old if k[0] != "3") < 1e-9
    assert 0 < max(float(np.abs(new[k] - old[k]).max()) for k in old if k[0] == "3") < 1e-5
    assert np.allclose(road.elevation(np.linspace(0, 40, 81)), before.road_by_id["1"].elevation(np.linspace(0, 40, 81)),
                       rtol=0, atol=1e-12)

    left = validate_file(out, rules="geometry.redundant-record").findings
    assert [(f.road, f.s) for f in left] == [("2", 10.0)]
    again, more = repair_redundant(after)
    assert more == [] and again is after
    assert to_xml(again) == out.read_bytes()


def test_the_sample_build_has_no_redundant_record(sample_build_dir):
    """netconvert writes the synthetic sample's straight edges with collinear inner points as one line per
    segment (12 pairs); the build merges them."""
    xodr = sample_build_dir / "sample.xodr"
    assert validate_file(xodr, rules="geometry.redundant-record").findings == ()
    manifest = (sample_build_dir / "manifest.json").read_text()
    assert MERGED_RECORDS in manifest
