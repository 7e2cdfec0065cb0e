"""The reference line of a road: its planView geometries as one function of s.

The geometries are kept as one numeric row per record (``NARROW_COLUMNS``, the few records with more parameters
than a line or an arc also in a side table), not as one Python object per record: curves as arcs give a city map
millions of records, and objects cost about four times the memory of rows.
``geometries`` makes the ``Geometry`` values on demand, for the repairs and the writer that work record by record.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive.geometry import (
    NARROW_COLUMNS, Geometry, GeometryTable, geometries_from_rows, geometry_rows, join_rows, split_rows)

_NO_SIDE_INDEX = np.zeros(0, dtype=np.int64)
_NO_SIDE_INDEX.flags.writeable = False
_NO_SIDE_PARAMS = np.zeros((0, 9))
_NO_SIDE_PARAMS.flags.writeable = False


class ReferenceLine:
    """Immutable: ``narrow`` (n, NARROW_COLUMNS) rows sorted by s, the few rows that need more parameters in a
    side table (``side_index`` into the rows, ``side_params`` their 9 parameters; see geometry.NARROW_COLUMNS),
    ``lines`` the source line of each (-1: none) and ``extra_xml`` the unknown children of the records that had
    any ({index: tuple of bytes}). ``rows`` gives the full (n, GEOMETRY_COLUMNS) rows, made on demand."""

    __slots__ = ("narrow", "side_index", "side_params", "lines", "extra_xml", "_table")

    def __init__(self, geometries=()):
        rows, lines, extra_xml = geometry_rows(geometries)
        self._set(*split_rows(rows), lines, extra_xml)

    @classmethod
    def from_rows(cls, rows: np.ndarray, lines: np.ndarray, extra_xml: dict | None = None) -> "ReferenceLine":
        """From full (n, GEOMETRY_COLUMNS) rows."""
        line = cls.__new__(cls)
        line._set(*split_rows(rows), np.asarray(lines, dtype=np.int32), extra_xml or None)
        return line

    @classmethod
    def from_narrow(cls, narrow: np.ndarray, side_index: np.ndarray | None, side_params: np.ndarray | None,
                    lines: np.ndarray, extra_xml: dict | None = None) -> "ReferenceLine":
        """From narrow rows and their side table (taken as they are, not copied)."""
        line = cls.__new__(cls)
        line._set(np.asarray(narrow, dtype=float).reshape(-1, NARROW_COLUMNS),
                  _NO_SIDE_INDEX if side_index is None or not len(side_index) else np.asarray(side_index, np.int64),
                  _NO_SIDE_PARAMS if side_params is None or not len(side_params)
                  else np.asarray(side_params, dtype=float).reshape(-1, 9),
                  np.asarray(lines, dtype=np.int32), extra_xml or None)
        return line

    def _set(self, narrow, side_index, side_params, lines, extra_xml) -> None:
        if not len(side_index):  # shared empties: most roads have no side rows
            side_index, side_params = _NO_SIDE_INDEX, _NO_SIDE_PARAMS
        for array in (narrow, side_index, side_params, lines):
            array.flags.writeable = False
        object.__setattr__(self, "narrow", narrow)
        object.__setattr__(self, "side_index", side_index)
        object.__setattr__(self, "side_params", side_params)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "extra_xml", extra_xml)
        object.__setattr__(self, "_table", None)

    def __setattr__(self, name, value):
        raise AttributeError("ReferenceLine is immutable")

    def __reduce__(self):
        return reference_line_from_narrow, (self.narrow, self.side_index, self.side_params, self.lines,
                                           self.extra_xml)

    @property
    def rows(self) -> np.ndarray:
        """The full (n, GEOMETRY_COLUMNS) rows (a new array: for the repairs that work road by road)."""
        return join_rows(self.narrow, self.side_index, self.side_params)

    @property
    def kinds(self) -> np.ndarray:
        return self.narrow[:, 5]

    def share_rows(self, narrow: np.ndarray) -> None:
        """Keep ``narrow`` (equal to this line's own, a view into a map's table) instead of a copy of them: a
        map's NetworkArrays gathers every road's rows into one table, and both copies would otherwise stay alive."""
        if narrow.shape != self.narrow.shape:
            raise ValueError("shared rows must have the shape of the reference line's own")
        narrow = narrow.view()
        narrow.flags.writeable = False
        object.__setattr__(self, "narrow", narrow)
        object.__setattr__(self, "_table", None)

    def __len__(self) -> int:
        return len(self.narrow)

    @property
    def geometries(self) -> tuple[Geometry, ...]:
        # without side rows every record is a line or an arc (split_rows puts every other kind there), whose
        # parameters the narrow rows hold: no full rows made for them (the writer asks for every road's)
        rows = self.narrow if not len(self.side_index) else self.rows
        return geometries_from_rows(rows, self.lines, self.extra_xml)

    @property
    def table(self) -> GeometryTable:
        if self._table is None:
            object.__setattr__(self, "_table", GeometryTable.from_rows(self.narrow, None, self.side_index,
                                                                       self.side_params))
        return self._table

    def geometry_index(self, s: np.ndarray) -> np.ndarray:
        """Index of the geometry that governs each s; zero-length geometries are never chosen over a successor."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return self.table.locate(np.zeros(len(s), dtype=np.int64), s)[0]

    def evaluate(self, s):
        """(x, y, heading, curvature) at each s (arrays); the map-wide NetworkArrays.reference evaluates alike
        (the same GeometryTable.locate and kernels)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if not len(self.narrow):
            zero = np.zeros_like(s)
            return zero, zero.copy(), zero.copy(), zero.copy()
        index = self.geometry_index(s)
        return self.table.evaluate(index, s - self.table.s[index])

    def xy(self, s) -> np.ndarray:
        x, y, _, _ = self.evaluate(s)
        return np.column_stack([x, y])


#: rows per shared array of ``RowPacker`` (about 8 MB)
PACK_ROWS = 65_536
#: rows copied by ``gather_rows`` between hand-backs of the freed memory (about 30 MB)
GATHER_ROWS = 262_144


class RowPacker:
    """Packs the rows of reference lines read one by one into shared arrays of about PACK_ROWS rows, each line
    holding a view of its part: a city's 155,000 roads then hold 80 arrays, not 155,000 small ones scattered over
    the heap between the other objects of the map, which ``gather_rows`` could not give back as it copies them."""

    def __init__(self, pack_rows: int | None = None):
        self.pack_rows = pack_rows or PACK_ROWS
        self.pending: list[ReferenceLine] = []
        self.count = 0

    def add(self, line: ReferenceLine) -> None:
        if not len(line):
            return
        self.pending.append(line)
        self.count += len(line)
        if self.count >= self.pack_rows:
            self.flush()

    def flush(self) -> None:
        if self.pending:  # one line too: its rows may be a view that keeps a larger table alive
            packed = np.concatenate([line.narrow for line in self.pending])
            start = 0
            for line in self.pending:
                line.share_rows(packed[start:start + len(line)])
                start += len(line)
        self.pending, self.count = [], 0


def gather_rows(lines) -> np.ndarray:
    """One (n, NARROW_COLUMNS) table of the lines' rows in order, each line then holding a view of its part
    (``share_rows``). Lines that already are consecutive parts of one table (gathered before) give that table,
    uncopied; otherwise the rows are copied line by line, and every GATHER_ROWS rows the memory of the arrays
    the lines let go (``RowPacker``'s, a repaired road's) is handed back: a city's 5 million rows (286 MB) are
    never resident twice. The side tables: ``gather_side``."""
    from tavf_mapkit.memory import trim_heap

    lines = list(lines)
    counts = np.array([len(line) for line in lines], dtype=np.int64)
    total = int(counts.sum())
    gathered = _gathered(lines, counts, total)
    if gathered is not None:
        return gathered
    table = np.empty((total, NARROW_COLUMNS))
    start = since = 0
    for line, count in zip(lines, counts.tolist()):
        if not count:
            continue
        part = table[start:start + count]
        part[...] = line.narrow
        line.share_rows(part)
        start += count
        since += count
        if since >= GATHER_ROWS:
            trim_heap()
            since = 0
    return table


def _gathered(lines: list, counts: np.ndarray, total: int) -> np.ndarray | None:
    """The table the lines' rows are already consecutive parts of, in order, or None."""
    if not total:
        return None
    holding = [line.narrow for line, count in zip(lines, counts) if count]
    base = holding[0].base
    if base is None or not isinstance(base, np.ndarray) or base.ndim != 2 or len(base) < total:
        return None
    start = base.__array_interface__["data"][0]
    step = base.strides[0]
    if base.strides != (NARROW_COLUMNS * 8, 8) or base.dtype != np.float64:
        return None
    offset = 0
    for rows in holding:
        if rows.base is not base or rows.__array_interface__["data"][0] != start + offset * step:
            return None
        offset += len(rows)
    return base[:total]


def gather_side(lines, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index, parameters): the side tables of the lines, whose rows ``gather_rows`` put one after another, as one
    side table of that table (row indices offset by where each line's rows start)."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    index, params = [], []
    for line, start in zip(lines, starts.tolist()):
        if len(line.side_index):
            index.append(line.side_index + start)
            params.append(line.side_params)
    if not index:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 9))
    return np.concatenate(index), np.concatenate(params)


def reference_line_from_narrow(narrow, side_index, side_params, lines, extra_xml) -> ReferenceLine:
    """``ReferenceLine.from_narrow`` as a plain function: what a pickled reference line is made by (a classmethod
    would pickle as ``getattr``, which a map snapshot's unpickler does not allow; opendrive/snapshot.py)."""
    return ReferenceLine.from_narrow(narrow, side_index, side_params, lines, extra_xml)
