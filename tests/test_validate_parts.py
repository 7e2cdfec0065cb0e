"""The validator's bounded memory never changes what it finds: the structure rules see the document in parts
(validate/document.py) and map rules sample in batches (topology.SECTIONS_PER_BATCH); with one element per part
and one lane section per batch, the report is the one of a single part and a single batch (the whole document,
as the validator read it before), on the sample build and on copies of it with faults spread over many parts."""

from __future__ import annotations

import pytest
from lxml import etree

from tavf_mapkit.errors import InputError
from tavf_mapkit.validate import document, topology, validate_file
from tavf_mapkit.validate.document import document_parts
from tavf_mapkit.xmlsafe import parse_safe, read_xml_source

WHOLE = 10**9


@pytest.fixture()
def sample_xodr(sample_build_dir):
    return sample_build_dir / "sample.xodr"


def _report(monkeypatch, path, elements_per_part: int, sections_per_batch: int) -> dict:
    monkeypatch.setattr(document, "ELEMENTS_PER_PART", elements_per_part)
    monkeypatch.setattr(topology, "SECTIONS_PER_BATCH", sections_per_batch)
    return validate_file(path).to_dict()


def _same_in_any_parts(monkeypatch, path) -> dict:
    """The report with the smallest parts and batches, after checking it equals the one of a single part."""
    whole = _report(monkeypatch, path, WHOLE, WHOLE)
    assert _report(monkeypatch, path, 1, 1) == whole
    return whole


def _top_level(root) -> list:
    return [(node.tag, node.sourceline) for node in root]


def _write(tmp_path, root, name: str):
    path = tmp_path / name
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8"))
    return path


def test_parts_hold_the_whole_document_in_order_and_bounded(sample_xodr):
    whole = parse_safe(read_xml_source(sample_xodr))
    largest = max(sum(1 for _ in child.iter()) for child in whole)
    seen, last = [], []
    for part in document_parts(read_xml_source(sample_xodr), 500):
        assert part.index == len(last)
        last.append(part.last)
        # a part ends at the first top-level element after 500 elements: at most 500 plus one element more
        assert sum(1 for _ in part.root.iter()) - 1 <= 500 + largest
        seen += _top_level(part.root)
    assert len(last) > 5 and last == [False] * (len(last) - 1) + [True]
    assert seen == _top_level(whole)
    assert part.outline.roads == len(whole.findall("road")) == 108
    assert part.outline.header.sourceline == whole.find("header").sourceline
    assert part.outline.root.tag == "OpenDRIVE" and part.outline.root.sourceline == whole.sourceline
    assert sum(1 for _ in document_parts(read_xml_source(sample_xodr), WHOLE)) == 1


def test_sample_build_findings_in_any_parts(monkeypatch, sample_xodr):
    report = _same_in_any_parts(monkeypatch, sample_xodr)
    assert report["summary"]["errors"] == 0 and report["summary"]["rules_run"] == 48


def test_geometry_faults_in_any_parts(monkeypatch, sample_xodr, tmp_path):
    """A gap in a road deep in the document (its finding is looked up from the map's geometry table by row),
    an unknown element, a free-form userData and a second header after the last road."""
    root = parse_safe(read_xml_source(sample_xodr))
    roads = root.findall("road")
    target = next(road for road in roads[60:] if len(road.findall("planView/geometry")) >= 4)
    moved, following = target.findall("planView/geometry")[2:4]
    moved.set("x", repr(float(moved.get("x")) + 0.5))  # a gap where it starts, and where the next one does
    etree.SubElement(roads[30], "bogus")
    etree.SubElement(etree.SubElement(roads[80], "userData"), "anything")
    root.append(etree.Element("header", revMajor="1", revMinor="4"))
    report = _same_in_any_parts(monkeypatch, _write(tmp_path, root, "geometry-faults.xodr"))
    gaps = [f for f in report["findings"] if f["rule"] == "geometry.gap"]
    assert [f["road"] for f in gaps] == [target.get("id")] * 2
    assert [f["s"] for f in gaps] == pytest.approx([float(moved.get("s")), float(following.get("s"))], abs=1e-3)
    assert all("0.5 m from where the previous one ends" in f["message"] for f in gaps)
    unknown = [f for f in report["findings"] if f["rule"] == "structure.unknown-element"]
    assert [(f["road"], f["message"]) for f in unknown] == [(roads[30].get("id"), "unknown element <bogus> inside "
                                                                                  "<road>")]
    assert [f["message"] for f in report["findings"] if f["rule"] == "structure.header"] == ["more than one <header>"]


