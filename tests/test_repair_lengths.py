"""@length repaired to the curve's arc length (opendrive/repair_lengths.py), s read as arc length, --no-repair.

The repair's promise: every lane border stays where the file's s put it before -- s spread over each curve in
proportion to its arc length, netconvert's own placement -- and the road ends exactly where its curve does.
"Before" is computed here from the unrepaired map and that proportion alone, "after" by the ordinary reader.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.repair_lengths import GEOMETRY_LENGTH, repair_geometry_lengths, true_lengths
from tavf_mapkit.opendrive.surface import surface_points
from tavf_mapkit.opendrive.writer import to_xml, write_opendrive
from tavf_mapkit.validate import validate_file
from tests.xodr_factory import document, road_xml

REPO_SAMPLE = "sample_data/tavf_synthetic.osm"

# geometry 0: normalized paramPoly3 u = 20 p + 5 p^2 - 2 p^3, v = 4 p^2 -- its @length 0.3 m short;
# geometry 1: a line from the curve's true end; geometry 2: arcLength u = p, v = 0.02 p^2 over p in [0, 15],
# @length 15 (shorter than the curve); geometry 3: normalized u = 9.9 p (9.9 m), @length 10 (too long)
CURVE = dict(aU=0.0, bU=20.0, cU=5.0, dU=-2.0, aV=0.0, bV=0.0, cV=4.0, dV=0.0)


def _poly(p, c):
    return c["aU"] + p * (c["bU"] + p * (c["cU"] + p * c["dU"])), c["aV"] + p * (c["bV"] + p * (c["cV"] + p * c["dV"]))


def _arc(c, p_end):
    from scipy.integrate import quad

    return quad(lambda p: math.hypot(c["bU"] + 2 * c["cU"] * p + 3 * c["dU"] * p * p,
                                     c["bV"] + 2 * c["cV"] * p + 3 * c["dV"] * p * p), 0.0, p_end,
                epsabs=1e-13, epsrel=1e-13)[0]


def _attrs(c, p_range):
    return " ".join(f'{k}="{v!r}"' for k, v in c.items()) + f' pRange="{p_range}"'


def _inconsistent_road() -> tuple[str, list[float]]:
    """A road with the four geometries above, and records of every kind along s (varying across joints)."""
    geometries, s, x, y, hdg = [], 0.0, 0.0, 0.0, 0.0
    second = dict(aU=0.0, bU=1.0, cU=0.0, dU=0.0, aV=0.0, bV=0.0, cV=0.02, dV=0.0)
    fourth = dict(aU=0.0, bU=9.9, cU=0.0, dU=0.0, aV=0.0, bV=0.0, cV=0.0, dV=0.0)
    true = [_arc(CURVE, 1.0), 25.0, _arc(second, 15.0), 9.9]
    stated = [true[0] - 0.3, 25.0, 15.0, 10.0]
    shapes = [f"<paramPoly3 {_attrs(CURVE, 'normalized')}/>", "<line/>", f"<paramPoly3 {_attrs(second, 'arcLength')}/>",
              f"<paramPoly3 {_attrs(fourth, 'normalized')}/>"]
    ends = [(_poly(1.0, CURVE), 8.0 / 24.0), None, (_poly(15.0, second), 0.6), ((9.9, 0.0), 0.0)]
    for k in range(4):
        geometries.append(f'<geometry s="{s!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{stated[k]!r}">'
                          f"{shapes[k]}</geometry>")
        if ends[k] is None:  # a line: straight on
            x, y = x + true[k] * math.cos(hdg), y + true[k] * math.sin(hdg)
        else:  # the next geometry starts at the curve's true end, with its heading
            (u, v), slope = ends[k]
            x, y = x + math.cos(hdg) * u - math.sin(hdg) * v, y + math.sin(hdg) * u + math.cos(hdg) * v
            hdg = hdg + math.atan(slope)
        s += stated[k]
    length = s
    lanes = """
        <laneSection s="0">
          <left><lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0.01" c="-0.0004" d="0.000003"/>
            <roadMark sOffset="12.5" type="solid" color="standard"/></lane></left>
          <center><lane id="0" type="none" level="false"/></center>
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3" b="0" c="0" d="0"/>
            <width sOffset="18" a="3" b="0.02" c="0" d="-0.00001"/></lane>
            <lane id="-2" type="sidewalk" level="false"><border sOffset="0" a="-9" b="-0.01" c="0" d="0"/></lane></right>
        </laneSection>
        <laneSection s="44.5">
          <right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3.2" b="-0.005" c="0.0001" d="0"/>
          </lane></right>
          <center><lane id="0" type="none" level="false"/></center>
        </laneSection>"""
    extra = """
      <elevationProfile><elevation s="0" a="1" b="0.02" c="0.0001" d="-0.000002"/>
        <elevation s="50" a="2" b="0" c="0" d="0"/></elevationProfile>
      <lateralProfile><superelevation s="0" a="0" b="0.001" c="0" d="0"/></lateralProfile>
      <objects><object id="7" s="30" t="-8" type="pole"><repeat s="10" length="40" distance="5" tStart="-8" tEnd="-8"
        zOffsetStart="0" zOffsetEnd="0" heightStart="1" heightEnd="1"/></object></objects>
      <signals><signal id="9" s="60" t="-7" dynamic="no" orientation="+" zOffset="2" type="206" subtype="-1"/></signals>"""
    offset = '<laneOffset s="0" a="0.1" b="0.002" c="0" d="0"/>'
    return document(road_xml("".join(geometries), length, lanes, extra=extra, lane_offset=offset)), true


@pytest.fixture
def inconsistent(tmp_path):
    text, true = _inconsistent_road()
    path = tmp_path / "inconsistent.xodr"
    path.write_text(text)
    return path, true


def _old_and_new_s(old_road, new_road, samples: int = 40):
    """Per geometry of the old road: s inside it, and the s that the same fraction of the curve has after the
    repair (the old s spread in proportion to the arc length: new = S + (s - s_k) * arc / @length)."""
    old_g, new_g = old_road.reference_line.geometries, new_road.reference_line.geometries
    old_s, new_s, rate = [], [], []
    for k, (before, after) in enumerate(zip(old_g, new_g)):
        end = old_g[k + 1].s if k + 1 < len(old_g) else old_road.length
        s = np.linspace(before.s, end, samples, endpoint=k + 1 == len(old_g))
        old_s.append(s)
        new_s.append(after.s + (s - before.s) * after.length / before.length)
        rate.append(np.full(len(s), after.length / before.length))
    return np.concatenate(old_s), np.concatenate(new_s), np.concatenate(rate)


def border_shift(old, new) -> float:
    """Largest distance between a lane border point of ``old`` (read with s spread over each curve) and the
    same border point of ``new`` (read as usual), over every repaired road, section and lane."""
    worst = 0.0
    for old_road, new_road in zip(old.roads, new.roads):
        if old_road is new_road:
            continue
        s_old, s_new, rate = _old_and_new_s(old_road, new_road)
        line = old_road.reference_line
        index = line.geometry_index(s_old)
        x, y, heading, _ = line.table.evaluate(index, (s_old - line.table.s[index]) * rate)
        before_frame = (x, y, old_road.elevation(s_old), heading,
                        old_road.elevation.derivative(s_old) / rate,  # dz per metre of curve
                        old_road.superelevation(s_old))
        after_frame = new_road.reference_point(s_new)
        old_section = old_road.section_index(s_old)
        for k in np.unique(old_section):
            mask = old_section == k
            new_k = int(new_road.section_index(s_new[mask][len(s_new[mask]) // 2:][:1])[0])
            t_old = old_road.lane_borders(int(k), s_old[mask])
            t_new = new_road.lane_borders(new_k, s_new[mask])
            assert set(t_old) == set(t_new)
            for lane, t in t_old.items():
                before = surface_points(*(v[mask] for v in before_frame), t)
                after = surface_points(*(v[mask] for v in after_frame), t_new[lane])
                worst = max(worst, float(np.linalg.norm(before - after, axis=1).max()))
    return worst


# --- reading s as arc length ----------------------------------------------------------------------------------


def test_s_is_arc_length_inside_a_param_poly3(inconsistent):
    """At s - s0 = the arc length up to p, the point is the curve's point at p -- whatever @length says; past
    the curve's end the reference line holds that end (libOpenDRIVE does the same)."""
    path, true = inconsistent
    road = load_opendrive(path).roads[0]
    for p in (0.1, 0.5, 0.9):
        arc = _arc(CURVE, p)
        x, y, heading, _ = road.reference_line.evaluate([arc])
        u, v = _poly(p, CURVE)
        assert math.hypot(x[0] - u, y[0] - v) < 1e-9
    # the curve is 0.3 m longer than its @length: read as arc length the geometry ends 0.3 m before its curve
    g1 = road.reference_line.geometries[1]
    x, y, _, _ = road.reference_line.table.evaluate(np.array([0]), np.array([true[0] - 0.3]))
    assert math.hypot(x[0] - g1.x, y[0] - g1.y) == pytest.approx(0.3, abs=1e-3)
    # geometry 3 is 9.9 m long, @length 10: its last 0.1 m of s stand still at the curve's end
    g3 = road.reference_line.geometries[3]
    x, y, _, _ = road.reference_line.evaluate([g3.s + 9.9, g3.s + 9.95, g3.s + 10.0])
    assert np.ptp(x) < 1e-12 and np.ptp(y) < 1e-12


