"""Lane sections: a fixed set of lanes over an s range; border offsets of every lane as functions of s."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tavf_mapkit.opendrive.lane import Lane


@dataclass(frozen=True, eq=False)
class LaneSection:
    s0: float
    lanes: tuple[Lane, ...]  # every lane including the centre lane 0, any order
    single_side: str | None = None
    line: int | None = field(default=None, compare=False)
    attrib: dict = field(default_factory=dict, compare=False)
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)

    @cached_property
    def by_id(self) -> dict[int, Lane]:
        return {lane.id: lane for lane in self.lanes}

    @cached_property
    def left(self) -> tuple[Lane, ...]:
        """Left lanes from the centre outwards (1, 2, ...)."""
        return tuple(sorted((lane for lane in self.lanes if lane.id > 0), key=lambda lane: lane.id))

    @cached_property
    def right(self) -> tuple[Lane, ...]:
        """Right lanes from the centre outwards (-1, -2, ...)."""
        return tuple(sorted((lane for lane in self.lanes if lane.id < 0), key=lambda lane: -lane.id))

    @property
    def side_lanes(self) -> tuple[Lane, ...]:
        return self.left + self.right

    def outer_borders(self, s: np.ndarray, lane_offset: np.ndarray) -> dict[int, np.ndarray]:
        """t of the outer border of every lane at each s; lane 0 maps to the lane offset (centre lane)."""
        s = np.asarray(s, dtype=float)
        out = {0: np.asarray(lane_offset, dtype=float)}
        for side, lanes in ((1, self.left), (-1, self.right)):
            t = out[0]
            for lane in lanes:
                if lane.uses_border:
                    t = lane.borders(s)
                else:
                    t = t + side * lane.widths(s)
                out[lane.id] = t
        return out
