"""Lane borders of a peer next to ours at the same (road, section, lane, s): the one comparison of lane
borders, used by the reference test (tests/test_opendrive_reference.py), the oracle tests and the benchmarks.

Rows are the CSV format of ../shared/data/reference/lane_borders: ``road,section_s0,lane,s,x,y,z`` with s and
section_s0 printed to 6 decimals, so both sides are joined on keys rounded to the micrometre.
"""

from __future__ import annotations

import gzip
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BORDER_DTYPE = np.dtype(
    [
        ("road", "U64"),
        ("section_s0", "f8"),
        ("lane", "i4"),
        ("s", "f8"),
        ("x", "f8"),
        ("y", "f8"),
        ("z", "f8"),
    ]
)


def read_borders(source) -> np.ndarray:
    """Structured rows (``BORDER_DTYPE``) of a lane-border CSV: a path (``.csv``, ``.csv.gz``) or a stream."""
    if isinstance(source, (str, Path)) and str(source).endswith(".gz"):
        with gzip.open(source, "rt") as stream:
            return read_borders(stream)
    return np.loadtxt(source, delimiter=",", skiprows=1, dtype=BORDER_DTYPE, ndmin=1)


def _keys(road, section_s0, lane, s) -> np.ndarray:
    """(n, 4) integer keys: road index, section s0 in micrometres, lane, s in micrometres."""
    return np.column_stack(
        [road, np.rint(np.asarray(section_s0) * 1e6), lane, np.rint(np.asarray(s) * 1e6)]
    ).astype(np.int64)


def _codes(keys: np.ndarray) -> np.ndarray:
    """The same number for equal key rows (a lexsort, then a new number wherever a row differs from the one
    before)."""
    order = np.lexsort(keys.T[::-1])
    ordered = keys[order]
    new = np.ones(len(keys), dtype=bool)
    new[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    codes = np.empty(len(keys), dtype=np.int64)
    codes[order] = np.cumsum(new) - 1
    return codes


@dataclass(frozen=True)
class BorderAgreement:
    """Per row of the peer: the index of our sample at its key (-1: we have none), the 3D distance there."""

    rows: np.ndarray
    ours: object  # tavf_mapkit.opendrive.sampling.BorderSamples
    index: np.ndarray
    distance: np.ndarray  # per row; nan where unmatched
    ours_unmatched: int  # our samples at keys the peer has no row for

    @property
    def matched(self) -> np.ndarray:
        return self.index >= 0

    def summary(self) -> dict:
        distance = self.distance[self.matched]
        stats = {
            "rows": len(self.rows),
            "ours": len(self.ours.s),
            "matched": int(self.matched.sum()),
            "rows_unmatched": int((~self.matched).sum()),
            "ours_unmatched": self.ours_unmatched,
        }
        if len(distance):
            stats.update(
                median_m=float(np.median(distance)),
                p99_m=float(np.percentile(distance, 99)),
                max_m=float(distance.max()),
                over_1mm=int((distance > 1e-3).sum()),
            )
            worst = int(np.flatnonzero(self.matched)[np.argmax(distance)])
            row = self.rows[worst]
            stats["worst"] = {
                "road": str(row["road"]),
                "section_s0": float(row["section_s0"]),
                "lane": int(row["lane"]),
                "s": float(row["s"]),
            }
        return stats


def border_agreement(odr, rows: np.ndarray, step: float) -> BorderAgreement:
    """Our outer lane borders at ``step`` (the peer's sample set: s0 + k*step, no extra section end) joined
    with the peer's ``rows`` on (road id, section s0, lane, s)."""
    from tavf_mapkit.opendrive.sampling import sample_lane_borders

    ours = sample_lane_borders(odr, step, include_end=False)
    road_index = {road.id: i for i, road in enumerate(odr.roads)}
    row_roads, inverse = np.unique(rows["road"], return_inverse=True)
    row_road = np.array([road_index.get(str(road), -1) for road in row_roads], dtype=np.int64)[inverse]
    ours_keys = _keys(ours.road, ours.section_s0, ours.lane, ours.s)
    row_keys = _keys(row_road, rows["section_s0"], rows["lane"], rows["s"])
    # one vectorised join: codes of the union of keys, then per peer row the last of ours with the same code
    codes = _codes(np.concatenate([ours_keys, row_keys]))
    ours_codes, row_codes = codes[: len(ours_keys)], codes[len(ours_keys) :]
    position = np.full(len(codes), -1, dtype=np.int64)
    position[ours_codes] = np.arange(len(ours_keys))
    index = position[row_codes]
    ours_unmatched = int((~np.isin(ours_codes, row_codes)).sum())
    distance = np.full(len(rows), np.nan)
    found = index >= 0
    i = index[found]
    ours_xyz = np.column_stack([ours.x[i], ours.y[i], ours.z[i]])
    theirs = np.column_stack([rows["x"][found], rows["y"][found], rows["z"][found]])
    distance[found] = np.linalg.norm(ours_xyz - theirs, axis=1)
    return BorderAgreement(rows, ours, index, distance, ours_unmatched)
