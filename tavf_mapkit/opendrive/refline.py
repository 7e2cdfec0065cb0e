"""The reference line of a road: its planView geometries as one function of s.

The geometries are kept as one numeric row per record (``GEOMETRY_COLUMNS``), not as one Python object per record:
curves as arcs give a city map millions of records, and objects cost about four times the memory of rows.
``geometries`` makes the ``Geometry`` values on demand, for the repairs and the writer that work record by record.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive.geometry import GEOMETRY_COLUMNS, Geometry, GeometryTable, geometries_from_rows, geometry_rows


class ReferenceLine:
    """Immutable: ``rows`` (n, GEOMETRY_COLUMNS) sorted by s, ``lines`` the source line of each (-1: none) and
    ``extra_xml`` the unknown children of the records that had any ({index: tuple of bytes})."""

    __slots__ = ("rows", "lines", "extra_xml", "_table")

    def __init__(self, geometries=()):
        rows, lines, extra_xml = geometry_rows(geometries)
        self._set(rows, lines, extra_xml)

    @classmethod
    def from_rows(cls, rows: np.ndarray, lines: np.ndarray, extra_xml: dict | None = None) -> "ReferenceLine":
        line = cls.__new__(cls)
        line._set(np.asarray(rows, dtype=float).reshape(-1, GEOMETRY_COLUMNS),
                  np.asarray(lines, dtype=np.int32), extra_xml or None)
        return line

    def _set(self, rows, lines, extra_xml) -> None:
        rows.flags.writeable = False
        lines.flags.writeable = False
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "extra_xml", extra_xml)
        object.__setattr__(self, "_table", None)

    def __setattr__(self, name, value):
        raise AttributeError("ReferenceLine is immutable")

    def __reduce__(self):
        return ReferenceLine.from_rows, (self.rows, self.lines, self.extra_xml)

    def share_rows(self, rows: np.ndarray) -> None:
        """Keep ``rows`` (equal to this line's own, a view into a map's table) instead of a copy of them: a map's
        NetworkArrays gathers every road's rows into one table, and both copies would otherwise stay alive."""
        if rows.shape != self.rows.shape:
            raise ValueError("shared rows must have the shape of the reference line's own")
        rows = rows.view()
        rows.flags.writeable = False
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "_table", None)

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def geometries(self) -> tuple[Geometry, ...]:
        return geometries_from_rows(self.rows, self.lines, self.extra_xml)

    @property
    def table(self) -> GeometryTable:
        if self._table is None:
            object.__setattr__(self, "_table", GeometryTable.from_rows(self.rows))
        return self._table

    def geometry_index(self, s: np.ndarray) -> np.ndarray:
        """Index of the geometry that governs each s; zero-length geometries are never chosen over a successor."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return self.table.locate(np.zeros(len(s), dtype=np.int64), s)[0]

    def evaluate(self, s):
        """(x, y, heading, curvature) at each s (arrays); the map-wide NetworkArrays.reference evaluates alike
        (the same GeometryTable.locate and kernels)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if not len(self.rows):
            zero = np.zeros_like(s)
            return zero, zero.copy(), zero.copy(), zero.copy()
        index = self.geometry_index(s)
        return self.table.evaluate(index, s - self.table.s[index])

    def xy(self, s) -> np.ndarray:
        x, y, _, _ = self.evaluate(s)
        return np.column_stack([x, y])
