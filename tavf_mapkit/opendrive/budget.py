"""How much a map may make us allocate: every sampler and mesher asks here before it allocates.

Samplers allocate by length / step, meshers by area / cell, so one absurd number in a file (a road @length of
5e12 m, SUMO's invalid-position sentinel as a vertex) becomes an 11 GiB array or an out-of-memory kill. Two
checks, both before any allocation, both one line naming file, line and road:

1. Plausibility, from the map's real extent (the box of its geometry start points that are on Earth): a
   road may be at most ``WINDING`` times as long as the map is wide (a serpentine mountain road or a ring
   road is 3-5 times), but at least ``MIN_ROAD_LIMIT``; no vertex may lie off Earth; no lane width, border
   or lane offset may reach ``LATERAL_LIMIT`` and no elevation ``ELEVATION_LIMIT`` (meshers allocate by
   area, and solid kernels refuse such coordinates). A road with such a number is never sampled.
2. A ceiling on the points one allocation may hold (``MAX_POINTS``), whatever the reason: a tiny step asked
   for on a big map, or many long but plausible roads.

Counts are passed as floats and compared before anything is converted to an integer, so 5e12 / 0.5 is a
clear refusal rather than an int64 overflow.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.cubic import cubic_largest_magnitude
from tavf_mapkit.opendrive.plausibility import Extent, length_text, off_earth, vertex_problem

#: points one allocation may hold; a lane sample costs ~400 bytes through sampling and surface points, so a
#: command stays below 2 GB (`mapkit export` of Andorra, 858 km of road: 3.9 million at 0.25 m, 1.86 GB peak;
#: 4.9 million at 0.2 m would take 2.24 GB). Andorra needs 2.0 million at 0.5 m, its adaptive mesh 0.7 million.
MAX_POINTS = 4_000_000
#: a road may be this many times as long as the map's extent is wide
WINDING = 10.0
#: m; every map may have roads this long, however small its extent (a single straight road has none)
MIN_ROAD_LIMIT = 100_000.0
#: m; no lane border lies this far from its road's reference line (a 20-lane motorway reaches 80 m)
LATERAL_LIMIT = 1_000.0
#: m; no road is this high or deep (the highest paved road is at 5.8 km), absolute altitudes included
ELEVATION_LIMIT = 100_000.0


@dataclass(frozen=True, eq=False)
class SampleBudget:
    """The allocation budget of one map; ``check`` raises InputError before a sampler goes over it."""

    source: str | None
    road_ids: tuple[str, ...]
    road_lines: tuple[int | None, ...]
    extent: Extent | None
    road_limit: float
    max_points: int = MAX_POINTS
    #: road index -> (line, element, message): why sampling that road is refused (first problem per road)
    problems: dict = field(default_factory=dict)

    @staticmethod
    def build(odr, arrays, max_points: int = MAX_POINTS) -> SampleBudget:
        """From the map and its flattened tables (``arrays``: NetworkArrays, without a budget yet)."""
        roads = odr.roads
        table, lengths = arrays.geometries, arrays.road_length
        extent = Extent.around(table.x, table.y)
        road_limit = max(MIN_ROAD_LIMIT, WINDING * (extent.diagonal if extent else 0.0))
        problems: dict[int, tuple[int | None, str, str]] = {}

        def note(road: int, line, element: str, message: str) -> None:
            problems.setdefault(road, (line, element, message))  # the first problem of a road is enough

        bad = np.flatnonzero(off_earth(table.x, table.y))
        if len(bad):
            first_of_road = np.searchsorted(table.group, table.group[bad], side="left")
            for k, first in zip(bad.tolist(), first_of_road.tolist()):
                line = int(roads[int(table.group[k])].reference_line.lines[k - first])
                note(int(table.group[k]), None if line < 0 else line, "geometry",
                     vertex_problem(float(table.x[k]), float(table.y[k])))
        spans = f"spans {length_text(extent.diagonal)}" if extent else "has no vertex on Earth"
        for road in np.flatnonzero(~(lengths <= road_limit)).tolist():
            note(road, roads[road].line, "road", f"@length={lengths[road]:.6g} m is implausible: the map's geometry "
                                                 f"{spans}, so no road can be longer than {length_text(road_limit)}")
        _note_profiles(odr, arrays, note)
        return SampleBudget(odr.source, tuple(road.id for road in roads), tuple(road.line for road in roads),
                            extent, road_limit, max_points, problems)

    def refuse(self, road: int, message: str, line: int | None = None, element: str | None = None) -> InputError:
        """The one-line error that names this map's file and a road (index into the map's roads)."""
        return InputError(message, file=self.source, line=line if line is not None else self.road_lines[road],
                          element=element, road=self.road_ids[road])

    def check_roads(self, road_index) -> None:
        """Refuse, before sampling them, roads whose numbers are implausible (the first such road)."""
        if not self.problems:
            return
        involved = np.unique(np.asarray(road_index, dtype=np.int64))
        bad = involved[np.isin(involved, np.fromiter(self.problems, dtype=np.int64))]
        if len(bad):
            line, element, message = self.problems[int(bad[0])]
            raise self.refuse(int(bad[0]), message, line, element)

    def check(self, road_index, counts, what: str, limit: float | None = None) -> None:
        """Refuse to allocate ``sum(counts)`` points of ``what`` (``counts[i]`` for road ``road_index[i]``).

        ``counts`` may be floats (even inf): nothing is converted before it has been compared. ``limit``: a
        ceiling other than ``max_points``, for points that are not one allocation (a sampler working in
        chunks keeps a few bytes of each point, not the evaluator's hundreds).
        """
        road_index = np.asarray(road_index, dtype=np.int64)
        self.check_roads(road_index)
        counts = np.asarray(counts, dtype=float)
        total = float(counts.sum()) if counts.size else 0.0
        limit = self.max_points if limit is None else limit
        if total <= limit:
            return
        per_road = np.bincount(road_index, weights=np.nan_to_num(counts, nan=np.inf, posinf=1e300),
                               minlength=len(self.road_ids))
        worst = int(np.argmax(per_road))
        raise self.refuse(worst, f"{what} would allocate {total:.3g} points, more than the budget of "
                                 f"{limit:.3g} ({per_road[worst]:.3g} of them on this road)")

    def check_total(self, count: float, what: str, road: int) -> None:
        """Refuse one allocation of ``count`` points for ``what``, charged to road index ``road``."""
        self.check(np.array([road]), np.array([count], dtype=float), what)


def _note_profiles(odr, arrays, note) -> None:
    """Lane widths, borders and lane offsets that reach beyond LATERAL_LIMIT, elevations beyond ELEVATION_LIMIT
    anywhere in their interval (exact extremes of each cubic record, not samples)."""
    road_end = arrays.road_length
    lane_end = arrays.section_end[arrays.lane_section]
    lane_road = arrays.section_road[arrays.lane_section]
    checks = (
        (arrays.lane_width, lane_end, lane_road, LATERAL_LIMIT, "lane", "width"),
        (arrays.lane_border, lane_end, lane_road, LATERAL_LIMIT, "lane", "border"),
        (arrays.lane_offset, road_end, None, LATERAL_LIMIT, "laneOffset", "lane offset"),
        (arrays.elevation, road_end, None, ELEVATION_LIMIT, "elevation", "elevation"),
    )
    lane_objects = None
    for records, group_end, road_of_group, limit, element, what in checks:
        if not len(records.s0):
            continue
        extreme = cubic_largest_magnitude(records.coefficients, np.maximum(records.intervals(group_end), 0.0))
        for k in np.flatnonzero(~(extreme <= limit)).tolist():
            group = int(records.group[k])
            if road_of_group is None:
                road, line, whose = group, odr.roads[group].line, ""
            else:
                if lane_objects is None:  # NetworkArrays' lane order: per section left lanes, then right lanes
                    lane_objects = [lane for road in odr.roads for section in road.lane_sections
                                    for lane in section.left + section.right]
                lane = lane_objects[group]
                road, line, whose = int(road_of_group[group]), lane.line, f"lane {lane.id} "
            s = float(records.s0[k])
            note(road, line, element, f"{whose}{what} reaches {extreme[k]:.3g} m in the record at s={s:g}; real roads "
                                      f"stay below {length_text(limit)}")
