"""The netconvert stage: profiles, projection, the <offset> sign convention, warnings and failures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import pytest
from lxml import etree

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.netconvert import (
    Messages,
    convert,
    find_netconvert,
    load_profile,
    netconvert_version,
    option_arguments,
    warning_kind,
)
from tavf_mapkit.osm.extract import extract
from tavf_mapkit.projection import as_tmerc, proj_parameters, read_xodr_georeference, tmerc_centred_on
from tavf_mapkit.sumonet import read_location

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"
JUNGFERNSTIEG = ("hamburg", "jungfernstieg_osm", "jungfernstieg_2023-03-10.osm")
TAVF_NET = ("hamburg", "tavf_dlr_sumo_net", "network.net.xml.gz")
CARLA_TYPES = [f"highway.{kind}" for kind in (
    "motorway", "motorway_link", "trunk", "trunk_link", "primary", "primary_link",
    "secondary", "secondary_link", "tertiary", "tertiary_link", "unclassified", "residential")]


def convert_osm(source: Path, folder: Path, profile: str = "carla", **options):
    """Sanitise like the extract stage, then convert; returns (conversion, centre)."""
    clean = folder / "in.osm"
    summary = extract(source, clean)
    conversion = convert(clean, "osm", folder / "out.net.xml", folder / "out.xodr", folder / "netconvert.log",
                         load_profile(profile), centre=summary.centre, **options)
    return conversion, summary.centre


def xodr_reference_points(xodr: Path) -> np.ndarray:
    root = etree.parse(str(xodr)).getroot()
    return np.array([[float(g.get("x")), float(g.get("y"))] for g in root.iter("geometry")])


def osm_node_lonlat(osm: Path) -> np.ndarray:
    root = etree.parse(str(osm)).getroot()
    return np.array([[float(n.get("lon")), float(n.get("lat"))] for n in root.iter("node")])


def assert_georeference_usable(xodr: Path) -> dict:
    """The geoReference parses with pyproj and carries +lat_0/+lon_0 (what CARLA reads)."""
    georeference = read_xodr_georeference(xodr)
    crs = pyproj.CRS.from_user_input(georeference["proj"])
    parameters = proj_parameters(georeference["proj"])
    assert "lat_0" in parameters and "lon_0" in parameters
    assert crs.is_projected
    return georeference


# --- profiles -----------------------------------------------------------------------------------------


def test_carla_profile_is_what_carlas_osm2odr_passes():
    carla = load_profile("carla")
    assert carla.osm["keep-edges.by-type"] == CARLA_TYPES
    for flag in ("geometry.remove", "ramps.guess", "edges.join", "junctions.join", "roundabouts.guess",
                 "tls.discard-loaded", "tls.discard-simple"):
        assert carla.osm[flag] is True
    assert carla.osm["default.lanewidth"] == 4.0
    assert carla.options_for("sumo-net") == {}  # nothing that re-guesses a hand-edited SUMO network


def test_full_profile_extends_carla():
    full, carla = load_profile("full"), load_profile("carla")
    osm = full.options_for("osm")
    assert {key: osm[key] for key in carla.osm} == carla.osm
    for flag in ("sidewalks.guess", "crossings.guess", "osm.turn-lanes", "osm.lane-access",
                 "tls.guess-signals", "output.original-names"):
        assert osm[flag] is True
    assert osm["junctions.scurve-stretch"] == 1.0 and osm["osm.layer-elevation"] == 6.0


def test_option_arguments():
    assert option_arguments({"a.b": True, "c": False, "d": 4.0, "e": ["x", "y"], "f": "s t"}) == [
        "--a.b=true", "--c=false", "--d=4.0", "--e=x,y", "--f=s t"]


def test_unknown_profiles_and_bad_profile_files_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="unknown netconvert profile 'nope'.*carla"):
        load_profile("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text('[osm]\n"x" = {a = 1}\n')
    with pytest.raises(InputError, match="option x"):
        load_profile(bad)
    bad.write_text('[extra]\n')
    with pytest.raises(InputError, match="unknown keys"):
        load_profile(bad)


# --- the binary ---------------------------------------------------------------------------------------


def test_netconvert_of_the_wheel_is_found_and_versioned():
    binary = find_netconvert()
    assert binary.is_file()
    assert netconvert_version().startswith("Eclipse SUMO netconvert ")


# --- messages -----------------------------------------------------------------------------------------


def test_warnings_are_counted_by_kind_and_errors_keep_their_continuation():
    messages = Messages()
    messages.add_output(
        "Warning: Could not compute smooth shape for edge '24407070#0'.\n"
        "Warning: Could not compute smooth shape for edge '711090310#0'.\n"
        "Warning: Reducing junction cluster -794,-795,-798 (not compact (maxEdge=23182274#3 length=8.76)).\n"
        "Error: On processing option '--bogus':\n No option with the name 'bogus' exists.\n"
        "Quitting (on error).\n")
    assert messages.warnings["Could not compute smooth shape for edge '%'."] == 2
    kind = warning_kind("Reducing junction cluster -794,-795 (not compact (maxEdge=23182274#3 length=8.76)).")
    assert kind == "Reducing junction cluster # (not compact (maxEdge=# length=#))."
    assert messages.errors == ["On processing option '--bogus': No option with the name 'bogus' exists."]
    assert messages.to_dict()["warnings"] == 3


# --- conversions --------------------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["carla", "full"])
def test_sample_converts_cleanly_under_both_profiles(profile, tmp_path):
    conversion, centre = convert_osm(SAMPLE, tmp_path, profile)
    assert conversion.messages.errors == [] and sum(conversion.messages.warnings.values()) == 0
    georeference = assert_georeference_usable(tmp_path / "out.xodr")
    assert georeference["proj"] == tmerc_centred_on(*centre)
    assert centre == (9.975, 53.556)  # the synthetic district is laid out around its centre
    net = etree.parse(str(tmp_path / "out.net.xml")).getroot()
    assert net.find("location").get("projParameter") == georeference["proj"]
    assert len(net.findall("tlLogic")) == 1  # the signalised junction


def _offset_xy(georeference: dict) -> tuple[float, float]:
    offset = georeference["offset"] or {"x": 0.0, "y": 0.0, "hdg": 0.0}
    assert offset.get("hdg", 0) == 0
    return offset["x"], offset["y"]


@pytest.mark.parametrize("crs", ["tmerc", "utm"])
def test_offset_is_the_negated_net_offset_and_projected_is_local_plus_offset(crs, tmp_path):
    """The sign convention georeference code relies on, checked with coordinates, not just attributes.

    With the centred tmerc the network is not shifted at all (local (0, 0) = +lat_0/+lon_0, what CARLA
    assumes); with UTM netconvert shifts it to (0, 0) and writes the negated netOffset into <offset>.
    """
    convert_osm(SAMPLE, tmp_path, crs=crs)
    net_offset = read_location(tmp_path / "out.net.xml").net_offset
    georeference = read_xodr_georeference(tmp_path / "out.xodr")
    offset = _offset_xy(georeference)
    assert offset == (-net_offset[0], -net_offset[1])
    if crs == "tmerc":
        assert georeference["offset"] is None and tuple(net_offset) == (0.0, 0.0)
    else:
        assert min(abs(offset[0]), abs(offset[1])) > 1000  # UTM eastings/northings, shifted to (0, 0)

    to_wgs84 = pyproj.Transformer.from_crs(georeference["proj"], "EPSG:4326", always_xy=True)
    to_metres = pyproj.Transformer.from_crs("EPSG:4326", georeference["proj"], always_xy=True)
    nodes = np.column_stack(to_metres.transform(*osm_node_lonlat(SAMPLE).T))
    local = xodr_reference_points(tmp_path / "out.xodr")

    def distance_to_nearest_node(projected):
        lon, lat = to_wgs84.transform(projected[:, 0], projected[:, 1])
        points = np.column_stack(to_metres.transform(lon, lat))
        return np.sqrt(((points[:, None, :] - nodes[None, :, :]) ** 2).sum(-1)).min(1)

    right = distance_to_nearest_node(local + np.array(offset))
    assert np.median(right) < 60 and right.max() < 160  # roads run between OSM nodes up to 150 m apart
    if crs == "utm":
        wrong = distance_to_nearest_node(local - np.array(offset))
        assert np.median(wrong) > 300


def junctions_off_their_osm_nodes(net: Path, osm: Path) -> np.ndarray:
    """Metres between each junction that is an OSM node (same id) and that node, the junction placed on Earth
    by the network's own projParameter: where the georeference puts the network, whatever its plane."""
    root = etree.parse(str(net)).getroot()
    to_wgs84 = pyproj.Transformer.from_crs(root.find("location").get("projParameter"), "EPSG:4326",
                                           always_xy=True)
    nodes = {n.get("id"): (float(n.get("lon")), float(n.get("lat"))) for n in etree.parse(str(osm)).iter("node")}
    junctions = [j for j in root.iter("junction") if j.get("id") in nodes and j.get("type") != "internal"]
    lon, lat = to_wgs84.transform([float(j.get("x")) for j in junctions], [float(j.get("y")) for j in junctions])
    osm_lon, osm_lat = np.array([nodes[j.get("id")] for j in junctions]).T
    return pyproj.Geod(ellps="WGS84").inv(lon, lat, osm_lon, osm_lat)[2]


