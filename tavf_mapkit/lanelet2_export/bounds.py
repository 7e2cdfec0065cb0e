"""Lane borders as lanelet bounds: every border of a lane section sampled once, as one polyline in s direction
that the lanes on both sides of it share.

Border ids: lane-table row r -> r (the lane's outer border); the centre line (laneOffset) of section k ->
``n_lanes + k``. A lane's inner border is its inner neighbour's outer border (row r - 1: lanes of one side are
consecutive rows from the centre out), the centre line for the lanes next to it. The offsets come from
``sample_lanes_at``, i.e. from ``opendrive.borders.border_offsets``, on samples shared by every lane of a
section.

Heights: a border between two lanes lies on the lower of the two lane surfaces there (a raised sidewalk's
inner bound is the road-level foot of its curb), so road lanes keep their exact surface; the height step
across a border is kept as ``raise_`` and makes it a curbstone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.surface import surface_frame


@dataclass(frozen=True, eq=False)
class SectionBorders:
    points: np.ndarray  # (n, 3) local x, y, z of every sampled border point, border by border in s order
    start: np.ndarray  # per border id: index of its first point (-1 where the border is not sampled)
    count: np.ndarray  # per border id: number of points (0 where not sampled)
    raise_: np.ndarray  # per border id: largest height step between the lanes on its two sides (m)
    n_lanes: int
    border: np.ndarray  # per point: its border id
    tangent: np.ndarray  # per point: (n, 2) unit vector of the reference line's direction there

    def inner(self, rows: np.ndarray, arrays) -> np.ndarray:
        """Border id of the inner border of lane rows."""
        rows = np.asarray(rows, dtype=np.int64)
        return np.where(arrays.lane_rank[rows] == 0, self.n_lanes + arrays.lane_section[rows], rows - 1)

    def first(self, border: np.ndarray) -> np.ndarray:
        """Point index of each border's first point (at the section start)."""
        return self.start[border]

    def last(self, border: np.ndarray) -> np.ndarray:
        """Point index of each border's last point (at the section end)."""
        return self.start[border] + self.count[border] - 1


def outermost_rows(arrays) -> np.ndarray:
    """Per lane row: is it the outermost lane of its side of its section?"""
    n = len(arrays.lane_id)
    if not n:
        return np.zeros(0, dtype=bool)
    nxt = np.minimum(np.arange(1, n + 1), n - 1)
    continues = (
        (arrays.lane_section[nxt] == arrays.lane_section)
        & (np.sign(arrays.lane_id[nxt]) == np.sign(arrays.lane_id))
        & (arrays.lane_rank[nxt] == arrays.lane_rank + 1)
    )
    continues[n - 1] = False
    return ~continues


def sample_borders(odr, sampling, rows: np.ndarray) -> SectionBorders:
    """The inner and outer border of every lane row in ``rows``, on the samples of ``sampling``
    (``sample_lanes_at``: samples grouped by section, ascending s)."""
    return join_borders([border_part(odr, sampling, rows)], len(odr.arrays.lane_id))


@dataclass(frozen=True, eq=False)
class BorderPart:
    """``sample_borders`` of one part of the map's samples (whole lane sections): its lane borders' points,
    its centre lines' points, and per border id its point count and height step (zero outside the part)."""

    lane_points: np.ndarray
    lane_border: np.ndarray
    lane_heading: np.ndarray
    centre_points: np.ndarray
    centre_border: np.ndarray
    centre_heading: np.ndarray
    count: np.ndarray
    raise_: np.ndarray


def join_borders(parts: list[BorderPart], n_lanes: int) -> SectionBorders:
    """The parts (in map order) as one SectionBorders: every lane border's points, then every centre line's,
    as ``sample_borders`` of all their samples at once orders them."""
    count = np.sum([part.count for part in parts], axis=0).astype(np.int64)
    raise_ = np.max([part.raise_ for part in parts], axis=0)
    start = np.cumsum(count) - count
    start[count == 0] = -1
    heading = np.concatenate([part.lane_heading for part in parts] + [part.centre_heading for part in parts])
    return SectionBorders(
        np.concatenate([part.lane_points for part in parts] + [part.centre_points for part in parts]),
        start,
        count,
        raise_,
        n_lanes,
        np.concatenate([part.lane_border for part in parts] + [part.centre_border for part in parts]),
        np.column_stack([np.cos(heading), np.sin(heading)]),
    )


def border_part(odr, sampling, rows: np.ndarray) -> BorderPart:
    """The borders of lane rows ``rows`` on the samples of ``sampling``, which holds their whole sections."""
    arrays = odr.arrays
    n_lanes, n_sections = len(arrays.lane_id), len(arrays.section_s0)
    rows = np.asarray(rows, dtype=np.int64)
    lane = sampling.pair_lane
    n_pairs = len(lane)
    pairs = np.arange(n_pairs)
    per_section = np.bincount(sampling.sample_section, minlength=n_sections)

    # heights: the lower surface of the two lanes beside a border; the step between them
    h_in, h_out = sampling.heights()
    has_outer = ~outermost_rows(arrays)[lane]
    outer_pair = np.minimum(pairs + per_section[arrays.lane_section[lane]], max(n_pairs - 1, 0))
    h_next = np.where(has_outer, h_in[outer_pair] if n_pairs else h_in, 0.0)
    height = np.where(has_outer, np.minimum(h_out, h_next), h_out)
    step = np.abs(h_out - h_next)
    raise_ = np.zeros(n_lanes + n_sections)
    np.maximum.at(raise_, lane, step)
    # the centre line: a step where a lane next to it is raised at its inner edge
    centre_step = np.where(arrays.lane_rank[lane] == 0, np.abs(h_in), 0.0)
    np.maximum.at(raise_, n_lanes + arrays.lane_section[lane], centre_step)

    lane_needed = np.zeros(n_lanes, dtype=bool)
    centre_needed = np.zeros(n_sections, dtype=bool)
    lane_needed[rows] = True
    inner_rows = rows[arrays.lane_rank[rows] > 0] - 1
    lane_needed[inner_rows] = True
    centre_needed[arrays.lane_section[rows[arrays.lane_rank[rows] == 0]]] = True

    chosen = lane_needed[lane]
    outer_points = sampling.points_at(sampling.t_outer, height)[chosen]
    centre_samples = np.flatnonzero(centre_needed[sampling.sample_section])
    e_t, _ = surface_frame(
        sampling.heading[centre_samples],
        sampling.slope[centre_samples],
        sampling.superelevation[centre_samples],
    )
    centre_points = (
        np.column_stack([sampling.ref_x, sampling.ref_y, sampling.ref_z])[centre_samples]
        + sampling.lane_offset[centre_samples, None] * e_t
    )

    count = np.concatenate([per_section[arrays.lane_section] * lane_needed, per_section * centre_needed])
    return BorderPart(
        outer_points,
        lane[chosen],
        sampling.heading[sampling.pair_sample[chosen]],
        centre_points,
        n_lanes + sampling.sample_section[centre_samples],
        sampling.heading[centre_samples],
        count.astype(np.int64),
        raise_,
    )
