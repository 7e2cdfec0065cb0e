"""The reader's lanes scan (opendrive/lanes_scan.py): repeated <lanes> contents read once per template give the
map the careful, element-by-element path gives -- same objects, same sharing, same source lines (also past
libxml2's 16-bit line numbers), same warnings and errors."""


import pytest

from tavf_mapkit.opendrive import planview_scan
from tavf_mapkit.opendrive.lanes_scan import lanes_layout, lanes_template
from tavf_mapkit.opendrive.reader import loads_opendrive
from tests.reader_scan import careful, document, same_map, same_map_or_error, taken_count

LANES = """<lanes>
      <laneOffset s="0" a="{offset}" b="0" c="0" d="0"/>
      <laneSection s="0">
        <left>
          <lane id="1" type="driving" level="false">
            <link>
              <successor id="1"/>
            </link>
            <width sOffset="0" a="{width}" b="0" c="{c}" d="0"/>
            <roadMark sOffset="0" type="broken" weight="standard" color="standard" width="0.13"/>
          </lane>
        </left>
        <center>
          <lane id="0" type="none" level="true">
            <roadMark sOffset="0" type="solid" weight="standard" color="standard" width="0.13"/>
          </lane>
        </center>
        <right>
          <lane id="-1" type="driving" level="true">
            <width sOffset="0" a="{width}" b="0" c="{c}" d="0"/>
            <width sOffset="2.5" a="3" b="0" c="0" d="0"/>
            <speed sOffset="0" max="13.89"/>
          </lane>
        </right>
      </laneSection>
      <laneSection s="{second}">
        <center>
          <lane id="0" type="none" level="true"/>
        </center>
      </laneSection>
    </lanes>"""


def road(road_id: int, width="3.5", c="0", offset="0", second="5", lanes: str | None = None) -> str:
    lanes = lanes or LANES.format(width=width, c=c, offset=offset, second=second)
    return (f'<road id="{road_id}" length="10" junction="-1">\n    <planView>\n      <geometry s="0" x="0" y="0" '
            f'hdg="0" length="10">\n        <line/>\n      </geometry>\n    </planView>\n    {lanes}\n  </road>\n')


def recipe_count(data: bytes, monkeypatch) -> int:
    return taken_count(data, monkeypatch, "take_lanes")


@pytest.mark.parametrize("padding", [0, 70000])  # 70000: past libxml2's 16-bit line numbers
def test_repeated_lanes_are_read_once_and_give_the_same_map(padding, monkeypatch):
    data = document(*(road(k) for k in range(4)), padding=padding)
    same_map(data)
    assert recipe_count(data, monkeypatch) == 3  # all but the first, which the parser reads
    lanes = loads_opendrive(data, "t.xodr").roads[2].lane_sections[0].lanes
    assert [lane.line for lane in lanes] == [lane.line for lane in careful(data).roads[2].lane_sections[0].lanes]
    assert min(lane.line for lane in lanes) > padding


def test_lanes_that_differ_in_widths_share_a_template(monkeypatch):
    widths = ["3.5", "3.25", "-0", "1e-3", "4.000000000000118", "0.1"]
    data = document(*(road(k, width=w, c=str(k * 1e-15), offset=w) for k, w in enumerate(widths)))
    same_map(data)
    assert recipe_count(data, monkeypatch) == len(widths) - 1
    odr = loads_opendrive(data, "t.xodr")
    assert [road.lane_sections[0].by_id[-1].widths(0.0).item() for road in odr.roads] == [
        float(w) for w in widths]


def test_zero_length_sections_warn_for_each_road(monkeypatch):
    data = document(*(road(k, second="0") for k in range(3)))
    same_map(data)
    assert recipe_count(data, monkeypatch) == 2
    warnings = loads_opendrive(data, "t.xodr").warnings
    assert [(w.road, w.line) for w in warnings if "zero-length" in w.message] == [
        (w.road, w.line) for w in careful(data).warnings if "zero-length" in w.message]
    assert len([w for w in warnings if "zero-length" in w.message]) == 3


@pytest.mark.parametrize("number", ["nan", "inf", "1e5e5", "", "&#49;"])
def test_a_broken_number_in_a_repeated_template_is_named_as_before(number):
    data = document(road(1), road(2, width=number), road(3))
    same_map_or_error(data)


@pytest.mark.parametrize("change", [
    ('level="true">', 'level="true">\n            <height sOffset="0" inner="0" outer="0.1"/>'),  # own objects
    ('<laneSection s="0">', '<laneSection s="0" singleSide="true">'),
    ("</right>", "</right>\n        <userData code='x'/>"),
    ('type="driving" level="false"', "type='driving' level='false'"),
    ("<center>", "<!-- a comment --><center>"),
    ('<speed sOffset="0" max="13.89"/>', '<speed sOffset="0" max="13.89"></speed>'),
    ('<width sOffset="2.5" a="3" b="0" c="0" d="0"/>', '<width sOffset="2.5" a="3" b="0" c="0"/>'),
    ("<left>", "<left>\n"),  # other line numbers: another layout, the same template otherwise
])
def test_other_lanes_read_as_before(change, monkeypatch):
    other = LANES.format(width="3.5", c="0", offset="0", second="5").replace(*change)
    data = document(road(1), road(2, lanes=other), road(3, lanes=other), road(4))
    same_map(data)


def test_lanes_across_the_scan_chunks(monkeypatch):
    monkeypatch.setattr(planview_scan, "CHUNK_BYTES", 7)
    data = document(*(road(k, width=str(3 + k / 8)) for k in range(12)))
    same_map(data)
    assert recipe_count(data, monkeypatch) == 11


def test_lanes_that_are_no_roads_are_kept_as_written():
    lanes = LANES.format(width="3.5", c="0", offset="0", second="5")
    data = document(road(1), f"<userData>\n{lanes}\n</userData>\n", road(2))
    same_map(data)


def test_layout_and_template():
    content = LANES.format(width="3.5", c="0", offset="1", second="5")[len("<lanes>"):-len("</lanes>")].encode()
    _, numbers = lanes_template(content)
    assert numbers == [b"0", b"1", b"0", b"0", b"0", b"0", b"3.5", b"0", b"0", b"0", b"0", b"3.5", b"0", b"0",
                       b"0", b"2.5", b"3", b"0", b"0", b"0"]
    assert lanes_template(content.replace(b'a="3.5"', b'a="3.5x"')) is None
    layout = lanes_layout(content)
    assert layout.newlines == content.count(b"\n")
    assert layout.tag_lines[:3] == (1, 2, 3) and layout.next_tag_lines[:3] == (2, 3, 4)
    assert lanes_layout(content.replace(b"<center>", b"<centre>")) is None
    assert lanes_layout(content.replace(b"</left>", b"")) is None