def network_centre(net: Path) -> tuple[float, float, float]:
    """(x, y) of the middle of the network's convBoundary and its half-diagonal (m)."""
    west, south, east, north = read_location(net).conv_boundary
    return 0.5 * (west + east), 0.5 * (south + north), 0.5 * float(np.hypot(east - west, north - south))


@pytest.mark.parametrize("name, centred", [("berlin-siegessaeule.osm.gz", False), ("krautsand.osm.gz", True)])
def test_small_real_osm_files_convert_with_a_usable_georeference(name, centred, shared, tmp_path):
    """Berlin's roads lie around the middle of its extract (476 m off, within OFF_CENTRE_M: one run);
    Krautsand's extract reaches 2.6 km beyond its roads, so the projection is centred on the network."""
    conversion, centre = convert_osm(shared("osm_small", name), tmp_path)
    georeference = assert_georeference_usable(tmp_path / "out.xodr")
    parameters = proj_parameters(georeference["proj"])
    assert ((float(parameters["lon_0"]), float(parameters["lat_0"])) == centre) is not centred
    assert len(conversion.commands) == 1 + centred
    x, y, half = network_centre(tmp_path / "out.net.xml")
    if centred:
        assert np.hypot(x, y) < 0.01 * half, (x, y)
        assert georeference["proj"] == conversion.projection != tmerc_centred_on(*centre)
        assert "centred the projection on the road network" in conversion.notes[0]
    # netconvert writes the net's coordinates with 2 decimals: each junction on an OSM node within 1 cm of it
    assert junctions_off_their_osm_nodes(tmp_path / "out.net.xml", tmp_path / "in.osm").max() < 0.01
    assert conversion.messages.errors == []