def test_road_and_map_evaluate_the_reference_line_alike(inconsistent):
    """ReferenceLine (one road) and NetworkArrays (the whole map) pick the same geometry by one rule, also
    before the first geometry and past the last one."""
    path, _ = inconsistent
    odr = load_opendrive(path)
    road = odr.roads[0]
    s = np.linspace(-5.0, road.length + 5.0, 997)
    x, y, heading, _ = road.reference_line.evaluate(s)
    ax, ay, _, aheading, *_ = odr.arrays.reference(np.zeros(len(s), dtype=np.int64), s)
    assert np.array_equal(x, ax) and np.array_equal(y, ay) and np.array_equal(heading, aheading)


def test_validator_names_the_gap_and_the_still_stretch(inconsistent):
    path, true = inconsistent
    report = validate_file(path)
    messages = [f.message for f in report.by_rule("geometry.param-poly3-length")]
    assert any("(+0.3 m): s ends 0.3 m before the curve does, a gap at its end" in m for m in messages), messages
    assert any("(-0.1 m): s runs 0.1 m past the curve's end, where the reference line stands still" in m
               for m in messages), messages
    gaps = [f.message for f in report.by_rule("geometry.gap")]
    assert any("the paramPoly3 before it is 0.3 m longer than its @length" in m for m in gaps), gaps


