"""A map's planView rows live once: the reader packs them into a few shared arrays, and the map-wide table
(NetworkArrays) gathers them into one table the roads then hold views of -- never a second copy of them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tavf_mapkit.opendrive import loads_opendrive, refline
from tavf_mapkit.opendrive.arrays import NetworkArrays
from tavf_mapkit.opendrive.geometry import GEOMETRY_COLUMNS, Geometry, GeometryKind, GeometryTable
from tavf_mapkit.opendrive.refline import ReferenceLine, gather_rows


def _map_xml(roads: int) -> str:
    """Roads of 1 to 4 geometries (lines and arcs), each with one driving lane."""
    parts = ['<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6"/>']
    for r in range(roads):
        count = 1 + r % 4
        geometries = "".join(
            f'<geometry s="{10.0 * k}" x="{100.0 * r + 10.0 * k}" y="{r * 0.5}" hdg="0.0" length="10.0">'
            + ("<line/>" if k % 2 == 0 else f'<arc curvature="{0.001 * (r + 1)}"/>') + "</geometry>"
            for k in range(count))
        parts.append(
            f'<road id="{r}" length="{10.0 * count}" junction="-1"><planView>{geometries}</planView>'
            '<lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right>'
            '<lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>'
            '</right></laneSection></lanes></road>')
    parts.append("</OpenDRIVE>\n")
    return "".join(parts)


@pytest.fixture
def small_packs(monkeypatch):
    """Packs of 7 rows and a hand-back every 5, so a map of a few dozen roads crosses many of both."""
    monkeypatch.setattr(refline, "PACK_ROWS", 7)
    monkeypatch.setattr(refline, "GATHER_ROWS", 5)


def _owner(rows: np.ndarray) -> np.ndarray:
    return rows if rows.base is None else rows.base


def test_reader_packs_rows_into_shared_arrays(small_packs):
    odr = loads_opendrive(_map_xml(40))
    total = sum(len(road.reference_line) for road in odr.roads)
    owners = {id(_owner(road.reference_line.narrow)) for road in odr.roads}
    # a pack closes once it holds 7 rows or more (a road adds at most 4): far fewer arrays than roads
    assert len(owners) <= total // 7 + 1 < len(odr.roads)


def test_network_table_is_the_roads_rows_once(small_packs):
    odr = loads_opendrive(_map_xml(40))
    expected = np.concatenate([road.reference_line.rows for road in odr.roads]).copy()
    s = np.linspace(0.0, 40.0, 17)
    before = [road.reference_line.evaluate(s) for road in odr.roads]
    table = odr.arrays.geometries
    assert np.array_equal(np.column_stack([table.s, table.x, table.y, table.hdg, table.length]), expected[:, :5])
    gathered = _owner(table.s)
    for road, values in zip(odr.roads, before):
        rows = road.reference_line.narrow
        assert _owner(rows) is gathered  # a view of the table, not a copy beside it
        assert not rows.flags.writeable
        for got, want in zip(road.reference_line.evaluate(s), values):
            assert np.array_equal(got, want)
    # another map of the same roads (a new header) gathers nothing again: the very same table
    again = NetworkArrays.build(odr.with_header(odr.header))
    assert np.shares_memory(again.geometries.s, table.s)


def test_gather_copies_lines_of_their_own(small_packs):
    lines = [ReferenceLine([Geometry(10.0 * k, float(r), float(k), 0.1 * r, 10.0, GeometryKind.ARC, (0.01 * r,))
                            for k in range(1 + r % 3)]) for r in range(12)] + [ReferenceLine()]
    expected = np.concatenate([line.narrow for line in lines])
    table = gather_rows(lines)
    assert np.array_equal(table, expected)
    assert all(np.shares_memory(line.narrow, table) for line in lines if len(line))
    assert gather_rows(lines) is not table and np.shares_memory(gather_rows(lines), table)  # no second copy


@settings(max_examples=200, deadline=None)
@given(sizes=st.lists(st.integers(0, 9), min_size=1, max_size=12), data=st.data())
def test_locate_picks_each_groups_last_start_at_or_before_s(sizes, data):
    """GeometryTable.locate (a binary search inside each query's group, no table-sized keys) against the rule
    written out per query: the group's last row starting at or before s, its first when s is before them all,
    found iff the group has rows; a non-finite s as the complex keys put it (the table's last row if it is the
    group's, else the group's first). Starts repeat (zero-length geometries) and sit 1e-12 m apart."""
    group = np.repeat(np.arange(len(sizes)), sizes)
    starts = st.sampled_from([0.0, 1e-12, 0.5, 3.0, 3.0 + 1e-12, 7.25, 100.0, -2.0])
    s = np.concatenate([np.sort(data.draw(st.lists(starts, min_size=n, max_size=n))) for n in sizes])
    assume(len(s))
    rows = np.zeros((len(s), GEOMETRY_COLUMNS))
    rows[:, 0] = s
    table = GeometryTable.from_rows(rows, group)
    queries = data.draw(st.lists(st.tuples(st.integers(-1, len(sizes)), st.one_of(
        starts, st.floats(-5.0, 120.0), st.sampled_from([np.inf, -np.inf, np.nan]))), min_size=1, max_size=40))
    q_group = np.array([g for g, _ in queries], dtype=np.int64)
    q_s = np.array([v for _, v in queries], dtype=float)
    index, found = table.locate(q_group, q_s)
    last = len(s) - 1
    for k, (g, value) in enumerate(queries):
        mine = np.flatnonzero(group == g)
        first = int(np.searchsorted(group, g)) if len(mine) == 0 else int(mine[0])
        if not np.isfinite(value):
            expected = last if group[last] == g else min(first, last)
        else:
            at_or_before = mine[s[mine] <= value]
            expected = int(at_or_before[-1]) if len(at_or_before) else min(first, last)
        assert index[k] == expected, (g, value, index[k], expected)
        assert found[k] == (len(mine) > 0)
