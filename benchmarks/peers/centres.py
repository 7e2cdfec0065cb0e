"""CARLA's waypoints next to our lane centres at the same (road, lane section, lane, s).

    >>> agreement = centre_agreement(load_opendrive("map.xodr"), carla_map.waypoints("map.xodr", 2.0))
    >>> agreement.summary()         # waypoints, unmatched, median_m, p99_m, max_m, over_1cm, worst
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CentreAgreement:
    """Per waypoint the 3D distance to our lane centre at its (road, section, lane, s); nan where we have no
    such lane (``unmatched``)."""

    points: np.ndarray
    distance: np.ndarray
    #: per waypoint the distance of our centre from itself rounded to single precision: CARLA's locations are
    #: floats, so no reader that stores them can come closer (on a map 10 km across about 0.15 mm)
    float32_floor: np.ndarray | None = None

    @property
    def matched(self) -> np.ndarray:
        return np.isfinite(self.distance)

    def summary(self) -> dict:
        distance = self.distance[self.matched]
        stats = {"waypoints": len(self.points), "unmatched": int((~self.matched).sum())}
        if len(distance):
            stats.update(
                median_m=float(np.median(distance)),
                p99_m=float(np.percentile(distance, 99)),
                max_m=float(distance.max()),
                over_1cm=int((distance > 0.01).sum()),
            )
            if self.float32_floor is not None:
                stats["float32_median_m"] = float(np.median(self.float32_floor[self.matched]))
            worst = self.points[np.flatnonzero(self.matched)[np.argmax(distance)]]
            stats["worst"] = {"road": str(worst["road"]), "lane": int(worst["lane"]), "s": float(worst["s"])}
        return stats


def centre_agreement(odr, points: np.ndarray) -> CentreAgreement:
    """Our lane centres (no lane height, as CARLA) at each waypoint's road, lane section, lane and s."""
    from tavf_mapkit.opendrive.sampling import sample_lanes_at

    arrays = odr.arrays
    road_index = {road.id: i for i, road in enumerate(odr.roads)}
    road = np.array([road_index.get(str(r), -1) for r in points["road"]], dtype=np.int64)
    distance = np.full(len(points), np.nan)
    known = road >= 0
    # CARLA's section_id is the section's position in its road; our sections are stored road by road
    first = np.searchsorted(arrays.section_road, road[known])
    section = first + points["section"][known]
    valid = section < len(arrays.section_road)
    valid[valid] &= arrays.section_road[section[valid]] == road[known][valid]
    rows = np.flatnonzero(known)[valid]
    section = section[valid]
    order = np.argsort(section, kind="stable")  # sample_lanes_at wants the samples grouped by section
    rows, section = rows[order], section[order]
    sampling = sample_lanes_at(odr, section, points["s"][rows])
    pair_row = rows[sampling.pair_sample]
    chosen = np.flatnonzero(sampling.lane_id == points["lane"][pair_row])
    centre = sampling.center_points(with_height=False)[chosen]
    target = pair_row[chosen]
    theirs = np.column_stack([points["x"][target], points["y"][target], points["z"][target]])
    distance[target] = np.linalg.norm(centre - theirs, axis=1)
    floor = np.full(len(points), np.nan)
    floor[target] = np.linalg.norm(centre - centre.astype(np.float32).astype(np.float64), axis=1)
    return CentreAgreement(points, distance, floor)
