"""Broken and hostile inputs: a clear one-line error with location, exit code 2, no traceback, no entity read."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import load_opendrive, loads_opendrive
from tests.xodr_factory import document, road_xml

LINE = '<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'


def _run(*args):
    result = CliRunner().invoke(cli, list(args))
    return result


def _write(tmp_path, name: str, data: bytes | str):
    path = tmp_path / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def test_truncated_xml(tmp_path):
    text = document(road_xml(LINE, 10))
    path = _write(tmp_path, "cut.xodr", text[: len(text) // 2])
    with pytest.raises(InputError, match=r"cut\.xodr:\d+: not well-formed XML"):
        load_opendrive(path)
    result = _run("info", str(path))
    assert result.exit_code == 2
    assert result.output.startswith("Error: ") and "cut.xodr:" in result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1


def test_non_xml_bytes(tmp_path):
    path = _write(tmp_path, "noise.xodr", bytes(range(256)) * 4)
    result = _run("info", str(path))
    assert result.exit_code == 2 and "noise.xodr" in result.output and "Traceback" not in result.output


def test_missing_file_and_directory(tmp_path):
    assert "file not found" in _run("info", str(tmp_path / "nope.xodr")).output
    assert _run("info", str(tmp_path / "nope.xodr")).exit_code == 2
    with pytest.raises(InputError, match="is a directory"):
        load_opendrive(tmp_path)


def test_billion_laughs_is_refused(tmp_path):
    entities = '<!ENTITY lol "lol">' + "".join(
        f'<!ENTITY lol{i} "{("&lol%s;" % (i - 1 if i > 1 else "")) * 10}">' for i in range(1, 10))
    text = f'<?xml version="1.0"?>\n<!DOCTYPE OpenDRIVE [{entities}]>\n<OpenDRIVE><header name="&lol9;"/></OpenDRIVE>'
    path = _write(tmp_path, "lol.xodr", text)
    with pytest.raises(InputError, match=r"lol\.xodr:2: DTD entity declarations are not allowed"):
        load_opendrive(path)


def test_external_entity_is_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET-CONTENT")
    text = (f'<?xml version="1.0"?>\n<!DOCTYPE OpenDRIVE [<!ENTITY xxe SYSTEM "file://{secret}">]>\n'
            '<OpenDRIVE><header name="&xxe;"/></OpenDRIVE>')
    path = _write(tmp_path, "xxe.xodr", text)
    result = _run("info", "--json", str(path))
    assert result.exit_code == 2
    assert "TOP-SECRET-CONTENT" not in result.output
    assert "entity declarations are not allowed" in result.output


def test_nan_and_negative_lengths_name_line_and_road(tmp_path):
    nan_road = document(road_xml('<geometry s="0" x="nan" y="0" hdg="0" length="10"><line/></geometry>', 10,
                                 road_id="77"))
    with pytest.raises(InputError) as error:
        loads_opendrive(nan_road, "nan.xodr")
    assert "road 77" in str(error.value) and "@x='nan' is not a finite number" in str(error.value)
    assert str(error.value).startswith("nan.xodr:")
    negative = document(road_xml(LINE, -5, road_id="12"))
    with pytest.raises(InputError, match=r"road 12 <road>: @length=-5 is negative"):
        loads_opendrive(negative, "neg.xodr")
    negative_geometry = document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="-3"><line/></geometry>', 10))
    odr = loads_opendrive(negative_geometry)
    assert any("negative @length=-3" in w.message and w.road == "1" and w.line for w in odr.warnings)


def test_unknown_geometry_element_is_a_warning_with_location():
    odr = loads_opendrive(document(road_xml(
        LINE + '<geometry s="10" x="10" y="0" hdg="0" length="5"><clothoid k="1"/></geometry>', 15)))
    warning = next(w for w in odr.warnings if "unknown geometry element <clothoid>" in w.message)
    assert warning.road == "1" and warning.line is not None


def test_dangling_links_are_warnings():
    link = '<link><successor elementType="road" elementId="999" contactPoint="start"/></link>'
    odr = loads_opendrive(document(road_xml(LINE, 10, link=link)))
    assert any(w.message == "successor links to missing road 999" and w.road == "1" for w in odr.warnings)


def test_wrong_root_and_leading_comment(tmp_path):
    with pytest.raises(InputError, match="root element is <osm>, expected <OpenDRIVE>"):
        loads_opendrive('<?xml version="1.0"?><osm/>')
    text = "<!-- licence text\nsecond line -->\n" + document(road_xml(LINE, 10))
    odr = loads_opendrive("\ufeff" + text)
    assert len(odr.roads) == 1
    # line numbers still count the skipped comment
    broken = "<!-- licence\n-->\n" + document(road_xml(LINE.replace('x="0"', 'x="abc"'), 10))
    with pytest.raises(InputError) as error:
        loads_opendrive(broken, "c.xodr")
    assert str(error.value).startswith("c.xodr:9:")


def test_bad_numbers_in_lanes():
    lanes = ('<laneSection s="0"><center><lane id="0" type="none"/></center><right>'
             '<lane id="-1.5" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection>')
    with pytest.raises(InputError, match="@id='-1.5' is not an integer"):
        loads_opendrive(document(road_xml(LINE, 10, lanes=lanes)))
