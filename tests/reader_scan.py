"""Helpers of the reader's scan tests (test_planview_scan.py, test_lanes_scan.py): a document of roads, the
careful element-by-element read, and how many blocks a scan method took."""

import pickle

import pytest

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import planview_scan
from tavf_mapkit.opendrive.reader import _Reader, loads_opendrive
from tavf_mapkit.xmlsafe import prepare_xml_bytes


def document(*roads: str, padding: int = 0) -> bytes:
    return ("<?xml version='1.0'?>\n<OpenDRIVE>\n<header revMajor='1' revMinor='6'/>\n" + "\n" * padding
            + "".join(roads) + "</OpenDRIVE>\n").encode()


def careful(data: bytes):
    return _Reader(prepare_xml_bytes(data, "t.xodr")).read()


def taken_count(data: bytes, monkeypatch, method: str) -> int:
    """How many blocks ``PlanViewScan.<method>`` (take: planViews, take_lanes: lanes) handed to the reader while
    ``data`` was loaded."""
    taken = []
    original = getattr(planview_scan.PlanViewScan, method)

    def counting(self, line, text):
        found = original(self, line, text)
        taken.append(found is not None)
        return found
    monkeypatch.setattr(planview_scan.PlanViewScan, method, counting)
    loads_opendrive(data, "t.xodr")
    return sum(taken)


def same_map(data: bytes) -> None:
    assert pickle.dumps(loads_opendrive(data, "t.xodr")) == pickle.dumps(careful(data))


def same_map_or_error(data: bytes) -> None:
    """The scanned read gives the careful read's map, or raises its error with the same message."""
    try:
        expected = pickle.dumps(careful(data))
    except InputError as error:
        with pytest.raises(InputError) as raised:
            loads_opendrive(data, "t.xodr")
        assert str(raised.value) == str(error)
        return
    assert pickle.dumps(loads_opendrive(data, "t.xodr")) == expected
