"""mapkit validate: API, JSON contract, CLI, rule selection, structure rules, schema, catalogue."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.validate import Finding, all_rules, select_rules, validate_file, validate_map
from tavf_mapkit.validate.catalogue import catalogue_in, render_catalogue
from tests.validate_network import network_text, write_network
from tests.xodr_factory import document, road_xml

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path, text: str, name: str = "map.xodr") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_json_contract(tmp_path):
    path = write_network(tmp_path, road4_right_width='<width sOffset="0" a="3" b="-0.2" c="0" d="0"/>')
    data = validate_file(path).to_dict()
    assert set(data) == {"file", "findings", "summary"} and data["file"] == str(path)
    finding = next(f for f in data["findings"] if f["rule"] == "geometry.negative-width")
    assert set(finding) == {"rule", "severity", "road", "lane", "s", "line", "message"}
    assert (finding["severity"], finding["road"], finding["lane"], finding["s"]) == ("error", "4", -1, 30.0)
    assert isinstance(finding["line"], int)
    summary = data["summary"]
    assert summary["errors"] == 1 and summary["exit_code"] == 1 and summary["by_rule"]["geometry.negative-width"] == 1
    assert summary["rules_run"] == len(all_rules())
    json.dumps(data)  # serialisable as it is


def test_finding_is_immutable():
    finding = Finding("geometry.gap", "error", "1", None, 2.0, 5, "gap")
    with pytest.raises(AttributeError):
        finding.road = "2"


def test_cli_text_json_and_exit_codes(tmp_path):
    runner = CliRunner()
    clean = write_network(tmp_path, "clean.xodr")
    result = runner.invoke(cli, ["validate", str(clean)])
    assert result.exit_code == 0, result.output
    assert "0 errors, 0 warnings, 2 notes" in result.output
    broken = write_network(tmp_path, "broken.xodr",
                           road2_successor='<successor elementType="road" elementId="99" contactPoint="start"/>')
    result = runner.invoke(cli, ["validate", str(broken), "--json"])
    assert result.exit_code == 1
    data = json.loads(result.output)
    assert [f["road"] for f in data["findings"] if f["rule"] == "topology.missing-road"] == ["2"]
    out = tmp_path / "report.json"
    result = runner.invoke(cli, ["validate", str(broken), "--json", "-o", str(out)])
    assert result.exit_code == 1 and json.loads(out.read_text())["summary"]["errors"] >= 1


def test_cli_unreadable_file_is_exit_2_with_one_line(tmp_path):
    runner = CliRunner()
    result = runner.invoke(cli, ["validate", str(tmp_path / "missing.xodr")])
    assert result.exit_code == 2 and result.output.strip().endswith("missing.xodr: file not found")
    broken = write(tmp_path, "<OpenDRIVE><header>\n<road", "broken.xodr")
    result = runner.invoke(cli, ["validate", str(broken)])
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and "broken.xodr:2: not well-formed XML" in result.output
    assert "Traceback" not in result.output


def test_cli_strict_and_rule_selection(tmp_path):
    runner = CliRunner()
    path = write_network(tmp_path, header_extra="")  # no geoReference: one warning
    assert runner.invoke(cli, ["validate", str(path)]).exit_code == 0
    result = runner.invoke(cli, ["validate", str(path), "--strict", "--json"])
    assert result.exit_code == 1
    assert [f["severity"] for f in json.loads(result.output)["findings"] if f["rule"] == "georeference.missing"] \
        == ["error"]
    result = runner.invoke(cli, ["validate", str(path), "--rules", "geometry", "--strict"])
    assert result.exit_code == 0  # the georeference family did not run
    result = runner.invoke(cli, ["validate", str(path), "--rules", "geometry.gpa"])
    assert result.exit_code == 2 and "unknown rule 'geometry.gpa'" in result.output


def test_select_rules():
    assert {r.family for r in select_rules("geometry")} == {"geometry"}
    assert [r.id for r in select_rules("topology.contact-gap, geometry.gap")] == ["geometry.gap",
                                                                                  "topology.contact-gap"]
    assert len(select_rules(None)) == len(select_rules("")) == len(all_rules())
    with pytest.raises(ValueError, match="unknown rule 'nope'"):
        select_rules(["nope"])


def test_validate_map_runs_map_rules_only(tmp_path):
    odr = load_opendrive(write_network(tmp_path, road1_right_successor=-5))
    report = validate_map(odr)
    assert [f.road for f in report.by_rule("topology.lane-link-target")] == ["1"]
    assert all(rule.needs == "map" for rule in all_rules().values() if rule.id in report.rules)
    assert "structure.s-order" in report.skipped


def test_reader_refusal_becomes_findings(tmp_path):
    path = write(tmp_path, network_text().replace('length="100.0" junction', 'length="long" junction', 1))
    report = validate_file(path)
    [number] = report.by_rule("structure.number")
    [readable] = report.by_rule("structure.readable")
    assert number.road == "1" and "@length='long'" in number.message
    assert readable.road == "1" and readable.line == number.line
    assert report.exit_code == 1 and "geometry.gap" in report.skipped


def test_wrong_root(tmp_path):
    report = validate_file(write(tmp_path, "<?xml version='1.0'?>\n<OpenSCENARIO><header/></OpenSCENARIO>\n"))
    [root] = report.by_rule("structure.root")
    assert root.line == 2 and "<OpenSCENARIO>" in root.message


def test_line_numbers_survive_a_leading_comment(tmp_path):
    text = "<!-- licence\n\n-->\n" + network_text().replace("<planView>", "<planView><geomtry/>", 1)
    report = validate_file(write(tmp_path, text))
    [unknown] = report.by_rule("structure.unknown-element")
    assert "<geomtry/>" in text.splitlines()[unknown.line - 1]


def test_required_attributes_numbers_and_header(tmp_path):
    text = network_text().replace('<width sOffset="0" a="3.5"', '<width a="nan"', 1)
    text = text.replace('revMajor="1" ', "")
    report = validate_file(write(tmp_path, text))
    [missing] = [f for f in report.by_rule("structure.required-attribute") if f.road == "1"]
    assert "@sOffset" in missing.message
    assert any("@a='nan'" in f.message for f in report.by_rule("structure.number"))
    assert any("@revMajor" in f.message for f in report.by_rule("structure.header"))


def test_param_poly3_length(tmp_path):
    """A normalised paramPoly3 u = 10 p, v = 0 is a 10 m straight line; @length says otherwise."""
    def road(length):
        geometry = (f'<geometry s="0" x="0" y="0" hdg="0" length="{length}"><paramPoly3 aU="0" bU="10" cU="0" dU="0" '
                    'aV="0" bV="0" cV="0" dV="0" pRange="normalized"/></geometry>')
        return document(road_xml(geometry, length))
    assert not validate_file(write(tmp_path, road(10.0), "exact.xodr")).by_rule("geometry.param-poly3-length")
    [finding] = validate_file(write(tmp_path, road(10.05), "off.xodr")).by_rule("geometry.param-poly3-length")
    assert "-0.05 m" in finding.message and finding.road == "1"


def test_param_poly3_arc_length_of_a_parabola(tmp_path):
    """u = p, v = p^2 with pRange arcLength and @length 2: p runs over [0, 2], the true length is the closed form
    integral of sqrt(1 + 4 p^2), 4.6468 m -- 2.65 m more than @length says."""
    import math

    from tavf_mapkit.validate.geometry import param_poly3_arc_lengths

    exact = math.sqrt(17.0) + math.asinh(4.0) / 4.0
    geometry = ('<geometry s="0" x="0" y="0" hdg="0" length="2"><paramPoly3 aU="0" bU="1" cU="0" dU="0" '
                'aV="0" bV="0" cV="1" dV="0" pRange="arcLength"/></geometry>')
    path = write(tmp_path, document(road_xml(geometry, 2.0)))
    table = load_opendrive(path).arrays.geometries
    assert param_poly3_arc_lengths(table, [0])[0] == pytest.approx(exact, abs=1e-9)
    [finding] = validate_file(path).by_rule("geometry.param-poly3-length")
    assert f"{exact - 2:+.4g} m" in finding.message


def test_border_crossing(tmp_path):
    lanes = """
        <laneSection s="0">
          <left><lane id="1" type="driving" level="false"><border sOffset="0" a="3" b="-0.2" c="0" d="0"/></lane></left>
          <center><lane id="0" type="none" level="false"/></center>
        </laneSection>"""
    text = document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="30"><line/></geometry>', 30.0, lanes))
    [finding] = validate_file(write(tmp_path, text)).by_rule("geometry.border-crossing")
    assert (finding.road, finding.lane) == ("1", 1) and finding.s == pytest.approx(15.25)


def test_elevation_and_lane_offset_jumps(tmp_path):
    profile = ('<elevationProfile><elevation s="0" a="0" b="0" c="0" d="0"/>'
               '<elevation s="10" a="0.5" b="0" c="0" d="0"/></elevationProfile>')
    offset = '<laneOffset s="0" a="0" b="0" c="0" d="0"/><laneOffset s="20" a="0.3" b="0" c="0" d="0"/>'
    text = document(road_xml('<geometry s="0" x="0" y="0" hdg="0" length="30"><line/></geometry>', 30.0,
                             extra=profile, lane_offset=offset))
    report = validate_file(write(tmp_path, text))
    [elevation] = report.by_rule("geometry.elevation-jump")
    [jump] = report.by_rule("geometry.border-jump")
    assert elevation.s == 10.0 and "+0.5 m" in elevation.message
    assert jump.s == 20.0 and "lane offset" in jump.message


def test_duplicate_ids_and_zero_length_road(tmp_path):
    geometry = '<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
    text = document(road_xml(geometry, 10.0, road_id="7"), road_xml(geometry, 10.0, road_id="7"),
                    road_xml('<geometry s="0" x="0" y="0" hdg="0" length="0"><line/></geometry>', 0.0, road_id="8"))
    report = validate_file(write(tmp_path, text))
    assert [f.road for f in report.by_rule("topology.duplicate-id")] == ["7"]
    assert [f.road for f in report.by_rule("geometry.zero-length-road")] == ["8"]
    assert [f.road for f in report.by_rule("geometry.zero-length-geometry")] == ["8"]


def test_junction_consistency(tmp_path):
    text = network_text().replace('connectingRoad="3" contactPoint="start"><laneLink from="-1" to="-1"/>',
                                  'connectingRoad="1" contactPoint="start"><laneLink from="-1" to="-7"/>')
    report = validate_file(write(tmp_path, text))
    [membership] = report.by_rule("topology.junction-connection")
    [lane] = report.by_rule("topology.junction-lane-link")
    assert membership.road == "1" and "belongs to no junction" in membership.message
    assert lane.road == "1" and lane.lane == -7


def test_schema_validation_with_a_schema_folder(tmp_path):
    """The schema rule uses a folder in asam-qc-opendrive's layout; here a tiny schema of our own."""
    folder = tmp_path / "xsd" / "1.6.1"
    folder.mkdir(parents=True)
    (folder / "opendrive_16_core.xsd").write_text("""<?xml version="1.0"?>
<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema">
  <xs:element name="OpenDRIVE"><xs:complexType><xs:sequence>
    <xs:element name="header"><xs:complexType><xs:sequence><xs:any processContents="skip" minOccurs="0"
      maxOccurs="unbounded"/></xs:sequence><xs:anyAttribute processContents="skip"/></xs:complexType></xs:element>
    <xs:element name="road" maxOccurs="unbounded"><xs:complexType><xs:sequence><xs:any processContents="skip"
      minOccurs="0" maxOccurs="unbounded"/></xs:sequence><xs:attribute name="id" type="xs:string"/>
      <xs:attribute name="length" type="xs:double"/><xs:attribute name="junction" type="xs:string"/>
    </xs:complexType></xs:element>
  </xs:sequence></xs:complexType></xs:element>
</xs:schema>""")
    path = write_network(tmp_path)  # has a <junction>, which this schema does not allow
    report = validate_file(path, schema_dir=tmp_path / "xsd")
    assert report.summary["schema"]["status"] == "invalid"
    [finding] = report.by_rule("structure.schema")
    assert "junction" in finding.message and "<junction" in path.read_text().splitlines()[finding.line - 1]
    without = validate_file(path, schema_dir=tmp_path / "empty")
    assert without.summary["schema"]["status"] in ("unavailable", "valid", "invalid")  # an installed qc package


def test_docs_catalogue_matches_the_registry():
    document_text = (REPO / "docs" / "validation-rules.md").read_text()
    assert catalogue_in(document_text) == render_catalogue(), \
        "docs/validation-rules.md is stale: python -m tavf_mapkit.validate.catalogue docs/validation-rules.md"
    for rule in all_rules().values():
        assert rule.why and rule.summary and rule.severity in ("error", "warning", "info")


def test_hostile_xml_is_refused(tmp_path):
    text = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">]>\n<OpenDRIVE><header/></OpenDRIVE>')
    with pytest.raises(InputError, match="entity"):
        validate_file(write(tmp_path, text))
