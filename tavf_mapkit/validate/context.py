"""What the rule checks look at: the raw document (for line numbers, order and names) and the loaded map,
plus derived tables several rules share (road end points, lane rows), computed once."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class RoadEnds:
    """Position and outward heading of both ends of every road (index = road index in the map).

    The outward heading points away from the road (heading at the end, heading + pi at the start), so the ends
    of two correctly joined roads have outward headings that differ by pi.
    """

    start_xy: np.ndarray  # (n, 2)
    end_xy: np.ndarray
    start_out: np.ndarray  # (n,) radians
    end_out: np.ndarray
    start_z: np.ndarray
    end_z: np.ndarray

    def at(self, road_index: int, contact: str) -> tuple[np.ndarray, float, float]:
        if contact == "start":
            return self.start_xy[road_index], float(self.start_out[road_index]), float(self.start_z[road_index])
        return self.end_xy[road_index], float(self.end_out[road_index]), float(self.end_z[road_index])


class ValidationContext:
    """``root``/``line_offset``: the parsed document (None for an already loaded map); ``odr``: the map or None.

    A file's document is read in parts (validate/document.py): then ``root`` holds the top-level elements of the
    current ``part`` only, ``part.outline`` what is known of the whole document, and ``source`` the file's bytes.
    Structure rules run once per part; what they can only say of the whole document they say on the last part.
    """

    def __init__(self, name: str, odr=None, root=None, line_offset: int = 0, schema_dir=None):
        self.name = name
        self.odr = odr
        self.root = root
        self.line_offset = line_offset
        self.schema_dir = schema_dir
        self.part = None  # the DocumentPart ``root`` belongs to
        self.source = None  # the XmlSource of the document, while its parts are checked
        self.notes: dict = {}  # facts for the report summary (e.g. which schema was used)

    def line(self, element) -> int | None:
        return element.sourceline + self.line_offset if element is not None and element.sourceline else None

    @cached_property
    def road_ends(self) -> RoadEnds:
        roads = self.odr.roads
        n = len(roads)
        arrays = self.odr.arrays
        index = np.arange(n)
        lengths = np.array([road.length for road in roads], dtype=float)
        x, y, z, h, *_ = arrays.reference(np.concatenate([index, index]), np.concatenate([np.zeros(n), lengths]))
        xy = np.column_stack([x, y])
        return RoadEnds(xy[:n], xy[n:], h[:n] + np.pi, h[n:], z[:n], z[n:])

    @cached_property
    def lane_rows(self) -> list[tuple]:
        """(road, section index, lane) for every row of the map's lane table (NetworkArrays order)."""
        rows = []
        for road in self.odr.roads:
            for k, section in enumerate(road.lane_sections):
                for side_lanes in (section.left, section.right):
                    rows.extend((road, k, lane) for lane in side_lanes)
        return rows


def angle_difference(a, b):
    """a - b wrapped to [-pi, pi)."""
    return (np.asarray(a) - np.asarray(b) + np.pi) % (2.0 * np.pi) - np.pi