def _with_a_far_river(source: Path, target: Path) -> Path:
    """``source`` plus a river 3.5-5.5 km east of it: nodes of a way the profiles do not import."""
    nodes = ('  <node id="-9001" version="1" lat="53.556" lon="10.03"/>\n'
             '  <node id="-9002" version="1" lat="53.557" lon="10.06"/>\n')
    way = '  <way id="-9100" version="1"><nd ref="-9001"/><nd ref="-9002"/><tag k="waterway" v="river"/></way>\n'
    text = source.read_text(encoding="utf-8")
    first_way = text.index("  <way ")  # OSM order: nodes, then ways
    target.write_text(text[:first_way] + nodes + text[first_way:].replace("</osm>", way + "</osm>"),
                      encoding="utf-8")
    return target


def test_nodes_beyond_the_roads_do_not_move_the_origin_off_the_network(tmp_path):
    """The extract's centre lies 2.7 km east of the sample's roads once a river is added; netconvert runs again
    with the projection centred on the network, which lands where the plain sample's does: its projection
    centre within 1e-6 degrees, its junctions on their OSM nodes, the same roads and lanes."""
    plain, far = tmp_path / "plain", tmp_path / "far"
    plain.mkdir(), far.mkdir()
    plain_conversion, plain_centre = convert_osm(SAMPLE, plain)
    conversion, centre = convert_osm(_with_a_far_river(SAMPLE, tmp_path / "far.osm"), far)
    assert centre[0] - plain_centre[0] > 0.03  # the river drew the extract's centre east
    assert len(plain_conversion.commands) == 1 and len(conversion.commands) == 2
    assert f"its centre lay 2667 m from the origin of {tmerc_centred_on(*centre)!r}" in conversion.notes[0]
    parameters = proj_parameters(read_xodr_georeference(far / "out.xodr")["proj"])
    assert abs(float(parameters["lon_0"]) - plain_centre[0]) < 1e-6
    assert abs(float(parameters["lat_0"]) - plain_centre[1]) < 1e-6
    x, y, _ = network_centre(far / "out.net.xml")
    assert np.hypot(x, y) < 0.05
    assert junctions_off_their_osm_nodes(far / "out.net.xml", far / "in.osm").max() < 0.01

    def lanes(folder):
        root = etree.parse(str(folder / "out.xodr")).getroot()
        return sorted((road.get("id"), len(road.findall(".//lane"))) for road in root.iter("road"))

    assert lanes(far) == lanes(plain)
    # the river's one warning, counted once: the messages are the second run's (the first run's output is gone)
    assert conversion.messages.warnings == {"Discarding unusable type '%' (first occurrence for edge '%').": 1}
    log = (far / "netconvert.log").read_text()
    assert log.count("$ ") == 2 and log.count("# exit code 0") == 2


