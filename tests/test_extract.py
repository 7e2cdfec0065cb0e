"""`mapkit extract`: complete-ways extracts checked against an independent count, and hostile/broken input."""

from __future__ import annotations

import gzip
import json
from collections import Counter
from pathlib import Path

import pytest
from click.testing import CliRunner
from lxml import etree

from tavf_mapkit.cli.main import cli
from tavf_mapkit.errors import InputError
from tavf_mapkit.osm.area import load_polygon, parse_bbox
from tavf_mapkit.osm.extract import extract

JUNGFERNSTIEG = ("hamburg", "jungfernstieg_osm", "jungfernstieg_2023-03-10.osm")
BBOX = (9.99, 53.55, 10.0, 53.555)  # Jungfernstieg / Binnenalster corner, part of the file


def run(*args: str):
    return CliRunner().invoke(cli, [str(a) for a in args])


def independent_extract(path: Path, inside) -> dict:
    """What a complete-ways extract must contain, counted with lxml and plain Python only."""
    root = etree.parse(str(path)).getroot()
    location = {int(n.get("id")): (float(n.get("lon")), float(n.get("lat"))) for n in root.iter("node")}
    inside_ids = {node_id for node_id, (lon, lat) in location.items() if inside(lon, lat)}
    ways, nodes, highways = set(), set(inside_ids), Counter()
    for way in root.iter("way"):
        refs = [int(nd.get("ref")) for nd in way.iter("nd")]
        if any(ref in inside_ids for ref in refs):
            ways.add(int(way.get("id")))
            nodes.update(refs)
            tags = {tag.get("k"): tag.get("v") for tag in way.iter("tag")}
            if "highway" in tags:
                highways[tags["highway"]] += 1
    return {"ways": ways, "nodes": nodes, "highways": highways}


def written_ids(path: Path) -> tuple[set[int], set[int]]:
    root = etree.parse(str(path)).getroot()
    return {int(n.get("id")) for n in root.iter("node")}, {int(w.get("id")) for w in root.iter("way")}


