"""The shared files: validate reports exactly the known, explained findings (docs/validation-rules.md)."""

from __future__ import annotations

import re

import pytest

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.validate import validate_file

GEOREFERENCE_CONTRADICTION = {"georeference.plausible": 3}
EXPECTED_ERRORS = {
    ("esmini", "crest-curve.xodr"): {},
    ("esmini", "curves_elevation.xodr"): {},
    ("esmini", "e6mini.xodr"): {**GEOREFERENCE_CONTRADICTION, "geometry.gap": 1},
    ("esmini", "fabriksgatan.xodr"): {},
    ("esmini", "jolengatan.xodr"): {},
    ("esmini", "multi_intersections.xodr"): {},
    # roads 5 and 7 both run on from road 1's end, and road 0's lane -3 ends at zero width yet has a successor
    # (ASAM's checker finds both: road.linkage.is_junction_needed, road.lane.link.zero_width_at_end)
    ("esmini", "soderleden.xodr"): {**GEOREFERENCE_CONTRADICTION, "topology.contact-gap": 1,
                                    "topology.junction-needed": 1, "topology.zero-width-link": 1},
    ("esmini", "straight_500m.xodr"): GEOREFERENCE_CONTRADICTION,
    ("esmini", "straight_500m_signs.xodr"): {},
    ("esmini", "two_plus_one.xodr"): {},
    ("libopendrive", "test.xodr"): {"geometry.gap": 1},
}


def error_counts(report) -> dict:
    counts: dict = {}
    for finding in report.errors:
        counts[finding.rule] = counts.get(finding.rule, 0) + 1
    return counts


@pytest.mark.parametrize("folder, name", sorted(EXPECTED_ERRORS))
def test_reference_files_have_only_the_explained_errors(shared, folder, name):
    report = validate_file(shared("xodr", folder, name))
    assert error_counts(report) == EXPECTED_ERRORS[(folder, name)], report.format_text()


def test_explained_errors_are_where_the_docs_say(shared):
    [gap] = validate_file(shared("xodr", "libopendrive", "test.xodr")).by_rule("geometry.gap")
    assert gap.road == "346" and "0.001013 m" in gap.message
    # s is arc length: a paramPoly3 1.6 mm longer than its @length ends 1.6 mm before the next geometry starts
    [gap] = validate_file(shared("xodr", "esmini", "e6mini.xodr")).by_rule("geometry.gap")
    assert gap.road == "0" and gap.s == pytest.approx(513.789, abs=1e-3) and "0.001616 m longer" in gap.message
    [contact] = validate_file(shared("xodr", "esmini", "soderleden.xodr")).by_rule("topology.contact-gap")
    assert contact.road == "7" and "road 2" in contact.message and "66.3 m" in contact.message


def _check_netconvert_invariants(path, controllers_repaired: bool = True):
    """netconvert's defects are all inside junctions: plain roads join exactly, length errors are 0.1 m stubs
    (and, unless repaired, junction controller ids are written twice)."""
    odr = load_opendrive(path)
    report = validate_file(path)
    allowed = {"geometry.length", "topology.contact-gap"} | (set() if controllers_repaired else {"topology.duplicate-id"})
    assert set(error_counts(report)) <= allowed, report.format_text()
    assert all(f.message.startswith("controller id ") for f in report.by_rule("topology.duplicate-id"))
    assert all(odr.road_by_id[f.road].length <= 0.1 + 1e-9 for f in report.by_rule("geometry.length"))
    for finding in report.by_rule("topology.contact-gap") + report.by_rule("topology.contact-heading"):
        assert odr.road_by_id[finding.road].in_junction, finding
    assert not report.by_rule("topology.missing-road") and not report.by_rule("topology.lane-link-target")
    return report


@pytest.mark.slow
def test_netconvert_tavf_file(tavf_xodr, tmp_path):
    """Read as the standard says (s = arc length), netconvert's paramPoly3 curves that are longer than their
    @length end early: every geometry.gap is exactly that shortfall, and once the lengths are repaired (as a
    build does) the file has only netconvert's junction defects."""
    from tavf_mapkit.opendrive.repair_lengths import repair_geometry_lengths
    from tavf_mapkit.opendrive.writer import write_opendrive

    raw = validate_file(tavf_xodr, rules=["geometry.gap"])
    assert raw.findings
    for finding in raw.findings:
        gap, shortfall = re.search(r"starts ([\d.e-]+) m .* paramPoly3 before it is ([\d.e-]+) m longer",
                                   finding.message).groups()
        assert float(gap) == pytest.approx(float(shortfall), abs=1e-6), finding.message
    repaired, _ = repair_geometry_lengths(load_opendrive(tavf_xodr))
    write_opendrive(repaired, tmp_path / "lengths.xodr")
    report = _check_netconvert_invariants(tmp_path / "lengths.xodr", controllers_repaired=False)
    assert not report.by_rule("geometry.param-poly3-length")
    dangling = report.by_rule("topology.dead-end-junction-link")
    assert len(dangling) == 40 and all(f.severity == "warning" for f in dangling)
    assert not report.by_rule("topology.missing-junction")
    # U-turn connecting roads start at atan(1/2) = 26.6 degrees to the lane they continue
    assert any(re.search(r"differs by 26\.6 deg", f.message) for f in report.by_rule("topology.contact-heading"))


@pytest.mark.slow
def test_jungfernstieg_build(jungfernstieg_build):
    report = _check_netconvert_invariants(jungfernstieg_build / "jungfernstieg.xodr")
    assert not report.by_rule("topology.dead-end-junction-link")  # the pipeline removes netconvert's dangling links
    assert not report.by_rule("georeference.plausible") and not report.by_rule("georeference.missing")
