"""The inverse of evaluation: (x, y) -> nearest (road, lane section, lane, s, t), for map matching.

Candidates come from a KD-tree over lane-centre samples; each candidate's s is refined by Newton steps on its
road's reference line, t follows from the normal, and the lane whose borders contain t wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tavf_mapkit.opendrive.borders import border_offsets
from tavf_mapkit.opendrive.sampling import sample_lanes


@dataclass(frozen=True)
class Location:
    road_index: np.ndarray
    section_index: np.ndarray
    lane_id: np.ndarray
    s: np.ndarray
    t: np.ndarray
    distance: np.ndarray  # 0 inside the lane, else the lateral distance to it (m)


class LaneLocator:
    """Build once per map (a few hundred ms for a city district), then locate many points at once."""

    def __init__(self, odr, step: float = 1.0, lane_types: set[str] | None = None):
        self.odr = odr
        sampling = sample_lanes(odr, step)
        keep = np.ones(len(sampling.pair_lane), dtype=bool)
        if lane_types is not None:
            keep = np.isin(sampling.lane_type, list(lane_types))
        centre = sampling.center_points(with_height=False)[keep]
        self.lane_row = sampling.pair_lane[keep]
        self.s = sampling.s[keep]
        self.tree = cKDTree(centre[:, :2])

    @classmethod
    def from_samples(cls, odr, lane_row: np.ndarray, s: np.ndarray, xy: np.ndarray) -> LaneLocator:
        """A locator over lane-centre samples someone already has (lane-table row, road s, plan-view point;
        a lane graph's): the locator the constructor builds from the same samples, without sampling again."""
        locator = cls.__new__(cls)
        locator.odr, locator.lane_row, locator.s = odr, lane_row, s
        locator.tree = cKDTree(xy)
        return locator

    def locate(self, x, y, candidates: int = 8) -> Location:
        arrays = self.odr.arrays
        q = np.column_stack([np.atleast_1d(np.asarray(x, dtype=float)), np.atleast_1d(np.asarray(y, dtype=float))])
        k = min(candidates, len(self.s))
        _, index = self.tree.query(q, k=k)
        index = index.reshape(len(q), k)
        row = self.lane_row[index].ravel()
        s = self.s[index].ravel()
        qx, qy = np.repeat(q[:, 0], k), np.repeat(q[:, 1], k)
        section = arrays.lane_section[row]
        road = arrays.section_road[section]
        s0, s1 = arrays.section_s0[section], arrays.section_end[section]
        for _ in range(4):
            px, py, _, heading, _, _, _ = arrays.reference(road, s)
            s = np.clip(s + (qx - px) * np.cos(heading) + (qy - py) * np.sin(heading), s0, s1)
        px, py, _, heading, _, _, _ = arrays.reference(road, s)
        t = -(qx - px) * np.sin(heading) + (qy - py) * np.cos(heading)
        along = np.hypot(qx - px, qy - py) ** 2 - t ** 2  # squared distance beyond the section end
        t_inner, t_outer = border_offsets(arrays, row, s)
        low, high = np.minimum(t_inner, t_outer), np.maximum(t_inner, t_outer)
        lateral = np.maximum(np.maximum(low - t, t - high), 0.0)
        distance = np.sqrt(lateral ** 2 + np.maximum(along, 0.0))
        # prefer the containing lane, then the one whose centre is nearest
        score = (distance + 1e-6 * np.abs(t - 0.5 * (low + high))).reshape(len(q), k)
        best = np.argmin(score, axis=1) + np.arange(len(q)) * k
        return Location(road[best], section[best], arrays.lane_id[row[best]], s[best], t[best], distance[best])
