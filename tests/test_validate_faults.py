"""Fault injection: each fault class, injected into a clean file, fires the right rule at the right road."""

from __future__ import annotations

import math

import pytest
from lxml import etree

from tavf_mapkit.validate import validate_file
from tests.validate_network import line, network_text, write_network


def report_for(tmp_path, **changes):
    return validate_file(write_network(tmp_path, **changes))


def roads_of(report, rule_id: str) -> set:
    return {finding.road for finding in report.by_rule(rule_id)}


def test_clean_network_has_no_errors_or_warnings(tmp_path):
    report = report_for(tmp_path)
    assert report.summary["errors"] == 0 and report.summary["warnings"] == 0, report.format_text()
    assert report.exit_code == 0
    # the two open road ends, nothing else
    assert {(f.road, f.s) for f in report.by_rule("topology.dead-end")} == {("1", 0.0), ("4", 30.0)}


def test_gap_between_geometries(tmp_path):
    geometry = line(0.0, 0.0, 0.0, 60.0) + line(60.0, 60.0, 0.05, 40.0)  # second piece starts 5 cm off
    report = report_for(tmp_path, road1_geometry=geometry)
    [finding] = report.by_rule("geometry.gap")
    assert (finding.road, finding.s, finding.severity) == ("1", 60.0, "error")
    assert "0.05 m" in finding.message
    assert report.exit_code == 1


def test_gap_below_tolerance_is_accepted(tmp_path):
    geometry = line(0.0, 0.0, 0.0, 60.0) + line(60.0, 60.0, 0.0009, 40.0)  # 0.9 mm < 1 mm
    assert not report_for(tmp_path, road1_geometry=geometry).by_rule("geometry.gap")


def test_kink_between_geometries(tmp_path):
    kinked = math.radians(0.5)
    geometry = line(0.0, 0.0, 0.0, 60.0) + line(60.0, 60.0, 0.0, 40.0, hdg=kinked)
    report = report_for(tmp_path, road1_geometry=geometry)
    [finding] = report.by_rule("geometry.kink")
    assert (finding.road, finding.s, finding.severity) == ("1", 60.0, "warning")
    assert "0.5 deg" in finding.message
    # the bent road no longer reaches road 2: 40 m * sin(0.5 deg) = 0.35 m
    assert "1" in roads_of(report, "topology.contact-gap") | roads_of(report, "topology.contact-gap")


def test_broken_road_link(tmp_path):
    report = report_for(tmp_path, road2_successor='<successor elementType="road" elementId="99" '
                                                  'contactPoint="start"/>')
    [finding] = report.by_rule("topology.missing-road")
    assert finding.road == "2" and "road 99" in finding.message and finding.severity == "error"


def test_broken_lane_link(tmp_path):
    report = report_for(tmp_path, road1_right_successor=-5)
    [finding] = report.by_rule("topology.lane-link-target")
    assert (finding.road, finding.lane) == ("1", -1) and "lane -5" in finding.message


def test_missing_junction(tmp_path):
    report = report_for(tmp_path, with_junction=False)
    findings = report.by_rule("topology.missing-junction")
    # the connecting road belongs to it, and both incoming roads link to it
    assert {f.road for f in findings} == {"2", "3", "4"}
    assert all(f.severity == "error" and "junction 10" in f.message for f in findings)
    assert not report.by_rule("topology.dead-end-junction-link")


def test_single_dangling_junction_link_is_a_warning(tmp_path):
    """netconvert's dead-end pattern: one road end links to a junction that is never written."""
    report = report_for(tmp_path, road2_successor='<successor elementType="junction" elementId="77"/>')
    [finding] = report.by_rule("topology.dead-end-junction-link")
    assert (finding.road, finding.severity, finding.s) == ("2", "warning", 50.0)
    assert not report.by_rule("topology.missing-junction")


def test_negative_width(tmp_path):
    # 3 m at s=0 falling 0.2 m per metre: zero at s=15, -3 m at the end (s=30)
    report = report_for(tmp_path, road4_right_width='<width sOffset="0" a="3" b="-0.2" c="0" d="0"/>')
    [finding] = report.by_rule("geometry.negative-width")
    assert (finding.road, finding.lane, finding.severity) == ("4", -1, "error")
    assert finding.s == pytest.approx(30.0) and "-3 m" in finding.message


def test_negative_width_inside_a_record_is_found_exactly(tmp_path):
    """A cubic that dips below zero between positive ends: the minimum is found analytically."""
    # w(s) = 1 - 0.3 s + 0.012 s^2 on [0, 30]: minimum at s=12.5, w = -0.875; w(0)=1, w(30)=2.8
    report = report_for(tmp_path, road4_right_width='<width sOffset="0" a="1" b="-0.3" c="0.012" d="0"/>')
    [finding] = report.by_rule("geometry.negative-width")
    assert finding.s == pytest.approx(12.5) and "-0.875 m" in finding.message


