"""Rules that find their culprits on the map's tables at once (validate/geometry.py, validate/redundancy.py) report
exactly what their former road-by-road loops reported, in the same order, on real maps with findings."""

from __future__ import annotations

import itertools

import pytest

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.repair_redundant import redundant_lines
from tavf_mapkit.validate import validate_map

RULES = "geometry.length,geometry.zero-length-geometry,geometry.redundant-record"


def road_by_road(odr, tolerance_length=0.001, tolerance_redundant=1e-9):
    """(rule, road, s, message) of the three rules as every road's loop made them before."""
    from tavf_mapkit.validate.registry import select_rules

    tolerance_redundant = next(rule for rule in select_rules("geometry.redundant-record")).tolerance
    out = {"geometry.length": [], "geometry.zero-length-geometry": [], "geometry.redundant-record": []}
    for road in odr.roads:
        geometries = road.reference_line.geometries
        hits = out["geometry.length"]
        if geometries:
            if abs(geometries[0].s) > tolerance_length:
                hits.append((road.id, geometries[0].s, f"first geometry starts at s={geometries[0].s:g}, not 0"))
            for before, after in itertools.pairwise(geometries):
                expected = before.s + before.length
                if abs(after.s - expected) > tolerance_length:
                    hits.append((road.id, after.s,
                                 f"geometry at s={after.s:g} should start at s={expected:.6g} (previous s + length)"))
            end = geometries[-1].s + geometries[-1].length
            if abs(end - road.length) > tolerance_length:
                hits.append((road.id, None, f"geometries end at s={end:.6g} but the road's @length is "
                                            f"{road.length:.6g} ({end - road.length:+.4g} m)"))
        for geometry in geometries:
            if not geometry.length > 0 and geometry.length == geometry.length and abs(geometry.length) != float("inf"):
                out["geometry.zero-length-geometry"].append(
                    (road.id, geometry.s, f"geometry at s={geometry.s:g} has length 0"))
        for k in redundant_lines(geometries, tolerance_redundant):
            out["geometry.redundant-record"].append(
                (road.id, geometries[k].s, f"line at s={geometries[k].s:g} continues the line before it (same heading)"))
    return out


def found(odr) -> dict:
    out = {rule: [] for rule in RULES.split(",")}
    for finding in validate_map(odr, rules=RULES).findings:
        if finding.rule == "geometry.redundant-record" and not finding.message.startswith("line at"):
            continue  # the profiles' records: unchanged, still road by road
        out[finding.rule].append((finding.road, finding.s, finding.message))
    return out


@pytest.mark.slow
def test_table_rules_equal_the_road_loops_on_netconverts_tavf_output(tavf_xodr):
    # netconvert's own TAVF OpenDRIVE, before the build's repairs: geometry-length findings (roads of 0.1 m whose geometries end elsewhere)
    odr = load_opendrive(tavf_xodr)
    expected = road_by_road(odr)
    assert len(expected["geometry.length"]) > 10
    assert found(odr) == expected


@pytest.mark.parametrize("folder, name", [("esmini", "e6mini.xodr"), ("libopendrive", "test.xodr"),
                                          ("esmini", "soderleden.xodr")])
def test_table_rules_equal_the_road_loops_on_reference_files(shared, folder, name):
    odr = load_opendrive(shared("xodr", folder, name))
    assert found(odr) == road_by_road(odr)
