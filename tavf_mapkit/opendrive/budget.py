"""How much a map may make us allocate: every sampler and mesher asks here before it allocates.

Samplers allocate by length / step, meshers by area / cell, so one absurd number in a file (a road @length of
5e12 m, SUMO's invalid-position sentinel as a vertex) becomes an 11 GiB array or an out-of-memory kill. Two
checks, both before any allocation, both one line naming file, line and road:

1. Plausibility, from the map's real extent (the box of its geometry start points that are on Earth): a
   road may be at most ``WINDING`` times as long as the map is wide (a serpentine mountain road or a ring
   road is 3-5 times), but at least ``MIN_ROAD_LIMIT``; no vertex may lie off Earth.
2. A ceiling on the points one allocation may hold (``MAX_POINTS``), whatever the reason: a tiny step asked
   for on a big map, or many long but plausible roads.

Counts are passed as floats and compared before anything is converted to an integer, so 5e12 / 0.5 is a
clear refusal rather than an int64 overflow.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.plausibility import Extent, length_text, off_earth, vertex_problem

#: points one allocation may hold; a lane sample costs ~400 bytes through sampling and surface points,
#: so this keeps a single step of any command near 2 GB. The largest zoo map (Andorra, 858 km of road)
#: needs 2.0 million at 0.5 m, its adaptive mesh 0.7 million per pass.
MAX_POINTS = 5_000_000
#: a road may be this many times as long as the map's extent is wide
WINDING = 10.0
#: m; every map may have roads this long, however small its extent (a single straight road has none)
MIN_ROAD_LIMIT = 100_000.0


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
    def build(odr, table, lengths: np.ndarray, max_points: int = MAX_POINTS) -> SampleBudget:
        """From the map's roads, its flattened geometry table (``group`` = road index) and road lengths."""
        roads = odr.roads
        extent = Extent.around(table.x, table.y)
        road_limit = max(MIN_ROAD_LIMIT, WINDING * (extent.diagonal if extent else 0.0))
        problems: dict[int, tuple[int | None, str, str]] = {}
        bad = np.flatnonzero(off_earth(table.x, table.y))
        if len(bad):
            first_of_road = np.searchsorted(table.group, table.group[bad], side="left")
            for k, first in zip(bad.tolist(), first_of_road.tolist()):
                road = int(table.group[k])
                if road not in problems:
                    geometry = roads[road].reference_line.geometries[k - first]
                    problems[road] = (geometry.line, "geometry", vertex_problem(geometry.x, geometry.y))
        spans = f"spans {length_text(extent.diagonal)}" if extent else "has no vertex on Earth"
        for road in np.flatnonzero(~(np.asarray(lengths, dtype=float) <= road_limit)).tolist():
            if road not in problems:
                problems[road] = (roads[road].line, "road",
                                  f"@length={lengths[road]:.6g} m is implausible: the map's geometry {spans}, "
                                  f"so no road can be longer than {length_text(road_limit)}")
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

    def check(self, road_index, counts, what: str) -> None:
        """Refuse to allocate ``sum(counts)`` points of ``what`` (``counts[i]`` for road ``road_index[i]``).

        ``counts`` may be floats (even inf): nothing is converted before it has been compared.
        """
        road_index = np.asarray(road_index, dtype=np.int64)
        self.check_roads(road_index)
        counts = np.asarray(counts, dtype=float)
        total = float(counts.sum()) if counts.size else 0.0
        if total <= self.max_points:
            return
        per_road = np.bincount(road_index, weights=np.nan_to_num(counts, nan=np.inf, posinf=1e300),
                               minlength=len(self.road_ids))
        worst = int(np.argmax(per_road))
        raise self.refuse(worst, f"{what} would allocate {total:.3g} points, more than the budget of "
                                 f"{self.max_points:.3g} ({per_road[worst]:.3g} of them on this road)")

    def check_total(self, count: float, what: str, road: int) -> None:
        """Refuse one allocation of ``count`` points for ``what``, charged to road index ``road``."""
        self.check(np.array([road]), np.array([count], dtype=float), what)
