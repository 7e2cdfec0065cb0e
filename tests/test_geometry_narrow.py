"""The planView table is narrow (7 columns) with a side table for the records that need more parameters: every
record must read, and evaluate, exactly as it did from the full 15-column rows, for all five geometry kinds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lxml import etree

from tavf_mapkit.opendrive import loads_opendrive
from tavf_mapkit.opendrive.geometry import _KERNELS, GeometryKind, join_rows, split_rows
from tavf_mapkit.opendrive.writer import to_xml

_SHAPES = [
    '<line/>',
    '<arc curvature="0.0125"/>',
    '<arc curvature="-0.0"/>',
    '<spiral curvStart="0.0" curvEnd="0.02"/>',
    '<spiral curvStart="-0.01" curvEnd="-0.0"/>',
    '<poly3 a="0.0" b="0.01" c="0.002" d="-0.00003"/>',
    '<poly3 a="-0.0" b="0" c="0" d="0"/>',
    '<paramPoly3 aU="0" bU="10" cU="0.5" dU="-0.1" aV="0" bV="0.2" cV="1.5" dV="-0.4" pRange="normalized"/>',
    '<paramPoly3 aU="0" bU="1" cU="-0.0" dU="0" aV="0" bV="0" cV="0.01" dV="-0.0002" pRange="arcLength"/>',
]


def _map_xml() -> str:
    """Roads of every kind of record, with negative zeros, in and out of s order."""
    roads = []
    for r in range(12):
        count = 1 + r % 5
        shapes = [_SHAPES[(r * 3 + k) % len(_SHAPES)] for k in range(count)]
        order = list(range(count))[::-1] if r % 4 == 3 else list(range(count))  # some planViews out of order
        geometries = "".join(
            f'<geometry s="{10.0 * k}" x="{100.0 * r + 10.0 * k}" y="{r * 0.5}" hdg="{0.1 * k}" length="10.0">'
            f'{shapes[k]}</geometry>' for k in order)
        roads.append(
            f'<road id="{r}" length="{10.0 * count}" junction="-1"><planView>{geometries}</planView>'
            '<lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right>'
            '<lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>'
            '</right></laneSection></lanes></road>')
    return ('<?xml version="1.0"?>\n<OpenDRIVE><header revMajor="1" revMinor="6"/>' + "".join(roads)
            + "</OpenDRIVE>\n")


_NAMES = {"line": (), "arc": ("curvature",), "spiral": ("curvStart", "curvEnd"), "poly3": ("a", "b", "c", "d"),
          "paramPoly3": ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")}


def _full_rows(xml: str) -> np.ndarray:
    """The full 15-column rows read from the XML on their own (plain lxml, no reader), sorted like the reader."""
    rows = []
    for road_index, road in enumerate(etree.fromstring(xml.encode()).iter("road")):
        mine = []
        for g in road.iter("geometry"):
            shape = g[0]
            params = [float(shape.get(name, 0.0)) for name in _NAMES[shape.tag]]
            if shape.tag == "paramPoly3":
                params.append(1.0 if shape.get("pRange") == "normalized" else 0.0)
            kind = int(GeometryKind[{"paramPoly3": "PARAM_POLY3"}.get(shape.tag, shape.tag.upper())])
            mine.append([float(g.get(k)) for k in ("s", "x", "y", "hdg", "length")] + [kind] + params
                        + [0.0] * (9 - len(params)))
        rows += sorted(mine, key=lambda row: row[0])
    return np.array(rows)


def _bits(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array, dtype=float).view(np.uint64)


XML = _map_xml()
FULL = _full_rows(XML)


@pytest.fixture(scope="module")
def table():
    return loads_opendrive(XML).arrays.geometries


def test_every_kind_is_in_the_map(table):
    assert set(np.unique(table.kind).tolist()) == {int(kind) for kind in GeometryKind}
    assert len(table) == len(FULL)
    assert 0 < len(table.params.side_index) < len(table)  # lines and arcs are not in the side table


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, len(FULL) - 1), min_size=1, max_size=40))
def test_parameters_read_bit_for_bit_as_the_full_rows(table, rows):
    rows = np.array(rows, dtype=np.int64)
    assert np.array_equal(_bits(table.params[rows]), _bits(FULL[rows, 6:]))  # -0.0 kept as -0.0
    columns = np.column_stack([table.s, table.x, table.y, table.hdg, table.length, table.kind])
    assert np.array_equal(_bits(columns[rows]), _bits(FULL[rows, :6]))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, len(FULL) - 1), st.floats(0.0, 10.0)), min_size=1, max_size=30))
def test_evaluation_is_the_full_rows_evaluation(table, samples):
    """The table's evaluate against the kernels fed the full 9-parameter rows (the wide table's evaluation)."""
    index = np.array([i for i, _ in samples], dtype=np.int64)
    ds = np.array([d for _, d in samples])
    got = table.evaluate(index, ds)
    kinds = FULL[index, 5].astype(int)
    for kind in np.unique(kinds).tolist():
        mask = kinds == kind
        g = index[mask]
        u, v, theta, k = _KERNELS[GeometryKind(kind)](FULL[g, 6:], FULL[g, 4], ds[mask], g)
        cos_h, sin_h = np.cos(FULL[g, 3]), np.sin(FULL[g, 3])
        want = (FULL[g, 1] + cos_h * u - sin_h * v, FULL[g, 2] + sin_h * u + cos_h * v, FULL[g, 3] + theta, k)
        for got_values, want_values in zip(got, want):
            assert np.array_equal(got_values[mask], want_values)


def test_split_and_join_are_inverse_bit_for_bit():
    narrow, side_index, side_params = split_rows(FULL)
    assert narrow.shape == (len(FULL), 7)
    assert np.array_equal(_bits(join_rows(narrow, side_index, side_params)), _bits(FULL))


def test_reference_lines_and_writer_keep_every_parameter():
    odr = loads_opendrive(XML)
    rows = np.concatenate([road.reference_line.rows for road in odr.roads])
    assert np.array_equal(_bits(rows), _bits(FULL))
    text = to_xml(odr)
    assert to_xml(loads_opendrive(text)) == text
    assert b'cU="-0.0"' in text or b'cU="-0"' in text  # a negative zero parameter is written back as one
