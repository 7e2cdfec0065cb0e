"""The writer's text path (roads and junctions spelled as text) writes the very bytes lxml makes of the same
element tree: on every shared and zoo OpenDRIVE file, and on a road with everything the text path must escape,
indent or hand back to lxml."""

from __future__ import annotations

import glob

import pytest

from tavf_mapkit.opendrive import load_opendrive, loads_opendrive, writer
from tests.conftest import SHARED_DATA, shared_path
from tests.xodr_factory import document, road_xml


def _both(odr) -> tuple[bytes, bytes]:
    return b"".join(writer._serialized(odr, as_text=False)), b"".join(writer._serialized(odr))


def _texts_made(odr, monkeypatch) -> int:
    """How many top-level items the text path wrote (not handed to lxml)."""
    made = []
    original = writer._text_or_none
    monkeypatch.setattr(writer, "_text_or_none",
                        lambda make, item, counts=None: made.append(original(make, item, counts)) or made[-1])
    b"".join(writer._serialized(odr))
    return sum(text is not None for text in made)


def _shared_files() -> list[str]:
    shared_path("xodr")
    return sorted(glob.glob(str(SHARED_DATA / "xodr" / "*" / "*.xodr"))
                  + glob.glob(str(SHARED_DATA / "zoo" / "xodr" / "*.xodr")))


def test_text_path_writes_lxml_bytes_on_every_shared_file(monkeypatch):
    files = _shared_files()
    assert len(files) >= 15
    written_as_text = 0
    for path in files:
        odr = load_opendrive(path)
        tree, text = _both(odr)
        assert text == tree, path
        written_as_text += _texts_made(odr, monkeypatch)
    assert written_as_text > 1000  # the comparison is of the text path, not of lxml with itself


_HOSTILE_ROAD = road_xml(
    '<geometry s="0" x="0" y="0" hdg="0" length="10"><line/>'
    '<userData code="a&amp;b"><vectorLane sOffset="0"> spaced text </vectorLane><empty>  </empty></userData>'
    '</geometry>'
    '<geometry s="10" x="10" y="0" hdg="-0.0" length="5"><paramPoly3 aU="0" bU="1" cU="-0.0" dU="1e-300" '
    'aV="0" bV="0" cV="0.5" dV="0" pRange="arcLength"/></geometry>'
    '<geometry s="15" x="15" y="0" hdg="0" length="5"><spiral curvStart="0" curvEnd="0.01"/></geometry>',
    20.0,
    extra='<userData><!-- a comment --><deep><deeper><deepest/></deeper></deep></userData>'
          '<objects><object id="o1" s="1" t="2" name="K&#246;nig &quot;Str.&quot;&#9;&lt;1&gt;">'
          '<outline id="0"><cornerLocal u="0" v="0" z="0"/></outline></object></objects>',
    road_id="r&amp;1")


def test_text_path_escapes_and_indents_as_lxml_does():
    odr = loads_opendrive(document(_HOSTILE_ROAD, header_extra="<userData><v tool='x'/></userData>"))
    tree, text = _both(odr)
    assert text == tree
    assert b'name="K\xc3\xb6nig &quot;Str.&quot;&#9;&lt;1&gt;"' in text  # escaped by lxml's rules, not ours
    assert b"<vectorLane sOffset=\"0\"> spaced text </vectorLane>" in text


def test_a_namespaced_fragment_is_handed_to_lxml(monkeypatch):
    road = road_xml('<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>', 10.0,
                    extra='<userData xmlns:v="urn:vendor"><v:lane v:id="1"/></userData>')
    odr = loads_opendrive(document(road))
    tree, text = _both(odr)
    assert text == tree
    assert _texts_made(odr, monkeypatch) == 0


@pytest.mark.parametrize("value", ["plain", "tab\there", "new\nline", "a&b<c>\"d'", "Straße", "\u00a0"])
def test_attribute_values_are_quoted_as_lxml_quotes_them(value):
    from lxml import etree

    element = etree.Element("a")
    element.set("v", value)
    expected = etree.tostring(element, encoding="UTF-8").decode("utf-8")
    assert f'<a v="{writer._quoted(value)}"/>' == expected