def test_missing_georeference(tmp_path):
    report = report_for(tmp_path, header_extra="")
    [finding] = report.by_rule("georeference.missing")
    assert finding.severity == "warning" and finding.road is None
    assert report.exit_code == 0
    assert validate_file(write_network(tmp_path, header_extra=""), strict=True).exit_code == 1


def _georeference(definition: str, offset: str = "") -> str:
    return f"<geoReference><![CDATA[{definition}]]></geoReference>{offset}"


@pytest.mark.parametrize("header, expected", [
    # UTM zone 32 without an offset: local (0..200, 0) are taken as eastings 0..200 m
    (_georeference("+proj=utm +zone=32 +ellps=WGS84 +units=m +no_defs"), "<offset> is missing or wrong"),
    (_georeference("EPSG:32632"), "<offset> is missing or wrong"),
    # a zone that does not contain +lon_0
    (_georeference("+proj=utm +zone=32 +lon_0=-122 +ellps=WGS84 +units=m +no_defs"), "covers longitudes"),
    # PROJ ignores +lat_0 for UTM: with a plausible offset the map is at the equator, +lat_0 says Hamburg
    (_georeference("+proj=utm +zone=32 +lat_0=53.55 +lon_0=9 +ellps=WGS84 +units=m +no_defs",
                   '<offset x="500000" y="0" z="0" hdg="0"/>'), "ignores +lat_0"),
])
def test_contradictory_georeference(tmp_path, header, expected):
    report = report_for(tmp_path, header_extra=header)
    findings = report.by_rule("georeference.plausible")
    assert findings and all(f.severity == "error" for f in findings)
    assert any(expected in f.message for f in findings), [f.message for f in findings]


def test_unparseable_georeference(tmp_path):
    report = report_for(tmp_path, header_extra="<geoReference>+proj=nonsense +zone=x</geoReference>")
    [finding] = report.by_rule("georeference.proj")
    assert finding.severity == "error" and "PROJ" in finding.message


def test_small_shift_is_invisible_to_a_single_file(tmp_path):
    """A consistently shifted map (3 m) is a valid map: only compare/match-trace against a reference see it."""
    report = report_for(tmp_path, shift_x=3.0)
    assert report.summary["errors"] == 0 and report.summary["warnings"] == 0


def test_large_shift_contradicts_the_header_box(tmp_path):
    report = report_for(tmp_path, shift_x=300.0)
    [finding] = report.by_rule("georeference.header-bounds")
    assert finding.severity == "warning" and "off by up to 300" in finding.message


def _transform_map(source, target, dx=0.0, dy=0.0, rotation_deg=0.0):
    """Move every planView geometry of a file rigidly (rotation about the local origin, then shift)."""
    tree = etree.parse(str(source))
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    for geometry in tree.iterfind("road/planView/geometry"):
        x, y = float(geometry.get("x")), float(geometry.get("y"))
        geometry.set("x", repr(c * x - s * y + dx))
        geometry.set("y", repr(s * x + c * y + dy))
        geometry.set("hdg", repr(float(geometry.get("hdg")) + math.radians(rotation_deg)))
    tree.write(str(target))
    return target


@pytest.mark.slow
def test_whole_map_rotated_or_shifted_netconvert(tavf_xodr, tmp_path):
    """On netconvert's TAVF file (header box tight, map 0.3-4 km from the local origin) a 1 degree rotation about
    the origin contradicts the header box; a 3 m shift does not (it needs mapkit compare)."""
    rules = "georeference,geometry.gap,topology.contact-gap"
    rotated = validate_file(_transform_map(tavf_xodr, tmp_path / "rotated.xodr", rotation_deg=1.0), rules=rules)
    [finding] = rotated.by_rule("georeference.header-bounds")
    assert "fit neither" in finding.message
    shifted = validate_file(_transform_map(tavf_xodr, tmp_path / "shifted.xodr", dx=3.0), rules=rules)
    original = validate_file(tavf_xodr, rules=rules)
    assert not shifted.by_rule("georeference.header-bounds")
    # a rigid motion changes no internal relation: the same findings as the original, rule by rule
    for report in (rotated, shifted):
        assert report.summary["by_rule"].get("topology.contact-gap") == original.summary["by_rule"].get(
            "topology.contact-gap")
        # the gaps where a paramPoly3 is longer than its @length (s is arc length), and only those
        assert {(f.road, f.s) for f in report.by_rule("geometry.gap")} == \
            {(f.road, f.s) for f in original.by_rule("geometry.gap")}


def test_s_order_and_unknown_element_with_lines(tmp_path):
    text = network_text(road1_geometry=line(60.0, 60.0, 0.0, 40.0) + line(0.0, 0.0, 0.0, 60.0))
    text = text.replace("<planView>", "<planView><geomtry/>", 1)
    path = tmp_path / "order.xodr"
    path.write_text(text)
    report = validate_file(path)
    [order] = report.by_rule("structure.s-order")
    [unknown] = report.by_rule("structure.unknown-element")
    lines = text.splitlines()
    assert order.road == "1" and 'geometry s="0.0"' in lines[order.line - 1]
    assert unknown.road == "1" and "<geomtry/>" in lines[unknown.line - 1]