def point_in_polygon(lon: float, lat: float, ring: list[tuple[float, float]]) -> bool:
    """Ray casting, written out here so the test does not share code with the implementation."""
    inside = False
    for (x1, y1), (x2, y2) in zip(ring, ring[1:] + ring[:1], strict=True):
        if (y1 > lat) != (y2 > lat) and lon < x1 + (lat - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def test_bbox_extract_agrees_with_an_independent_count(shared, tmp_path):
    source = shared(*JUNGFERNSTIEG)
    west, south, east, north = BBOX
    expected = independent_extract(source, lambda lon, lat: west <= lon <= east and south <= lat <= north)
    output = tmp_path / "part.osm"

    summary = extract(source, output, parse_bbox(",".join(map(str, BBOX))))

    nodes, ways = written_ids(output)
    assert ways == expected["ways"]
    assert nodes == expected["nodes"]  # complete ways: every node of every kept way
    assert summary.ways == len(expected["ways"]) and summary.nodes == len(expected["nodes"])
    assert summary.highway_ways == expected["highways"]
    assert 0 < summary.ways < 700


def test_polygon_extract_agrees_with_an_independent_count(shared, tmp_path):
    source = shared(*JUNGFERNSTIEG)
    ring = [(9.990, 53.550), (10.000, 53.551), (9.996, 53.556)]  # a triangle over the Binnenalster corner
    geojson = tmp_path / "area.geojson"
    polygon = {"type": "Polygon", "coordinates": [[*map(list, ring), list(ring[0])]]}
    feature = {"type": "Feature", "properties": {}, "geometry": polygon}
    geojson.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    expected = independent_extract(source, lambda lon, lat: point_in_polygon(lon, lat, ring))

    result = run("extract", source, "--polygon", geojson, "-o", tmp_path / "tri.osm", "--json")

    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    nodes, ways = written_ids(tmp_path / "tri.osm")
    assert ways == expected["ways"] and nodes == expected["nodes"]
    assert summary["ways"] == len(expected["ways"])
    assert summary["area"]["description"] == "polygon area.geojson"
    assert summary["highway_ways"] == dict(expected["highways"])


def test_without_an_area_the_whole_file_is_rewritten(shared, tmp_path):
    source = shared(*JUNGFERNSTIEG)
    summary = extract(source, tmp_path / "all.osm")
    assert (summary.nodes, summary.ways) == (3154, 700)  # SOURCE.txt
    assert summary.buildings > 0 and summary.highway_ways["footway"] > 0
    assert written_ids(tmp_path / "all.osm") == written_ids(source)


def test_formats_round_trip_through_pbf_gz_and_bz2(shared, tmp_path):
    source = shared("osm_small", "berlin-siegessaeule.osm.gz")
    first = extract(source, tmp_path / "a.osm.pbf", parse_bbox("13.345,52.512,13.352,52.516"))
    second = extract(tmp_path / "a.osm.pbf", tmp_path / "b.osm.bz2")
    third = extract(tmp_path / "b.osm.bz2", tmp_path / "c.osm.gz")
    assert (first.nodes, first.ways, first.relations) == (third.nodes, third.ways, third.relations)
    assert second.traffic_signals == third.traffic_signals > 0
    assert gzip.decompress((tmp_path / "c.osm.gz").read_bytes()).startswith(b"<?xml")


def test_routes_are_kept_only_when_asked(shared, tmp_path):
    source = shared("osm_small", "berlin-siegessaeule.osm.gz")
    without = extract(source, tmp_path / "a.osm", parse_bbox("13.30,52.50,13.40,52.52"))
    with_routes = extract(source, tmp_path / "b.osm", parse_bbox("13.30,52.50,13.40,52.52"), routes=True)
    assert without.routes == 0 and with_routes.routes > 0


def test_human_summary_names_counts_by_highway_type(shared, tmp_path):
    bbox = ",".join(map(str, BBOX))
    result = run("extract", shared(*JUNGFERNSTIEG), "--bbox", bbox, "-o", tmp_path / "x.osm")
    assert result.exit_code == 0
    assert "highway ways:" in result.stdout and "footway" in result.stdout
    assert "traffic signals:" in result.stdout and "buildings:" in result.stdout


def test_an_empty_extract_is_refused_with_a_hint(shared, tmp_path):
    output = tmp_path / "empty.osm"
    # lat,lon swapped: the common mistake; nothing is inside
    result = run("extract", shared(*JUNGFERNSTIEG), "--bbox", "53.55,9.99,53.56,10.0", "-o", output)
    assert result.exit_code == 2
    assert "empty extract" in result.stderr and "W,S,E,N" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not output.exists() and not list(tmp_path.iterdir())


def one_line_error(result, code: int = 2) -> str:
    assert result.exit_code == code, result.output
    assert isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_truncated_osm_is_a_one_line_error(shared, tmp_path):
    broken = tmp_path / "truncated.osm"
    broken.write_bytes(shared(*JUNGFERNSTIEG).read_bytes()[:200_000])
    message = one_line_error(run("extract", broken, "-o", tmp_path / "out.osm"))
    assert "truncated.osm:" in message and "not well-formed" in message
    assert not (tmp_path / "out.osm").exists()


def test_a_pbf_that_is_not_pbf_is_a_one_line_error(tmp_path):
    fake = tmp_path / "fake.osm.pbf"
    fake.write_text("<osm version='0.6'></osm>\n")
    message = one_line_error(run("extract", fake, "-o", tmp_path / "out.osm"))
    assert "not a valid OSM PBF file" in message


def test_a_missing_file_is_a_one_line_error(tmp_path):
    message = one_line_error(run("extract", tmp_path / "nope.osm", "-o", tmp_path / "out.osm"))
    assert message == f"Error: {tmp_path / 'nope.osm'}: file not found"


def test_an_unknown_suffix_is_refused(tmp_path):
    other = tmp_path / "data.txt"
    other.write_text("hello")
    assert "must end in one of" in one_line_error(run("extract", other, "-o", tmp_path / "out.osm"))


def test_an_unwritable_output_is_a_one_line_error(shared, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    message = one_line_error(run("extract", shared(*JUNGFERNSTIEG), "-o", blocker / "out.osm"))
    assert "cannot write" in message


def test_bbox_and_polygon_together_are_a_usage_error(shared, tmp_path):
    result = run("extract", shared(*JUNGFERNSTIEG), "--bbox", "9,53,10,54",
                 "--polygon", tmp_path / "a.geojson", "-o", tmp_path / "out.osm")
    assert result.exit_code == 2 and "not both" in result.stderr


@pytest.mark.parametrize("text", ["1,2,3", "a,b,c,d", "10,53,9,54", "9,54,10,53", "200,0,201,1"])
def test_malformed_bbox_is_a_usage_error(text, tmp_path):
    result = run("extract", tmp_path / "x.osm", "--bbox", text, "-o", tmp_path / "out.osm")
    assert result.exit_code == 2 and "bbox" in result.stderr


def test_polygon_files_are_checked(tmp_path):
    bad = tmp_path / "bad.geojson"
    bad.write_text('{"type": "Point", "coordinates": [9.9, 53.5]}')
    with pytest.raises(InputError, match="Polygon or MultiPolygon"):
        load_polygon(bad)
    bad.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_polygon(bad)


# --- hostile XML: osmium re-writes every OSM input before netconvert's parser sees it -----------------

PASSWD_MARKERS = ("root:", "/bin/", "nologin")

HOSTILE = {
    "external-entity": '<!DOCTYPE osm [<!ENTITY x SYSTEM "file:///etc/passwd">]>',
    "parameter-entity": '<!DOCTYPE osm [<!ENTITY % p SYSTEM "file:///etc/passwd"> %p;]>',
    "billion-laughs": '<!DOCTYPE osm [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>',
    "external-dtd": '<!DOCTYPE osm SYSTEM "file:///etc/passwd">',
}


def hostile_osm(tmp_path: Path, kind: str) -> Path:
    value = {"external-entity": "&x;", "billion-laughs": "&b;"}.get(kind, "plain")
    path = tmp_path / f"{kind}.osm"
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f"{HOSTILE[kind]}\n"
        '<osm version="0.6" generator="test">\n'
        f'  <node id="1" version="1" lat="53.55" lon="9.99"><tag k="name" v="{value}"/></node>\n'
        '  <node id="2" version="1" lat="53.551" lon="9.991"/>\n'
        '  <way id="10" version="1"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/></way>\n'
        "</osm>\n")
    return path


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_hostile_xml_is_refused_or_never_expanded(kind, tmp_path):
    output = tmp_path / "out.osm"
    result = run("extract", hostile_osm(tmp_path, kind), "-o", output)
    if result.exit_code == 0:
        text = output.read_text()
        assert "DOCTYPE" not in text and "ENTITY" not in text
    else:
        assert "XML entities" in one_line_error(result)
        assert not output.exists()
    everything = result.output + (output.read_text() if output.exists() else "")
    assert not any(marker in everything for marker in PASSWD_MARKERS)


def test_entity_declarations_are_refused_not_expanded(tmp_path):
    # what osmium's reader does with a DOCTYPE that declares entities: it refuses the whole file
    result = run("extract", hostile_osm(tmp_path, "external-entity"), "-o", tmp_path / "out.osm")
    assert "refused: the file declares XML entities" in one_line_error(result)


def test_an_external_dtd_is_not_loaded_and_dropped_from_the_output(tmp_path):
    output = tmp_path / "out.osm"
    assert run("extract", hostile_osm(tmp_path, "external-dtd"), "-o", output).exit_code == 0
    assert "DOCTYPE" not in output.read_text()


def test_a_node_with_a_non_numeric_coordinate_is_a_one_line_error(tmp_path):
    source = tmp_path / "bad.osm"
    source.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6">\n'
        '  <node id="1" lat="53.55" lon="9.99"/>\n  <node id="2" lat="abc" lon="9.991"/>\n'
        '  <way id="100"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/></way>\n</osm>\n')
    result = run("extract", source, "-o", tmp_path / "out.osm")
    assert result.exit_code == 2
    assert one_line_error(result) == (f"Error: {source}: a node has an invalid location "
                                      "(wrong format for coordinate: 'abc')")
    assert not (tmp_path / "out.osm").exists()
