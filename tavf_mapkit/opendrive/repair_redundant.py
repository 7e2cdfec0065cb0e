"""Repair redundant records: consecutive <line> geometries that are one line, and cubic records that repeat the
record before them.

netconvert writes a straight edge whose shape has collinear inner points as one <line> per segment (the sample
build: 12 such pairs). Nothing is wrong with the road, but ASAM's quality checker (performance.avoid_redundant_info,
OpenDRIVE 1.7 on) warns about each pair, as it does about an elevation, superelevation, lane offset, lane width or
border record that only continues the polynomial of the record before it. The validator's
``geometry.redundant-record`` finds the same records (``redundant_lines``, ``redundant_records``).

The repair merges a run of lines whose headings agree within ASAM's tolerance (netconvert writes headings to 8
decimals: Milan's collinear lines differ by 1.4e-7 rad) into one line from the run's start to its end, when that
line passes within ``POSITION_TOLERANCE`` (10 micrometres) of every joint of the run, so no point of the reference
line moves by more than that; s is unchanged (the merged line ends where the run did). A record
that continues the one before it is dropped: the one before it now governs its range, with values equal within
``EQUATION_TOLERANCE``. A file with nothing redundant is returned unchanged, so the repair is idempotent.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tavf_mapkit.opendrive.cubic import CubicProfile
from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.refline import ReferenceLine
from tavf_mapkit.opendrive.repair import Repair

#: Repair.action of this repair
MERGED_RECORDS = "merged redundant records"

#: ASAM's tolerance: headings (rad) and polynomial coefficients this close are the same
EQUATION_TOLERANCE = 1e-6
#: lines are merged only when the merged line passes this close (m) to every joint of the lines it replaces
POSITION_TOLERANCE = 1e-5


def _heading_difference(a: float, b: float) -> float:
    return abs((a - b + np.pi) % (2.0 * np.pi) - np.pi)


def redundant_lines(geometries, tolerance: float = EQUATION_TOLERANCE) -> list[int]:
    """Indices k of geometries that are a <line> following a <line> of the same heading (ASAM's test: the
    heading alone; whether they also meet is geometry.gap's question)."""
    return [k for k in range(1, len(geometries))
            if geometries[k].kind == GeometryKind.LINE and geometries[k - 1].kind == GeometryKind.LINE
            and _heading_difference(geometries[k].hdg, geometries[k - 1].hdg) < tolerance]


def redundant_records(profile: CubicProfile, tolerance: float = EQUATION_TOLERANCE) -> np.ndarray:
    """Indices k of records whose polynomial is the one of record k-1 re-expanded about record k's start
    (every coefficient within ``tolerance``), in s order."""
    if len(profile) < 2:
        return np.zeros(0, dtype=np.int64)
    a, b, c, d = profile.coefficients[:-1].T
    ds = np.diff(profile.s0)
    continued = np.column_stack([a + ds * (b + ds * (c + ds * d)), b + ds * (2.0 * c + 3.0 * d * ds),
                                 c + 3.0 * d * ds, d])
    same = np.all(np.abs(continued - profile.coefficients[1:]) < tolerance, axis=1)
    return np.flatnonzero(same) + 1


def _without(profile: CubicProfile, drop: np.ndarray) -> CubicProfile:
    keep = np.ones(len(profile), dtype=bool)
    keep[drop] = False
    return replace(profile, s0=profile.s0[keep], coefficients=profile.coefficients[keep])


def _line_end(geometry) -> tuple[float, float]:
    return (geometry.x + geometry.length * np.cos(geometry.hdg), geometry.y + geometry.length * np.sin(geometry.hdg))


def _one_line(run: list):
    """The single line that replaces a run of lines, or None when it would move a point of the reference line by
    more than ``POSITION_TOLERANCE``. It starts where the run starts, runs to where the run ends (its heading the
    chord's, the first line's when all headings are equal) and keeps the run's s range."""
    first, last = run[0], run[-1]
    length = float(last.s + last.length - first.s)
    end_x, end_y = _line_end(last)
    hdg = first.hdg if all(g.hdg == first.hdg for g in run) else \
        float(first.hdg + np.arctan2(np.sin(np.arctan2(end_y - first.y, end_x - first.x) - first.hdg),
                                     np.cos(np.arctan2(end_y - first.y, end_x - first.x) - first.hdg)))
    merged = replace(first, hdg=hdg, length=length)
    cos, sin = np.cos(hdg), np.sin(hdg)
    for geometry in run:
        for s, (x, y) in ((geometry.s, (geometry.x, geometry.y)), (geometry.s + geometry.length, _line_end(geometry))):
            along = s - first.s
            if np.hypot(first.x + along * cos - x, first.y + along * sin - y) > POSITION_TOLERANCE:
                return None
    return merged


def _merged_lines(geometries) -> tuple[tuple, int]:
    """(geometries with runs of collinear lines merged, how many lines were merged away). A line joins the run
    before it when its heading is within ``EQUATION_TOLERANCE`` of the previous line's (ASAM's test), it starts
    within ``POSITION_TOLERANCE`` of where that one ends, and the run stays one line (``_one_line``)."""
    out, run = [], []

    def close():
        if run:
            out.append(_one_line(run) if len(run) > 1 else run[0])

    for geometry in geometries:
        before = run[-1] if run else None
        if (before is not None and geometry.kind == GeometryKind.LINE
                and _heading_difference(geometry.hdg, before.hdg) < EQUATION_TOLERANCE
                and np.hypot(*np.subtract(_line_end(before), (geometry.x, geometry.y))) <= POSITION_TOLERANCE
                and _one_line(run + [geometry]) is not None):
            run.append(geometry)
            continue
        close()
        run = [geometry] if geometry.kind == GeometryKind.LINE else []
        if not run:
            out.append(geometry)
    close()
    return tuple(out), len(geometries) - len(out)


def _dedup(profile: CubicProfile) -> tuple[CubicProfile, int]:
    drop = redundant_records(profile)
    return (profile, 0) if not len(drop) else (_without(profile, drop), len(drop))


def _near_line_pairs(line: ReferenceLine) -> bool:
    """Whether two consecutive lines of the reference line head alike within ten times ASAM's tolerance: where
    none do, ``_merged_lines`` merges nothing, and its Geometry per record is not made (after the curves became
    arcs, a region's roads have hundreds of thousands of records and hardly a pair of lines)."""
    rows = line.narrow
    if len(rows) < 2:
        return False
    is_line = rows[:, 5] == int(GeometryKind.LINE)
    turn = np.abs((rows[1:, 3] - rows[:-1, 3] + np.pi) % (2.0 * np.pi) - np.pi)
    return bool(np.any(is_line[1:] & is_line[:-1] & (turn < 10.0 * EQUATION_TOLERANCE)))


def near_line_roads(rows: np.ndarray, road: np.ndarray, n_roads: int) -> np.ndarray:
    """Per road, whether two of its consecutive rows are lines whose headings are near: only there can
    ``redundant_lines`` find any (asked of all roads' rows at once, not with a Geometry record per row)."""
    near = np.zeros(n_roads, dtype=bool)
    if len(rows) < 2:
        return near
    lines = rows[:, 5] == int(GeometryKind.LINE)
    pair = lines[1:] & lines[:-1] & (road[1:] == road[:-1])
    pair &= np.abs((rows[1:, 3] - rows[:-1, 3] + np.pi) % (2.0 * np.pi) - np.pi) < 10.0 * EQUATION_TOLERANCE
    near[road[1:][pair]] = True
    return near


#: roads whose rows are gathered at once to find near lines (``repair_redundant``)
ROADS_PER_BATCH = 8192


def _near_lines(roads) -> np.ndarray:
    """``near_line_roads`` of the roads' reference lines, in batches of roads (a copy of their rows each)."""
    near = np.zeros(len(roads), dtype=bool)
    for first in range(0, len(roads), ROADS_PER_BATCH):
        lines = [road.reference_line for road in roads[first:first + ROADS_PER_BATCH]]
        counts = [len(line) for line in lines]
        if sum(counts):
            rows = np.concatenate([line.narrow for line in lines if len(line)])
            near[first:first + len(lines)] = near_line_roads(rows, np.repeat(np.arange(len(lines)), counts),
                                                             len(lines))
    return near


def _single_records(road) -> bool:
    """Whether every cubic profile of the road has fewer than two records (no record can repeat another)."""
    if len(road.elevation) > 1 or len(road.superelevation) > 1 or len(road.lane_offset) > 1:
        return False
    return all(len(lane.widths) < 2 and len(lane.borders) < 2
               for section in road.lane_sections for lane in section.lanes)


def _repaired_road(road, near_lines: bool | None = None):
    """(road, {what: how many merged}) for one road; the very road when nothing is redundant. ``near_lines``:
    ``_near_line_pairs`` of its reference line, when known."""
    near = _near_line_pairs(road.reference_line) if near_lines is None else near_lines
    if not near and _single_records(road):  # nothing to merge: the road as it is, no profile looked into
        return road, {}
    counts: dict = {}
    changes: dict = {}
    if near:
        geometries, merged = _merged_lines(road.reference_line.geometries)
        if merged:
            counts["line geometries"] = merged
            changes["reference_line"] = ReferenceLine(geometries)
    for name, label in (("elevation", "elevation"), ("superelevation", "superelevation"),
                        ("lane_offset", "lane offset")):
        profile, dropped = _dedup(getattr(road, name))
        if dropped:
            counts[f"{label} records"] = dropped
            changes[name] = profile
    sections = []
    for section in road.lane_sections:
        lanes = []
        for lane in section.lanes:
            widths, dropped_widths = _dedup(lane.widths)
            borders, dropped_borders = _dedup(lane.borders)
            if dropped_widths or dropped_borders:
                lane = replace(lane, widths=widths, borders=borders)
                counts["lane width records"] = counts.get("lane width records", 0) + dropped_widths
                counts["lane border records"] = counts.get("lane border records", 0) + dropped_borders
            lanes.append(lane)
        changed = any(new is not old for new, old in zip(lanes, section.lanes))
        sections.append(replace(section, lanes=tuple(lanes)) if changed else section)
    if any(new is not old for new, old in zip(sections, road.lane_sections)):
        changes["lane_sections"] = tuple(sections)
    counts = {what: n for what, n in counts.items() if n}
    return (replace(road, **changes) if changes else road), counts


def repair_redundant(odr, near_lines: np.ndarray | None = None):
    """(map with redundant lines merged and redundant cubic records dropped, one Repair per road changed).
    ``near_lines``: per road whether its reference line has two consecutive lines of near headings
    (``_near_line_pairs``), when the caller has found that already; else it is found for all roads at once."""
    from tavf_mapkit.opendrive.network import OpenDriveMap

    roads, repairs = list(odr.roads), []
    if near_lines is None:
        near_lines = _near_lines(odr.roads)
    for index, road in enumerate(odr.roads):
        repaired, counts = _repaired_road(road, bool(near_lines[index]))
        if repaired is road:
            continue
        roads[index] = repaired
        what = ", ".join(f"{n} {label}" for label, n in counts.items())
        repairs.append(Repair(MERGED_RECORDS, road.id, road.line,
                              f"{what} merged into the record before (same line or polynomial)"))
    if not repairs:
        return odr, []
    return OpenDriveMap(odr.header, tuple(roads), odr.junctions, odr.controllers, odr.source, odr.warnings,
                        odr.extra_xml), repairs
