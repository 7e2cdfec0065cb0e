"""Sample every lane of every road at a step in s, vectorised across the whole map.

This is the engine behind ``mapkit export``, the accuracy checks and the benchmarks: per lane section the
samples are s0, s0+step, ... (and the section end itself when ``include_end``), and for every side lane the
inner and outer border offsets t, evaluated in one pass over all roads.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tavf_mapkit.opendrive.borders import border_offsets
from tavf_mapkit.opendrive.surface import surface_frame


@dataclass(frozen=True, eq=False)
class LaneSampling:
    """Per sample (section, s) the reference frame; per (lane, sample) pair the lane's border offsets."""

    odr: object
    # per sample
    sample_section: np.ndarray
    sample_s: np.ndarray
    ref_x: np.ndarray
    ref_y: np.ndarray
    ref_z: np.ndarray
    heading: np.ndarray
    slope: np.ndarray
    superelevation: np.ndarray
    lane_offset: np.ndarray
    # per pair
    pair_lane: np.ndarray  # row of NetworkArrays' lane table
    pair_sample: np.ndarray
    t_inner: np.ndarray
    t_outer: np.ndarray

    @cached_property
    def _frame(self):
        return surface_frame(self.heading, self.slope, self.superelevation)

    @property
    def arrays(self):
        return self.odr.arrays

    @cached_property
    def road_index(self) -> np.ndarray:
        return self.arrays.section_road[self.arrays.lane_section[self.pair_lane]]

    @cached_property
    def section_index(self) -> np.ndarray:
        return self.arrays.lane_section[self.pair_lane]

    @cached_property
    def lane_id(self) -> np.ndarray:
        return self.arrays.lane_id[self.pair_lane]

    @cached_property
    def lane_type(self) -> np.ndarray:
        return self.arrays.lane_type[self.pair_lane]

    @cached_property
    def s(self) -> np.ndarray:
        return self.sample_s[self.pair_sample]

    @cached_property
    def section_s0(self) -> np.ndarray:
        return self.arrays.section_s0[self.section_index]

    def points_at(self, t: np.ndarray, h: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) surface points of every pair at lateral offsets t (and heights h)."""
        e_t, e_h = self._frame
        i = self.pair_sample
        points = np.column_stack([self.ref_x[i], self.ref_y[i], self.ref_z[i]]) + t[:, None] * e_t[i]
        if h is not None:
            points += h[:, None] * e_h[i]
        return points

    def heights(self) -> tuple[np.ndarray, np.ndarray]:
        """Lane height (inner, outer) of every pair (0 where a lane has no height record)."""
        lane, s = self.pair_lane, self.s
        return self.arrays.lane_height_inner.evaluate(lane, s), self.arrays.lane_height_outer.evaluate(lane, s)

    def outer_border_points(self) -> np.ndarray:
        """Outer border, no lane height applied (the convention of the reference evaluations)."""
        return self.points_at(self.t_outer)

    def center_points(self, with_height: bool = True) -> np.ndarray:
        """Lane centre line; with the lane height (mean of inner and outer) by default, as the surface is."""
        t = 0.5 * (self.t_inner + self.t_outer)
        if not with_height:
            return self.points_at(t)
        inner, outer = self.heights()
        return self.points_at(t, 0.5 * (inner + outer))


def section_samples(arrays, step: float, include_end: bool = True, sections: np.ndarray | None = None):
    """(sample_section, sample_s) sorted by section then s; zero-length sections get no samples."""
    if step <= 0 or not np.isfinite(step):
        raise ValueError("step must be a positive number")
    all_sections = np.arange(len(arrays.section_s0)) if sections is None else np.asarray(sections)
    s0 = arrays.section_s0[all_sections]
    end = arrays.section_end[all_sections]
    keep = end - s0 > 0
    all_sections, s0, end = all_sections[keep], s0[keep], end[keep]
    counts = np.floor((end - s0) / step + 1e-9) + 1
    arrays.budget.check(arrays.section_road[all_sections], counts, f"sampling every {step:g} m")
    counts = counts.astype(np.int64)
    starts = np.cumsum(counts) - counts
    total = int(counts.sum())
    k = np.arange(total) - np.repeat(starts, counts)
    section = np.repeat(all_sections, counts)
    s = np.repeat(s0, counts) + k * step
    if include_end:
        last = s0 + (counts - 1) * step
        needs_end = end - last > 1e-9
        section = np.concatenate([section, all_sections[needs_end]])
        s = np.concatenate([s, end[needs_end]])
        order = np.lexsort((s, section))
        section, s = section[order], s[order]
    return section, s


def section_chunks(arrays, step: float, chunk_points: int, max_points: float | None = None):
    """Runs of consecutive lane sections of positive length (in map order) holding about ``chunk_points`` lane
    samples each, to sample a map in bounded parts (a run ends where the bound is reached; a section bigger
    than the bound is a run of its own). The whole map's samples are refused first, as ``section_samples``
    refuses them in one go (implausible roads, an absurd step), so chunks never hide a hostile number:
    against ``max_points`` when given (a caller that keeps only a few bytes of each sample), else against
    the map's budget of one allocation."""
    if step <= 0 or not np.isfinite(step):
        raise ValueError("step must be a positive number")
    sections = np.flatnonzero(arrays.section_end - arrays.section_s0 > 0)
    if not len(sections):
        return
    length = arrays.section_end[sections] - arrays.section_s0[sections]
    arrays.budget.check(arrays.section_road[sections], np.floor(length / step + 1e-9) + 1,
                        f"sampling every {step:g} m", max_points)
    lanes = np.bincount(arrays.lane_section, minlength=len(arrays.section_s0))[sections]
    points = (np.floor(length / step + 1e-9) + 2) * np.maximum(lanes, 1)  # + 1 for a section's end
    chunk = (np.cumsum(points) // max(int(chunk_points), 1)).astype(np.int64)
    yield from np.split(sections, np.flatnonzero(np.diff(chunk)) + 1)


def sample_lanes(odr, step: float = 0.5, include_end: bool = True) -> LaneSampling:
    """Border offsets of every side lane of every lane section, sampled every ``step`` metres of s."""
    return sample_lanes_at(odr, *section_samples(odr.arrays, step, include_end))


def sample_lane_chunks(odr, step: float = 0.5, chunk_points: int = 500_000, include_end: bool = True):
    """``sample_lanes(odr, step, include_end)`` in parts: one LaneSampling per run of consecutive lane sections
    (``section_chunks``, about ``chunk_points`` lane samples each), in map order. Every number is the whole
    map's (each sample is evaluated on its own), so the parts' pairs, one after the other, are the whole
    sampling's; a map is refused as ``section_chunks`` refuses it."""
    for sections in section_chunks(odr.arrays, step, chunk_points):
        yield sample_sections(odr, step, sections, include_end)


def sample_sections(odr, step: float, sections: np.ndarray, include_end: bool = True) -> LaneSampling:
    """``sample_lanes`` of the given lane sections only (the same samples and numbers as the whole map's)."""
    return sample_lanes_at(odr, *section_samples(odr.arrays, step, include_end, sections))


def lane_pairs(arrays, sample_section: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lane, sample, inner neighbour's pair) of every (lane, sample) pair of samples grouped by section: lane by
    lane, inside a lane in sample order; the number of pairs is checked against the map's budget first.

    The work is that of the sections sampled, not of the map: the adaptive mesher asks a few times per batch
    for a handful of samples, and whole-map tables per call were most of a region's sampling time."""
    sample_section = np.asarray(sample_section, dtype=np.int64)
    # the sections sampled, each with its first sample (samples are grouped: the first occurrence starts the run)
    present, first, counts = np.unique(sample_section, return_index=True, return_counts=True)
    # lanes are rows ordered by section: each sampled section's lanes are one run of rows
    lane_start = np.searchsorted(arrays.lane_section, present, side="left")
    lanes_per_section = np.searchsorted(arrays.lane_section, present, side="right") - lane_start
    lane_of = np.repeat(np.arange(len(present)), lanes_per_section)  # sampled section of each lane below
    lanes = np.arange(len(lane_of)) - np.repeat(np.cumsum(lanes_per_section) - lanes_per_section,
                                                lanes_per_section) + np.repeat(lane_start, lanes_per_section)
    lane_counts = counts[lane_of]
    arrays.budget.check(arrays.section_road[arrays.lane_section[lanes]], lane_counts, "lane samples")
    pair_lane = np.repeat(lanes, lane_counts)
    within = np.arange(len(pair_lane)) - np.repeat(np.cumsum(lane_counts) - lane_counts, lane_counts)
    pair_sample = np.repeat(first[lane_of], lane_counts) + within
    # lanes of one side are consecutive rows: the inner neighbour's pair is one section-sample count earlier
    inner_pair = np.arange(len(pair_lane)) - np.repeat(lane_counts, lane_counts)
    return pair_lane, pair_sample, inner_pair


def sample_lanes_at(odr, sample_section: np.ndarray, sample_s: np.ndarray) -> LaneSampling:
    """Reference frame at each sample and border offsets of every side lane of its section.

    Samples must be grouped by section (all samples of a section contiguous, any order inside). Pairs come
    out lane by lane, and inside a lane in sample order.
    """
    arrays = odr.arrays
    sample_section = np.asarray(sample_section, dtype=np.int64)
    sample_s = np.asarray(sample_s, dtype=float)
    road = arrays.section_road[sample_section]
    x, y, z, heading, slope, superelevation = arrays.pose(road, sample_s)
    lane_offset = arrays.section_lane_offset(sample_section, sample_s)
    pair_lane, pair_sample, inner_pair = lane_pairs(arrays, sample_section)
    t_inner, t_outer = border_offsets(arrays, pair_lane, sample_s[pair_sample], inner_pair)
    return LaneSampling(odr, sample_section, sample_s, x, y, z, heading, slope, superelevation, lane_offset,
                        pair_lane, pair_sample, t_inner, t_outer)



@dataclass(frozen=True)
class BorderSamples:
    road: np.ndarray  # road index
    section_s0: np.ndarray
    lane: np.ndarray
    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray


def sample_lane_borders(odr, step: float = 0.5, include_end: bool = True) -> BorderSamples:
    """Outer border of every side lane, the contract of ``mapkit export --layer lane-border``."""
    sampling = sample_lanes(odr, step, include_end)
    points = sampling.outer_border_points()
    return BorderSamples(sampling.road_index, sampling.section_s0, sampling.lane_id, sampling.s,
                         points[:, 0], points[:, 1], points[:, 2])