# --- the repair -----------------------------------------------------------------------------------------------


def test_repair_keeps_every_lane_border_and_joins_the_geometries(inconsistent, tmp_path):
    path, true = inconsistent
    odr = load_opendrive(path)
    repaired, repairs = repair_geometry_lengths(odr)
    [repair] = repairs
    assert repair.action == GEOMETRY_LENGTH and repair.road == "1"
    assert repair.detail == ("3 paramPoly3 @length set to the curve's arc length (by up to +0.8567 m); "
                             "road @length 73.139393 -> 74.196132 m")
    geometries = repaired.roads[0].reference_line.geometries
    assert [g.length for g in geometries] == pytest.approx(true, abs=1e-9)
    assert [g.s for g in geometries] == pytest.approx(np.cumsum([0.0, *true[:-1]]), abs=1e-9)
    assert repaired.roads[0].length == pytest.approx(sum(true), abs=1e-9)
    # the arcLength curve keeps its shape: p now runs to the new @length, over the same points
    old, new = odr.roads[0].reference_line.geometries[2], geometries[2]
    for fraction in (0.0, 0.3, 1.0):
        p_old, p_new = fraction * old.length, fraction * new.length
        c_old = dict(zip(CURVE, old.params[:8]))
        c_new = dict(zip(CURVE, new.params[:8]))
        assert _poly(p_old, c_old) == pytest.approx(_poly(p_new, c_new), abs=1e-9)
    assert border_shift(odr, repaired) < 1e-9
    write_opendrive(repaired, tmp_path / "repaired.xodr")
    report = validate_file(tmp_path / "repaired.xodr")
    for rule in ("geometry.param-poly3-length", "geometry.gap", "geometry.length", "geometry.kink",
                 "geometry.border-jump", "geometry.elevation-jump"):
        assert not report.by_rule(rule), report.format_text()


