"""Redundant records: a <line> that continues the <line> before it, a cubic record (elevation, superelevation,
lane offset, lane width or border) that continues the polynomial of the record before it. ASAM's
performance.avoid_redundant_info; the build merges them (tavf_mapkit/opendrive/repair_redundant.py)."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive.geometry import GeometryKind
from tavf_mapkit.opendrive.repair_redundant import EQUATION_TOLERANCE, redundant_lines, redundant_records
from tavf_mapkit.validate.finding import WARNING, Hit
from tavf_mapkit.validate.registry import rule


@rule("geometry.redundant-record", WARNING, tolerance=EQUATION_TOLERANCE,
      summary="No record only repeats the one before it: consecutive <line> geometries of the same heading (within "
              "the tolerance, rad), and elevation, superelevation, lane offset, lane width or border records whose "
              "polynomial is the previous record's (every coefficient within the tolerance).",
      why="Such a record carries nothing, but every reader evaluates one more piece and a joint appears where there "
          "is none (ASAM: redundant elements should be avoided).")
def redundant_record(ctx, rule):
    tolerance = rule.tolerance
    lines_after_lines = _roads_with_consecutive_lines(ctx.odr.arrays.geometries)
    for road_index, road in enumerate(ctx.odr.roads):
        # only a road with a line after a line can have a redundant one: the others' geometries are not made
        geometries = road.reference_line.geometries if road_index in lines_after_lines else ()
        for k in redundant_lines(geometries, tolerance):
            yield Hit(f"line at s={geometries[k].s:g} continues the line before it (same heading)", road=road.id,
                      s=geometries[k].s, line=geometries[k].line)
        for name, label in (("elevation", "elevation"), ("superelevation", "superelevation"),
                            ("lane_offset", "lane offset")):
            profile = getattr(road, name)
            for k in redundant_records(profile, tolerance):
                s = float(profile.s0[k])
                yield Hit(f"{label} record at s={s:g} repeats the polynomial of the one before it", road=road.id,
                          s=s, line=road.line)
        for section in road.lane_sections:
            for lane in section.side_lanes:
                for label, profile in (("width", lane.widths), ("border", lane.borders)):
                    for k in redundant_records(profile, tolerance):
                        s = float(profile.s0[k])
                        yield Hit(f"lane {label} record at s={s:g} repeats the polynomial of the one before it",
                                  road=road.id, lane=lane.id, s=s, line=lane.line)


def _roads_with_consecutive_lines(table) -> set[int]:
    """Indices of the roads in whose geometry table (the map's, road by road) a line follows a line."""
    line = table.kind == int(GeometryKind.LINE)
    pair = (table.group[1:] == table.group[:-1]) & line[1:] & line[:-1]
    return set(np.unique(table.group[1:][pair]).tolist())
