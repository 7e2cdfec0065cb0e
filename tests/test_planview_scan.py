"""The reader's planView scan (opendrive/planview_scan.py) gives the map the careful, element-by-element path
gives: same rows, same source lines (also past libxml2's 16-bit line numbers), same warnings and errors."""


import pytest

from tavf_mapkit.opendrive import planview_scan
from tavf_mapkit.opendrive.reader import loads_opendrive
from tests.reader_scan import document, same_map, same_map_or_error, taken_count

ARC = '<geometry s="{s}" x="1.5" y="-2.25" hdg="0.125" length="{length}">\n  <arc curvature="0.01"/>\n</geometry>'
LINE = '<geometry s="{s}" x="3e2" y="-.5" hdg="-1.5E-3" length="{length}">\n  <line/>\n</geometry>'
LANES = '<lanes><laneSection s="0"><center><lane id="0" type="none"/></center></laneSection></lanes>'


def road(road_id, plan_view: str, before: str = "\n  ") -> str:
    return f'<road id="{road_id}" length="10" junction="-1">{before}<planView>\n{plan_view}\n</planView>{LANES}</road>\n'


def scanned_count(data: bytes, monkeypatch) -> int:
    return taken_count(data, monkeypatch, "take")


PLAIN = road(1, ARC.format(s=0, length=2) + "\n" + LINE.format(s=2, length=8))


def test_plain_plan_views_are_scanned_and_give_the_same_map(monkeypatch):
    data = document(PLAIN, road(2, LINE.format(s=0, length=10)))
    same_map(data)
    assert scanned_count(data, monkeypatch) == 2
    odr = loads_opendrive(data, "t.xodr")
    assert odr.roads[0].reference_line.lines.tolist() == [6, 9]  # the lines of the <geometry> tags


def test_lines_past_65535_are_the_parsers(monkeypatch):
    # libxml2 gives an element past line 65535 the line of its first child: the scan must give the same
    data = document(PLAIN, road(2, ARC.format(s=0, length=10)), padding=70000)
    same_map(data)
    assert scanned_count(data, monkeypatch) == 2
    assert loads_opendrive(data, "t.xodr").roads[0].reference_line.lines[0] > 65535


@pytest.mark.parametrize("plan_view", [
    ARC.format(s=0, length=-1),  # negative length: a warning, the record skipped
    ARC.format(s=0, length=0),  # zero length: a warning
    ARC.format(s=0, length="nan"),
    ARC.format(s=0, length="1e5e5"),
    ARC.format(s=0, length="1_0"),
    ARC.format(s=0, length="&#49;0"),
    ARC.format(s=5, length=1) + LINE.format(s=0, length=5),  # out of order: sorted
    ARC.format(s=0, length=1).replace('"0.01"', "'0.01'"),
    ARC.format(s=0, length=1).replace("<arc", "<!-- a comment --><arc"),
    '<geometry s="0" x="0" y="0" hdg="0" length="4"><spiral curvStart="0" curvEnd="0.1"/></geometry>',
    LINE.format(s=0, length=1).replace("<line/>", "<line/><userData code='x'/>"),
])
def test_other_plan_views_read_as_before(plan_view):
    data = document(road(1, plan_view), PLAIN)
    same_map_or_error(data)


@pytest.mark.parametrize("trap", [
    "<!-- <planView>\n" + ARC.format(s=0, length=1) + "\n</planView> -->\n",  # in a comment
    "<userData>\n  <planView>\n" + ARC.format(s=0, length=1) + "\n</planView></userData>\n",  # not a road's
])
def test_plan_views_that_are_no_roads_are_kept_as_written(trap, monkeypatch):
    data = document(PLAIN, trap, road(2, LINE.format(s=0, length=10)))
    same_map(data)


def test_two_roads_on_one_line():
    data = document(road(1, ARC.format(s=0, length=10)).rstrip("\n") + road(2, LINE.format(s=0, length=10)))
    same_map(data)
    one_line = document('<road id="1" length="1"> <planView/></road>' + road(2, LINE.format(s=0, length=10)))
    same_map(one_line)


def test_a_plan_view_across_the_scan_chunks(monkeypatch):
    monkeypatch.setattr(planview_scan, "CHUNK_BYTES", 7)
    data = document(*(road(k, ARC.format(s=0, length=1) + "\n" + LINE.format(s=1, length=9)) for k in range(30)))
    same_map(data)
    assert scanned_count(data, monkeypatch) == 30


def test_texts_of_every_width_class_are_told_apart(monkeypatch):
    # the scan groups the texts between values by length (planview_scan._distinct_texts): texts that differ in
    # one byte or only in length, short and long, in one chunk, must each get their own code and line count
    spaced = [ARC.format(s=0, length=1).replace(' x="', sep + 'x="') for sep in (" ", "  ", "\t", " \t ", " " * 9)]
    indented = [LINE.format(s=0, length=1).replace("\n", "\n" + " " * width) for width in (0, 7, 8, 30, 60, 100)]
    odd = ARC.format(s=0, length=1).replace(' y="', ' y ="')  # one byte more than " y=": not the plain form
    data = document(*(road(k, plan_view) for k, plan_view in enumerate(spaced + indented + [odd, PLAIN])))
    same_map(data)
    assert scanned_count(data, monkeypatch) == len(spaced) + len(indented)  # all but the odd one