def test_repair_moves_every_record_along_s(inconsistent):
    """Records inside the first curve stretch with it, later ones shift by what the curves before them grew;
    cubic records that vary across a joint where the stretch changes are cut there, constant ones are not."""
    path, true = inconsistent
    odr = load_opendrive(path)
    old, new = odr.roads[0], repair_geometry_lengths(odr)[0].roads[0]
    grow = true[0] / (true[0] - 0.3)  # inside geometry 0; geometry 1 (a line, old s 23.14..48.14) shifts by 0.3
    assert new.objects[0].s == pytest.approx(30.3, abs=1e-12)
    def in_geometry_2(s):  # old 48.14..63.14, the arcLength curve: 15 -> 15.857 m
        return 48.43939297200511 + (s - 48.13939297200511) * true[2] / 15.0

    repeat = new.objects[0].repeats[0]  # old s 10..50: from inside geometry 0 to inside geometry 2
    assert repeat.s == pytest.approx(10.0 * grow, abs=1e-12)
    assert repeat.length == pytest.approx(in_geometry_2(50.0) - 10.0 * grow, abs=1e-12)
    assert repeat.attrib["s"] == repr(repeat.s) and repeat.attrib["length"] == repr(repeat.length)
    assert new.lane_sections[1].s0 == pytest.approx(44.8, abs=1e-12)
    assert new.lane_sections[0].by_id[1].road_marks[0].s_offset == pytest.approx(12.5 * grow, abs=1e-12)
    assert new.signals[0].s == pytest.approx(in_geometry_2(60.0), abs=1e-12)
    # lane 1's varying width spans geometries 0 and 1 of section 0 (s 0..44.5): cut at their joint
    assert len(new.lane_sections[0].by_id[1].widths) == 2
    # lane -1: a constant record (not cut) and a varying one from s=18 across the same joint
    assert len(new.lane_sections[0].by_id[-1].widths) == 3
    # section 1 (old 44.5 to the road's end) crosses the joints 1|2 and 2|3; the elevation record from 0 to 50
    # the joints 0|1 and 1|2, its constant one from 50 none; laneOffset and superelevation all three
    assert len(new.lane_sections[1].by_id[-1].widths) == 3
    assert len(new.elevation) == 4 and len(old.elevation) == 2
    assert len(new.lane_offset) == len(new.superelevation) == 4
    stated = [true[0] - 0.3, 25.0, 15.0, 10.0]
    assert old.length == pytest.approx(sum(stated), abs=1e-12) and new.length == pytest.approx(sum(true), abs=1e-9)


def test_repair_is_idempotent_and_leaves_consistent_files_alone(inconsistent, tmp_path, shared):
    path, _ = inconsistent
    repaired, _ = repair_geometry_lengths(load_opendrive(path))
    write_opendrive(repaired, tmp_path / "once.xodr")
    again = load_opendrive(tmp_path / "once.xodr")
    twice, repairs = repair_geometry_lengths(again)
    assert repairs == [] and twice is again
    assert to_xml(twice) == (tmp_path / "once.xodr").read_bytes()
    # CARLA's Town07 (libOpenDRIVE test.xodr): paramPoly3 lengths right to 1 micrometre, nothing to do
    town = load_opendrive(shared("xodr", "libopendrive", "test.xodr"))
    assert repair_geometry_lengths(town) == (town, [])


def test_true_lengths_are_exact(inconsistent):
    """The arc length of every geometry, against scipy's adaptive quadrature (independent), to 1e-9 m."""
    path, true = inconsistent
    table = load_opendrive(path).arrays.geometries
    assert true_lengths(table) == pytest.approx(true, abs=1e-9)
    assert table.kind.tolist() == [GeometryKind.PARAM_POLY3, GeometryKind.LINE, GeometryKind.PARAM_POLY3,
                                   GeometryKind.PARAM_POLY3]


# --- netconvert's own output ----------------------------------------------------------------------------------


@pytest.mark.slow
def test_netconvert_tavf_repair_keeps_borders_within_a_millimetre(tavf_xodr, tmp_path):
    """DLR's TAVF network through netconvert: every lane border of every repaired road within 1 mm of where it
    was (measured: 1e-12 m), arc lengths exact (scipy), and repairing the written file changes nothing."""
    from scipy.integrate import quad

    raw = load_opendrive(tavf_xodr)
    repaired, repairs = repair_geometry_lengths(raw)
    assert len(repairs) > 500 and {r.action for r in repairs} == {GEOMETRY_LENGTH}
    assert border_shift(raw, repaired) < 1e-3
    table = raw.arrays.geometries
    arc = true_lengths(table)
    rows = np.flatnonzero(table.kind == int(GeometryKind.PARAM_POLY3))
    worst = np.argsort(table.length[rows] - arc[rows])[:20]  # the curves netconvert made shortest
    for k in rows[worst]:
        params = table.params[k]
        speed = lambda p: math.hypot(params[1] + 2 * params[2] * p + 3 * params[3] * p * p,  # noqa: E731
                                     params[5] + 2 * params[6] * p + 3 * params[7] * p * p)
        assert arc[k] == pytest.approx(quad(speed, 0.0, 1.0, epsabs=1e-12, limit=200)[0], abs=1e-7)
    write_opendrive(repaired, tmp_path / "tavf.xodr")
    again = load_opendrive(tmp_path / "tavf.xodr")
    assert repair_geometry_lengths(again)[1] == []


