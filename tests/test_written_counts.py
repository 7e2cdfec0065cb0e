"""The writer counts what it writes and hashes it as it goes (``writer.write_opendrive``): the report's counts of
NAME.xodr (``pipeline.summary.opendrive_counts``) and the snapshot's file key come from the opendrive stage
instead of a pass over the file it has just written (a region's: 500 MB). Here the writer's figures are checked
against the pass over the file it wrote: real files, and documents with counted elements where the writer does
not spell them itself (verbatim fragments, items built as trees)."""

from __future__ import annotations

import glob
import json
from dataclasses import replace
from pathlib import Path

import pytest

from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from tavf_mapkit.opendrive.snapshot import snapshot_file
from tavf_mapkit.opendrive.writer import write_opendrive
from tavf_mapkit.pipeline.manifest import file_sha256
from tavf_mapkit.pipeline.summary import opendrive_counts
from tests.conftest import SHARED_DATA, shared_path
from tests.xodr_factory import document, road_xml

LINE = '<geometry s="0" x="0" y="0" hdg="0" length="{length}"><line/></geometry>'


def _written_as_counted(odr, path: Path) -> dict:
    written = write_opendrive(odr, path)
    assert written.sha256 == file_sha256(path)
    assert written.counts == opendrive_counts(path)
    return written.counts


def test_counts_of_every_shared_file(tmp_path):
    shared_path("xodr")
    files = sorted(glob.glob(str(SHARED_DATA / "xodr" / "*" / "*.xodr")))
    assert files
    for path in files:
        _written_as_counted(load_opendrive(path), tmp_path / "out.xodr")


def test_counts_of_netconvert_output(tavf_xodr, tmp_path):
    counts = _written_as_counted(load_opendrive(tavf_xodr), tmp_path / "tavf.xodr")
    assert counts["roads"] > 1000 and counts["road_length_km"] > 10


def test_counts_see_into_fragments_and_tree_items(tmp_path):
    # counted elements the writer does not write itself: in userData of a road, of a signal and of the
    # document (a junction there is a child of the document's root: counted), a nested road whose length adds
    # before its parent's, and a namespaced fragment that makes its road an lxml tree instead of text
    signals = ('<signals><signal id="s1" s="1" t="0"><userData><signal id="inner"/></userData></signal>'
               '<signalReference id="s2" s="2" t="0"/></signals>')
    objects = '<objects><object id="o1" s="1" t="2"/><object id="o2" s="3" t="2"/></objects>'
    user_data = ('<userData><object id="u1"/><junction id="not-top-level"/>'
                 '<road id="nested" length="0.30000000000000004"/></userData>')
    namespaced = '<userData><v:signal xmlns:v="urn:vendor" id="ns"/></userData>'
    text = document(
        road_xml(LINE.format(length=10), 10.1, extra=user_data + objects + signals, road_id="1"),
        road_xml(LINE.format(length=7), 7.2, extra=namespaced, road_id="2"),
        road_xml(LINE.format(length=5), 0.1, road_id="3"),
        tail='<junction id="j1"/><userData><junction id="top" /><road length="2.5"/></userData>')
    odr = loads_opendrive(text)
    counts = _written_as_counted(odr, tmp_path / "fragments.xodr")
    assert counts == {"roads": 5, "junctions": 1, "signals": 3, "objects": 3, "road_length_km": 0.02}


def test_an_unreadable_nested_length_is_left_to_the_pass_over_the_file(tmp_path):
    text = document(road_xml(LINE.format(length=10), 10, extra='<userData><road length="ten"/></userData>'))
    written = write_opendrive(loads_opendrive(text), tmp_path / "bad.xodr")
    assert written.counts is None and written.sha256 == file_sha256(tmp_path / "bad.xodr")
    with pytest.raises(ValueError):
        opendrive_counts(tmp_path / "bad.xodr")


def test_snapshot_keyed_by_the_written_sha256_is_the_hashed_one(shared, tmp_path):
    odr = load_opendrive(shared("xodr", "esmini", "e6mini.xodr"))
    xodr = tmp_path / "e6mini.xodr"
    written = write_opendrive(odr, xodr)
    snapshot_file(xodr, tmp_path / "hashed.odrmap")
    snapshot_file(xodr, tmp_path / "given.odrmap", sha256=written.sha256)
    assert (tmp_path / "hashed.odrmap").read_bytes() == (tmp_path / "given.odrmap").read_bytes()


def test_report_takes_the_written_counts_only_for_their_file(tavf_xodr, tmp_path):
    from tavf_mapkit.pipeline.config import load_pipeline
    from tavf_mapkit.pipeline.context import BuildContext
    from tavf_mapkit.pipeline.summary import build_report

    xodr = tmp_path / "tavf.xodr"
    odr = load_opendrive(tavf_xodr)
    written = write_opendrive(odr, xodr)
    counts_file = tmp_path / "xodr_counts.json"
    context = BuildContext(name="tavf", folder=tmp_path, input_path=tavf_xodr, input_kind="opendrive",
                           config=load_pipeline(None), artifacts={"xodr": xodr, "xodr_counts": counts_file})
    parsed = opendrive_counts(xodr)
    # counts that are not the file's, to tell which were used
    marked = {**written.counts, "roads": -1}
    counts_file.write_text(json.dumps({"file": xodr.name, "bytes": xodr.stat().st_size, "sha256": written.sha256,
                                       "counts": marked}))
    assert build_report(context)["opendrive"] == {"file": xodr.name, **marked}
    # another file (the counts of a file of another size, or name) are not used: the file is parsed
    write_opendrive(replace(odr, roads=odr.roads[:-1]), xodr)
    assert build_report(context)["opendrive"] == {"file": xodr.name, **opendrive_counts(xodr)}
    assert opendrive_counts(xodr) != parsed
    counts_file.write_text("not json")
    assert build_report(context)["opendrive"] == {"file": xodr.name, **opendrive_counts(xodr)}
