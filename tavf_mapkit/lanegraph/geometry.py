"""Lane centre lines: lengths and end points of every lane of the map at once, and one lane's polyline."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.opendrive.borders import border_offsets
from tavf_mapkit.opendrive.sampling import sample_lanes_at, section_chunks, section_samples

#: lane samples evaluated at once. The sampler's temporaries cost ~400 bytes a sample (the budget's
#: MAX_POINTS is about that), what the table keeps 28 (row, s, x, y): sampled in chunks, a region's lane graph
#: costs memory by its samples' few bytes (Columbus: 7.3 million samples at 1 m), not by the sampler's.
CHUNK_SAMPLES = 500_000
#: samples of the map's reference lines a lane table takes in all (refused beyond, like an absurd step): 25
#: million at 1 m is 25,000 km of road, 3.4 times Columbus's 7.3 million; kept, 28 bytes a lane sample
MAX_TABLE_SAMPLES = 25_000_000


@dataclass(frozen=True, eq=False)
class LaneTable:
    """Per row of ``odr.arrays``' lane table (in s direction): centre-line length, first and last point, plan-view
    bounding box of the centre line; and the centre-line samples of the kept rows (row, s, plan-view point),
    sorted by row then s (None when built with ``keep_samples=False``: see ``lane_samples``)."""

    length: np.ndarray
    first: np.ndarray  # (n, 3) centre point at the section start
    last: np.ndarray   # (n, 3) centre point at the section end
    sample_row: np.ndarray | None  # int32
    sample_s: np.ndarray | None
    sample_xy: np.ndarray | None  # (m, 2), no lane height
    box: np.ndarray | None = None  # (n, 4) x min, y min, x max, y max of the centre samples (NaN: none)

    @staticmethod
    def build(odr, step: float = 1.0, keep: np.ndarray | None = None,
              chunk_samples: int = CHUNK_SAMPLES, keep_samples: bool = True) -> LaneTable:
        """``keep``: a mask of lane-table rows whose samples the table keeps (default all); lengths and end
        points are those of every row. Chunks of whole lane sections in map order give the same numbers, to
        the bit, as sampling the whole map at once (every number is a lane's own). ``keep_samples=False``: no
        samples are kept (a region's are 28 bytes each, 204 MB on Columbus), only each row's bounding box."""
        arrays = odr.arrays
        n = len(arrays.lane_id)
        keep = np.ones(n, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
        length = np.zeros(n)
        first = np.zeros((n, 3))
        last = np.zeros((n, 3))
        box = np.full((n, 4), np.nan)
        has = np.zeros(n, dtype=bool)
        kept_rows, kept_s, kept_xy = [], [], []
        for rows, s, centre in _sampled_chunks(odr, step, chunk_samples):
            low = int(rows[0])  # rows come out ascending: lane by lane, sections in map order
            lanes = np.arange(low, int(rows[-1]) + 1)
            segment = np.linalg.norm(np.diff(centre, axis=0), axis=1)
            same_lane = rows[1:] == rows[:-1]
            length[lanes] = np.bincount(rows[1:][same_lane] - low, weights=segment[same_lane],
                                        minlength=len(lanes))
            begin = np.searchsorted(rows, lanes, side="left")
            end = np.searchsorted(rows, lanes, side="right") - 1
            sampled = end >= begin
            first[lanes[sampled]] = centre[begin[sampled]]
            last[lanes[sampled]] = centre[end[sampled]]
            has[lanes[sampled]] = True
            starts = begin[sampled]
            for column, (reduce, axis) in enumerate(((np.minimum, 0), (np.minimum, 1), (np.maximum, 0),
                                                      (np.maximum, 1))):
                box[lanes[sampled], column] = reduce.reduceat(centre[:, axis], starts)
            if keep_samples:
                wanted = keep[rows]
                kept_rows.append(rows[wanted].astype(np.int32))
                kept_s.append(s[wanted])
                kept_xy.append(centre[wanted, :2])
            del centre, segment
        if not np.all(has):  # zero-length lane sections get no samples: evaluate their single point
            missing = np.flatnonzero(~has)
            s = arrays.section_s0[arrays.lane_section[missing]]
            first[missing] = last[missing] = centre_points(odr, missing, s)
        if not keep_samples:
            return LaneTable(length, first, last, None, None, None, box)
        # one column at a time, each chunk list let go once joined: a region's samples are held twice over
        # only one column at a time (Columbus: the points, 117 MB, not all three columns, 204 MB)
        sample_row = _joined(kept_rows, np.zeros(0, dtype=np.int32))
        sample_s = _joined(kept_s, np.zeros(0))
        sample_xy = _joined(kept_xy, np.zeros((0, 2)))
        return LaneTable(length, first, last, sample_row, sample_s, sample_xy, box)


def lane_samples(odr, step: float, rows: np.ndarray, chunk_samples: int = CHUNK_SAMPLES):
    """(row int32, s, plan-view point) of the centre-line samples of lane-table rows ``rows`` (a mask), sorted
    by row then s: exactly those ``LaneTable.build(odr, step, keep=rows)`` keeps, sampling only the lane
    sections of those rows."""
    arrays = odr.arrays
    rows = np.asarray(rows, dtype=bool)
    wanted_sections = np.zeros(len(arrays.section_s0), dtype=bool)
    wanted_sections[arrays.lane_section[rows]] = True
    kept_rows, kept_s, kept_xy = [], [], []
    for row, s, centre in _sampled_chunks(odr, step, chunk_samples, wanted_sections):
        wanted = rows[row]
        kept_rows.append(row[wanted].astype(np.int32))
        kept_s.append(s[wanted])
        kept_xy.append(centre[wanted, :2])
    return (_joined(kept_rows, np.zeros(0, dtype=np.int32)), _joined(kept_s, np.zeros(0)),
            _joined(kept_xy, np.zeros((0, 2))))


def _sampled_chunks(odr, step: float, chunk_samples: int, sections: np.ndarray | None = None):
    """(lane row, s, centre point (m, 3)) of every lane sample at ``step``, a chunk of whole lane sections at a
    time (only the sections in the mask ``sections`` when given), rows ascending."""
    arrays = odr.arrays
    # a chunk may overshoot its bound by one section: half the map's ceiling keeps it within that
    chunk_samples = min(chunk_samples, arrays.budget.max_points // 2)
    for chunk in section_chunks(arrays, step, chunk_samples, MAX_TABLE_SAMPLES):
        if sections is not None:
            chunk = chunk[sections[chunk]]
            if not len(chunk):
                continue
        sampling = sample_lanes_at(odr, *section_samples(arrays, step, True, chunk))
        rows = sampling.pair_lane
        if not len(rows):
            continue
        yield rows, sampling.s, sampling.center_points(with_height=False)
        del sampling


def _joined(parts: list, empty: np.ndarray) -> np.ndarray:
    """The parts concatenated, the list emptied (its arrays freed as soon as the joined copy exists)."""
    joined = np.concatenate(parts) if parts else empty
    parts.clear()
    return joined


def centre_points(odr, lane_rows: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(n, 3) lane-centre points of lane-table rows at road coordinates s (no lane height)."""
    from tavf_mapkit.opendrive.surface import surface_points

    arrays = odr.arrays
    lane_rows = np.asarray(lane_rows)
    s = np.asarray(s, dtype=float)
    road = arrays.section_road[arrays.lane_section[lane_rows]]
    t_inner, t_outer = border_offsets(arrays, lane_rows, s)
    x, y, z, heading, slope, roll, _ = arrays.reference(road, s)
    return surface_points(x, y, z, heading, slope, roll, 0.5 * (t_inner + t_outer), None)


def section_centre_lines(odr, rows: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre lines of lane-table rows ``rows`` in s direction, each sampled at its section's
    ``sections_s_values``: (points (n, 3) without lane height, s (n,), points per row), row after row in the
    order given. ``centre_points`` of every row at those s, to the bit, but the reference line and its surface
    frame are evaluated once per section sample, not once per lane (the lanes of a section share their s), and
    every border once (a lane's inner border is its inner neighbour's outer one, ``border_offsets``' pairs)."""
    from tavf_mapkit.opendrive.surface import surface_frame

    arrays = odr.arrays
    rows = np.asarray(rows, dtype=np.int64)
    if not len(rows):
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    rank = arrays.lane_rank[rows]
    # the rows asked for and their inner neighbours (the rows of a side run outwards: the inner one is row - 1)
    needed = np.unique(np.concatenate([rows[rank >= r] - r for r in range(int(rank.max()) + 1)]))
    sections, position = np.unique(arrays.lane_section[needed], return_inverse=True)
    s, counts = sections_s_values(arrays.section_s0[sections], arrays.section_end[sections], step)
    section_first = np.cumsum(counts) - counts
    x, y, z, heading, slope, roll, _ = arrays.reference(np.repeat(arrays.section_road[sections], counts), s)
    e_t, _ = surface_frame(heading, slope, roll)
    base = np.column_stack([x, y, z])
    # (lane, sample) pairs of the needed rows, lane by lane
    lane_counts = counts[position]
    lane_first = np.cumsum(lane_counts) - lane_counts
    within = np.arange(int(lane_counts.sum())) - np.repeat(lane_first, lane_counts)
    pair_sample = np.repeat(section_first[position], lane_counts) + within
    inner = np.searchsorted(needed, needed - 1)  # the inner neighbour's place (used for rank > 0 only)
    inner_pair = np.repeat(lane_first[np.minimum(inner, len(needed) - 1)], lane_counts) + within
    pair_lane = np.repeat(needed, lane_counts)
    t_inner, t_outer = border_offsets(arrays, pair_lane, s[pair_sample], inner_pair)
    # the pairs of the rows asked for, in their order
    place = np.searchsorted(needed, rows)
    wanted_counts = lane_counts[place]
    wanted_first = np.cumsum(wanted_counts) - wanted_counts
    pairs = np.repeat(lane_first[place] - wanted_first, wanted_counts) + np.arange(int(wanted_counts.sum()))
    sample = pair_sample[pairs]
    t = 0.5 * (t_inner[pairs] + t_outer[pairs])
    return base[sample] + t[:, None] * e_t[sample], s[sample], wanted_counts


def section_s_values(s0: float, s1: float, step: float) -> np.ndarray:
    """Evenly spaced s from s0 to s1 inclusive, no further apart than step (at least the two ends)."""
    if s1 - s0 <= 0:
        return np.array([s0])
    count = max(int(np.ceil((s1 - s0) / step - 1e-9)), 1)
    return np.linspace(s0, s1, count + 1)


def sections_s_values(s0: np.ndarray, s1: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """``section_s_values`` of many sections at once: (every section's values, one after the other; how many
    each has). The same bits as ``np.linspace`` gives one section (k * ((s1 - s0) / count) + s0, the last
    one s1); a step that underflows to 0 is left to ``section_s_values``."""
    s0, s1 = np.asarray(s0, dtype=float), np.asarray(s1, dtype=float)
    delta = s1 - s0
    positive = delta > 0
    count = np.ones(len(s0), dtype=np.int64)
    with np.errstate(invalid="ignore"):
        count[positive] = np.maximum(np.ceil(delta[positive] / step - 1e-9), 1).astype(np.int64)
    points = np.where(positive, count + 1, 1)
    owner = np.repeat(np.arange(len(s0)), points)
    k = (np.arange(len(owner)) - np.repeat(np.cumsum(points) - points, points)).astype(float)
    spacing = np.where(positive, delta / count, 0.0)
    values = k * spacing[owner] + s0[owner]
    ends = np.cumsum(points) - 1
    values[ends[positive]] = s1[positive]
    for i in np.flatnonzero(positive & (spacing == 0)).tolist():  # a denormal step: linspace's own branch
        values[ends[i] - count[i]:ends[i] + 1] = section_s_values(float(s0[i]), float(s1[i]), step)
    return values, points