def _build(*args):
    from tavf_mapkit.cli.main import cli

    result = CliRunner().invoke(cli, ["build", *args], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result


def test_no_repair_keeps_netconvert_file_and_a_build_repairs_it(tmp_path):
    """``--no-repair`` keeps netconvert's OpenDRIVE byte for byte (its s read as arc length leaves gaps); the
    same build without it rewrites the file with every @length the arc length, and says so in its facts."""
    from pathlib import Path

    pipeline = tmp_path / "upto.toml"
    pipeline.write_text('[pipeline]\nstages = ["extract", "netconvert", "opendrive"]\n')
    source = Path(__file__).resolve().parents[1] / REPO_SAMPLE
    out = tmp_path / "sample"

    def stage(manifest, name):
        return next(record for record in manifest["stages"] if record["name"] == name)

    _build(str(source), "-o", str(out), "--pipeline", str(pipeline), "--no-repair", "-q")
    manifest = json.loads((out / "manifest.json").read_text())
    opendrive = stage(manifest, "opendrive")
    assert opendrive["options"] == {"repair": False} and opendrive["facts"]["repair"] is False
    assert manifest["artifacts"]["xodr"]["stage"] == "opendrive"
    assert manifest["artifacts"]["xodr"]["sha256"] == stage(manifest, "netconvert")["outputs"]["xodr"]["sha256"]
    assert (out / "sample.xodr").read_bytes() == (out / "netconvert" / "sample.xodr").read_bytes()
    raw = validate_file(out / "sample.xodr")
    assert raw.by_rule("geometry.param-poly3-length") or raw.by_rule("geometry.gap")

    _build(str(source), "-o", str(out), "--pipeline", str(pipeline), "-q")
    manifest = json.loads((out / "manifest.json").read_text())
    opendrive = stage(manifest, "opendrive")
    assert opendrive["options"] == {"repair": True, "curves": "arcs"} and "repair" not in opendrive["facts"]
    assert opendrive["facts"]["repairs"][GEOMETRY_LENGTH]["count"] > 0
    assert manifest["artifacts"]["xodr"]["stage"] == "opendrive"
    repaired = validate_file(out / "sample.xodr")
    assert not repaired.by_rule("geometry.param-poly3-length") and not repaired.by_rule("geometry.gap")
    assert repair_geometry_lengths(load_opendrive(out / "sample.xodr"))[1] == []


def test_what_lies_where_the_stretch_moves_nothing_is_not_moved():
    """SMap.fixed: every s at or before it maps to itself, and a profile that _unmoved_profile passes over comes
    back from _mapped_profile unchanged (the repair takes such records over without asking the map), on stretch
    maps (roads in s order) with gaps, overlaps and zero-length geometries, and profiles constant or not, before and across it."""
    from tavf_mapkit.opendrive.cubic import CubicProfile
    from tavf_mapkit.opendrive.repair_lengths import _mapped_profile, _stretch_map, _unmoved_profile

    rng = np.random.default_rng(7)
    fixed_seen, unmoved_seen = set(), 0
    for _ in range(400):
        n = int(rng.integers(1, 5))
        lengths = rng.choice([0.0, 0.1, 3.3, 10.0], n) * rng.random(n) + rng.choice([0.0, 1.0], n)
        steps = np.maximum(lengths[:-1] + rng.choice([0.0, 0.0, 1e-9, -0.05], n - 1), 0.0)  # in s order
        starts = np.cumsum(np.r_[rng.choice([0.0, 2.5]), steps])
        wrong = rng.random(n) < 0.5
        arc = np.where(wrong, lengths * rng.uniform(0.9, 1.1, n), lengths)
        mapping = _stretch_map(starts.tolist(), lengths.tolist(), arc, wrong & (lengths > 0))
        fixed = mapping.fixed
        fixed_seen.add("inf" if fixed == np.inf else "finite" if np.isfinite(fixed) else "none")
        probes = np.r_[np.asarray(mapping.old), np.asarray(mapping.old) - 1e-7, rng.uniform(-1, 40, 20)]
        for s in probes[probes <= fixed].tolist():
            assert mapping.at(s) == s, (s, mapping)
        s0 = np.sort(rng.choice(np.r_[0.0, starts, rng.uniform(0, 30, 3)], int(rng.integers(1, 4))))
        coefficients = rng.normal(size=(len(s0), 4)) * (rng.random((len(s0), 1)) < 0.5) * [1, 1, 1, 1]
        coefficients[:, 0] = rng.normal(size=len(s0))
        profile = CubicProfile(s0, coefficients)
        end = float(starts[-1] + lengths[-1])
        if _unmoved_profile(profile, end, fixed):
            unmoved_seen += 1
            assert _mapped_profile(profile, mapping, end) is profile, (profile, mapping)
    assert {"inf", "finite"} <= fixed_seen and unmoved_seen > 50