@pytest.mark.slow
def test_krems_is_centred_on_its_roads_not_on_the_river_and_cycleway_of_its_extract(shared, tmp_path):
    """The zoo's Krems file reaches 15.86 E along the Danube and a cycleway netconvert does not import; centred
    on the extract, its roads lay 0.1-9.6 km west of the origin (CARLA's waypoints 0.17 mm off, median)."""
    conversion, centre = convert_osm(shared("zoo", "osm", "AT_krems.osm.gz"), tmp_path)
    assert centre == (15.7057357, 48.4071206)
    assert conversion.projection == tmerc_centred_on(15.6401974, 48.4068328)
    x, y, half = network_centre(tmp_path / "out.net.xml")
    assert np.hypot(x, y) < 0.001 * half and half > 5000
    assert junctions_off_their_osm_nodes(tmp_path / "out.net.xml", tmp_path / "in.osm").max() < 0.01


def test_jungfernstieg_converts_with_a_usable_georeference(shared, tmp_path):
    conversion, _ = convert_osm(shared(*JUNGFERNSTIEG), tmp_path, "full")
    georeference = assert_georeference_usable(tmp_path / "out.xodr")
    net_offset = read_location(tmp_path / "out.net.xml").net_offset
    assert _offset_xy(georeference) == (-net_offset[0], -net_offset[1]) == (0.0, 0.0)
    assert sum(conversion.messages.warnings.values()) > 0
    log = (tmp_path / "netconvert.log").read_text()
    assert log.startswith("# Eclipse SUMO netconvert") and "--osm-files" in log and "Warning:" in log


def test_utm_option_uses_the_data_zone(tmp_path):
    convert_osm(SAMPLE, tmp_path, crs="utm")
    proj = read_xodr_georeference(tmp_path / "out.xodr")["proj"]
    assert "+proj=utm" in proj and "+zone=32" in proj


def test_crs_keep_is_refused_for_osm(tmp_path):
    with pytest.raises(InputError, match="SUMO network"):
        convert_osm(SAMPLE, tmp_path, crs="keep")


def test_netconvert_does_not_reproject_a_sumo_net_with_proj(shared, tmp_path):
    """Why the stage re-projects SUMO networks through plain XML: -s with --proj only relabels."""
    source = shared(*TAVF_NET)
    out = tmp_path / "relabelled.net.xml"
    import subprocess

    subprocess.run([str(find_netconvert()), "-s", str(source), "--proj", tmerc_centred_on(9.98, 53.556),
                    "-o", str(out)], check=True, capture_output=True)
    before, after = read_location(source), read_location(out)
    assert after.net_offset == before.net_offset and after.conv_boundary == before.conv_boundary
    assert after.proj != before.proj  # same coordinates, new label: a mislabelled map