def test_attribute_faults_in_any_parts(monkeypatch, sample_xodr, tmp_path):
    """Missing attributes and bad numbers in roads far apart: listed by path, attribute, then document order,
    as one pass over the whole document lists them. With a namespace on the root (stripped: OpenDRIVE has none)
    the findings are the same."""
    root = parse_safe(read_xml_source(sample_xodr))
    roads = root.findall("road")
    for index in (90, 5, 40):
        del roads[index].find("planView/geometry").attrib["hdg"]
    roads[70].find("planView/geometry").set("length", "abc")
    roads[20].find("planView/geometry").set("s", "-1")
    roads[99].set("length", "nan")
    for junction in root.findall("junction")[::3]:
        del junction.find("connection").attrib["connectingRoad"]
    report = _same_in_any_parts(monkeypatch, _write(tmp_path, root, "attribute-faults.xodr"))
    missing = [(f["road"], f["message"]) for f in report["findings"] if f["rule"] == "structure.required-attribute"]
    assert missing[:3] == [(roads[i].get("id"), "<geometry> lacks required @hdg") for i in (5, 40, 90)]
    assert {message for _, message in missing[3:]} == {"<connection> lacks required @connectingRoad"}
    numbers = [(f["road"], f["message"].split(" ", 1)[0]) for f in report["findings"]
               if f["rule"] == "structure.number"]
    assert numbers == [(roads[99].get("id"), "<road>"), (roads[20].get("id"), "<geometry>"),
                       (roads[70].get("id"), "<geometry>")]
    namespaced = etree.tostring(root).replace(b"<OpenDRIVE", b'<OpenDRIVE xmlns="http://example.com/opendrive"', 1)
    in_namespace = _same_in_any_parts(monkeypatch, _write(tmp_path, etree.fromstring(namespaced), "namespaced.xodr"))
    assert in_namespace["findings"] == report["findings"]


def test_road_end_borders_in_any_batches(monkeypatch, sample_xodr):
    """topology.contact-gap's borders at road ends, sampled one lane section at a time, are the whole map's."""
    from tavf_mapkit.opendrive import load_opendrive
    from tavf_mapkit.validate.context import ValidationContext

    odr = load_opendrive(sample_xodr)
    tables = []
    for batch in (WHOLE, 1):
        monkeypatch.setattr(topology, "SECTIONS_PER_BATCH", batch)
        tables.append(topology._end_border_table(ValidationContext(str(sample_xodr), odr)))
    whole, single = ({key: xy[row].tolist() for key, row in rows.items()} for rows, xy in tables)
    assert len({(road, side) for road, side, _ in whole}) == 2 * len(odr.roads) and len(whole) > 200
    assert single == whole


def test_a_fault_after_many_parts_reads_as_a_whole_parse_does(sample_xodr, tmp_path):
    text = sample_xodr.read_bytes()
    broken = tmp_path / "broken.xodr"
    broken.write_bytes(text[: int(len(text) * 0.8)])
    with pytest.raises(InputError) as whole:
        parse_safe(read_xml_source(broken))
    with pytest.raises(InputError) as in_parts:
        for _part in document_parts(read_xml_source(broken), 50):
            pass
    assert str(in_parts.value) == str(whole.value)
    assert (in_parts.value.line, in_parts.value.message) == (whole.value.line, whole.value.message)
