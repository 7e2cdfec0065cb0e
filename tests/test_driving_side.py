"""Driving side: the offline country lookup of a map's centre, the user's override, OpenDRIVE's rule."""

from __future__ import annotations

import pytest

from tavf_mapkit.drivingside import LEFT_HAND_COUNTRIES, check_choice, choose, country_at, opendrive_side, side_at
from tavf_mapkit.errors import InputError


@pytest.mark.parametrize("place, lon, lat, country, side", [
    ("London", -0.1276, 51.5072, "GB", "left"),
    ("Melbourne", 144.9631, -37.8136, "AU", "left"),
    ("Tokyo", 139.6917, 35.6895, "JP", "left"),
    ("Delhi", 77.2090, 28.6139, "IN", "left"),
    ("Berlin", 13.4050, 52.5200, "DE", "right"),
    ("New York", -74.0060, 40.7128, "US", "right"),
    # borders that split the sides, a few km apart
    ("Hong Kong, Kowloon", 114.1694, 22.3193, "HK", "left"),
    ("Shenzhen", 114.0579, 22.5431, "CN", "right"),
    ("Macau", 113.5439, 22.1987, "MO", "left"),
    ("Gibraltar", -5.3536, 36.1408, "GI", "right"),
    ("La Linea, Spain", -5.3480, 36.1650, "ES", "right"),
    ("Dublin", -6.2603, 53.3498, "IE", "left"),
    ("Belfast", -5.9301, 54.5973, "GB", "left"),
])
def test_lookup_of_well_known_places(place, lon, lat, country, side):
    assert country_at(lon, lat)[0] == country, place
    found = side_at(lon, lat)
    assert found.side == side and found.country == country and found.source == "location"
    assert country in found.reason and found.reason.startswith(f"{side}-hand traffic: the map centre")


def test_open_sea_is_right_hand():
    found = side_at(-30.0, 0.0)  # mid-Atlantic
    assert found.side == "right" and found.country is None and "no country" in found.reason


def test_left_hand_list_holds_only_iso_codes():
    assert all(len(code) == 2 and code.isupper() for code in LEFT_HAND_COUNTRIES)
    assert {"GB", "JP", "AU", "IN", "SG", "ZA"} <= LEFT_HAND_COUNTRIES
    assert not {"DE", "US", "FR", "CN", "GI", "TW"} & LEFT_HAND_COUNTRIES


def test_option_overrides_the_location():
    london = side_at(-0.1276, 51.5072)
    assert choose("auto", london) is london
    assert choose("right", london).side == "right" and choose("right", london).source == "option"
    assert choose("LEFT", None).side == "left"
    assert choose("auto", None).side == "right" and choose("auto", None).source == "default"


@pytest.mark.parametrize("value", ["both", "", 1, None, "lht"])
def test_bad_choice_is_one_line(value):
    with pytest.raises(InputError, match="driving_side must be one of auto, left, right"):
        check_choice(value, "pipelines/x.toml")


def test_not_a_position_is_refused():
    with pytest.raises(InputError, match="not a WGS84 position"):
        country_at(float("nan"), 10.0)
    with pytest.raises(InputError, match="not a WGS84 position"):
        country_at(200.0, 10.0)


def test_opendrive_rule_decides_by_road_length(tmp_path):
    from tavf_mapkit.opendrive import load_opendrive
    from tests.xodr_factory import document, road_xml

    line = '<geometry s="0" x="0" y="0" hdg="0" length="{0}"><line/></geometry>'
    long_lht = road_xml(line.format(100), 100.0, road_id="1").replace('junction="-1"', 'junction="-1" rule="LHT"')
    short_rht = road_xml(line.format(20), 20.0, road_id="2")
    path = tmp_path / "lht.xodr"
    path.write_text(document(long_lht, short_rht), encoding="utf-8")
    found = opendrive_side(load_opendrive(path))
    assert found.side == "left" and found.source == "opendrive" and "1 of 2 roads" in found.reason
    path.write_text(document(short_rht), encoding="utf-8")
    assert opendrive_side(load_opendrive(path)).side == "right"


def test_pipeline_key_and_command_line_override(tmp_path):
    from tavf_mapkit.pipeline.config import load_pipeline

    path = tmp_path / "london.toml"
    path.write_text('[pipeline]\nname = "london"\ndriving_side = "left"\n', encoding="utf-8")
    config = load_pipeline(path)
    assert config.driving_side == "left" and config.to_dict()["driving_side"] == "left"
    assert config.with_overrides(driving_side="right").driving_side == "right"
    assert config.with_overrides().driving_side == "left"
    path.write_text('[pipeline]\ndriving_side = "both"\n', encoding="utf-8")
    with pytest.raises(InputError) as error:
        load_pipeline(path)
    assert str(error.value) == (f"{path.resolve()}: [pipeline] driving_side must be one of auto, left, right, "
                                "not 'both'")