@pytest.mark.slow
def test_tavf_sumo_net_is_reprojected_to_a_centred_tmerc(shared, tmp_path):
    source = shared(*TAVF_NET)
    conversion = convert(source, "sumo-net", tmp_path / "t.net.xml", tmp_path / "t.xodr", tmp_path / "t.log",
                         load_profile("carla"))
    georeference = assert_georeference_usable(tmp_path / "t.xodr")
    lat_0 = float(proj_parameters(georeference["proj"])["lat_0"])
    lon_0 = float(proj_parameters(georeference["proj"])["lon_0"])
    assert 53.543 < lat_0 < 53.570 and 9.95 < lon_0 < 10.012  # centred on the net, not UTM's 0/9
    original, rebuilt = etree.parse(str(source)).getroot(), etree.parse(str(tmp_path / "t.net.xml")).getroot()

    def counts(root):
        edges = [e for e in root.iter("edge") if e.get("function") is None]
        return len(edges), sum(len(e.findall("lane")) for e in edges), len(root.findall("tlLogic"))

    assert counts(rebuilt) == counts(original) == (617, 1315, 43)
    assert any("re-projected" in note for note in conversion.notes)


@pytest.mark.slow
def test_tavf_sumo_net_keep_keeps_coordinates_and_writes_utm_as_tmerc(shared, tmp_path):
    source = shared(*TAVF_NET)
    convert(source, "sumo-net", tmp_path / "t.net.xml", tmp_path / "t.xodr", tmp_path / "t.log",
            load_profile("full"), crs="keep")
    georeference = assert_georeference_usable(tmp_path / "t.xodr")
    before = read_location(source)
    assert georeference["proj"] == as_tmerc(before.proj)
    assert read_location(tmp_path / "t.net.xml").net_offset == before.net_offset
    offset = georeference["offset"]
    assert (offset["x"], offset["y"]) == (-before.net_offset[0], -before.net_offset[1])
    # the tmerc form is the same projection as UTM 32: same metres for the same point
    utm = pyproj.Transformer.from_crs("EPSG:4326", before.proj, always_xy=True)
    tmerc = pyproj.Transformer.from_crs("EPSG:4326", georeference["proj"], always_xy=True)
    assert np.allclose(utm.transform(9.98, 53.556), tmerc.transform(9.98, 53.556), atol=1e-6)


def test_as_tmerc_only_rewrites_utm():
    assert as_tmerc("+proj=utm +zone=32 +ellps=WGS84 +datum=WGS84 +units=m +no_defs") == (
        "+proj=tmerc +lat_0=0 +lon_0=9 +k=0.9996 +x_0=500000 +y_0=0 +ellps=WGS84 +datum=WGS84 "
        "+units=m +no_defs")
    assert "+y_0=10000000" in as_tmerc("+proj=utm +zone=33 +south +ellps=WGS84")
    assert as_tmerc("+proj=merc +ellps=WGS84") == "+proj=merc +ellps=WGS84"


# --- failures -----------------------------------------------------------------------------------------


def test_an_invalid_option_in_a_profile_fails_with_netconverts_message(tmp_path):
    profile = tmp_path / "broken.toml"
    profile.write_text('extends = "carla"\n[osm]\n"no-such.option" = true\n')
    clean = tmp_path / "in.osm"
    summary = extract(SAMPLE, clean)
    expected = "netconvert: On processing option '--no-such.option=true'"
    with pytest.raises(StageError, match=expected) as caught:
        convert(clean, "osm", tmp_path / "o.net.xml", tmp_path / "o.xodr", tmp_path / "o.log",
                load_profile(profile), centre=summary.centre)
    assert caught.value.exit_code == 1
    assert "Quitting (on error)" in (tmp_path / "o.log").read_text()


def test_input_without_roads_of_the_profiles_types_fails_clearly(tmp_path):
    footways = tmp_path / "footways.osm"
    footways.write_text(
        '<?xml version="1.0"?>\n<osm version="0.6">\n'
        '  <node id="1" version="1" lat="53.55" lon="9.99"/>\n'
        '  <node id="2" version="1" lat="53.551" lon="9.99"/>\n'
        '  <way id="3" version="1"><nd ref="1"/><nd ref="2"/><tag k="highway" v="footway"/></way>\n</osm>\n')
    (tmp_path / "out").mkdir()
    with pytest.raises(StageError, match="No edges loaded.*profile's types"):
        convert_osm(footways, tmp_path / "out", "carla")
