"""Reference frames at arbitrary (road, s) for the mesher. Lane borders at arbitrary samples come from
``opendrive.sampling.sample_lanes_at`` (grouped samples) and ``opendrive.locate.border_offsets`` (any rows)."""

from __future__ import annotations

import numpy as np


def reference_frames(odr, road: np.ndarray, s: np.ndarray):
    """Reference point (n, 3), frame vectors e_t, e_h (n, 3) and lane offset at (road index, s)."""
    from tavf_mapkit.opendrive.surface import surface_frame

    x, y, z, heading, slope, superelevation, lane_offset = odr.arrays.reference(road, s)
    e_t, e_h = surface_frame(heading, slope, superelevation)
    return np.column_stack([x, y, z]), e_t, e_h, lane_offset
