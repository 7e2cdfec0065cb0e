"""Pipeline files are checked on load: unknown tables and keys, wrong types and out-of-range values are one
line naming the file, table and key, exit code 2, and nothing is built."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.pipeline.config import load_pipeline

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_data" / "tavf_synthetic.osm"


@pytest.mark.parametrize("toml, message", [
    # wrong types
    ('[check.thresholds]\ngnss_p95_distance_m = "15"\n',
     "[check.thresholds] gnss_p95_distance_m must be a number >= 0 (metres), not '15'"),
    ('[extract]\nroutes = "yes"\n', "[extract] routes must be true or false, not 'yes'"),
    ('[mesh]\nsolids = 1\n', "[mesh] solids must be true or false, not 1"),
    ('[mesh]\nformat = "fbx"\n', "[mesh] format must be one of glb, obj, not 'fbx'"),
    ('[netconvert]\ncrs = "wgs84"\n', "[netconvert] crs must be one of tmerc, utm, keep, not 'wgs84'"),
    ('[netconvert]\nprofile = 3\n',
     "[netconvert] profile must be a profile name (carla, full) or a .toml path, not 3"),
    ('[pipeline]\nstages = "mesh"\n', "[pipeline] stages must be a list of stage names, not 'mesh'"),
    ('[pipeline]\nname = 5\n', "[pipeline] name must be a non-empty string, not 5"),
    ('[area]\nbbox = [9.9, 53.5, 10.0]\n',
     "[area] bbox must be [west, south, east, north] in degrees, not [9.9, 53.5, 10.0]"),
    ('[check]\ngnss_trace_path = 5\n',
     "[check] gnss_trace_path must be a file path (a string, relative to the pipeline file), not 5"),
    ('[check]\nthresholds = 3\n', "[check] thresholds must be a table ([check.thresholds])"),
    ('routes = true\n', "top-level key 'routes' must be a table ([routes])"),
    # out of range
    ('[check.thresholds]\nreference_min_coverage = 1.5\n',
     "[check.thresholds] reference_min_coverage must be a number from 0 to 1, not 1.5"),
    ('[check.thresholds]\ngnss_median_distance_m = -1.0\n',
     "[check.thresholds] gnss_median_distance_m must be a number >= 0 (metres), not -1.0"),
    ('[check.thresholds]\ngnss_median_distance_m = nan\n',
     "[check.thresholds] gnss_median_distance_m must be a number >= 0 (metres), not nan"),
    ('[mesh]\neps = 0\n', "[mesh] eps must be a positive number of metres, not 0"),
    ('[check.validation]\nmax_errors = -1\n',
     "[check.validation] max_errors must be a whole number >= 0, not -1"),
    ('[check.validation]\nmax_warnings = 2.5\n',
     "[check.validation] max_warnings must be a whole number >= 0, not 2.5"),
    ('[check.validation.rules]\n"geometry.gap" = true\n',
     "[check.validation.rules] geometry.gap must be a whole number >= 0, not true"),
    ('[area]\nbbox = [9.9, 53.5, 190.0, 53.6]\n',
     "[area] bbox 9.9,53.5,190.0,53.6 is outside lon -180..180 / lat -90..90"),
    # unknown keys and tables
    ('[mesh]\nepsilon = 0.1\n', "[mesh] unknown key 'epsilon' (known: eps, format, solids, tile)"),
    ('[check.thresholds]\ngnss_p99_distance_m = 20.0\n',
     "[check.thresholds] unknown key 'gnss_p99_distance_m' (known: georeference_roundtrip_m, "
     "gnss_median_distance_m, gnss_p95_distance_m, reference_median_offset_m, reference_min_coverage, "
     "reference_p95_offset_m)"),
    ('[opendrive]\neps = 0.1\n', "[opendrive] unknown key 'eps' (known: curves, repair)"),
    ('[opendrive]\ncurves = "splines"\n', "[opendrive] curves must be one of arcs, keep, not 'splines'"),
    ('[opendrive]\nrepair = "no"\n', "[opendrive] repair must be true or false, not 'no'"),
    ('[extract]\nroute = true\n', "[extract] unknown key 'route' (known: routes)"),
    ('[mehs]\neps = 0.1\n',
     "[mehs] is not a table of a pipeline file (known: area, check, collision, extract, mesh, netconvert, "
     "opendrive, pipeline, report)"),
])
def test_a_bad_pipeline_file_is_one_line_exit_2_and_builds_nothing(tmp_path, toml, message):
    pipeline = tmp_path / "bad.toml"
    pipeline.write_text(toml)
    result = CliRunner().invoke(cli, ["build", str(SAMPLE), "--pipeline", str(pipeline),
                                      "-o", str(tmp_path / "b")])
    assert result.exit_code == 2, result.output
    assert result.stderr == f"Error: {pipeline}: {message}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]  # no build folder, lock or staging


def test_the_table_of_a_listed_stage_that_is_not_installed_is_kept_unchecked(tmp_path):
    pipeline = tmp_path / "future.toml"
    pipeline.write_text('[pipeline]\nstages = ["extract", "lidar-survey"]\n[lidar-survey]\npoints = "many"\n')
    assert load_pipeline(pipeline).section("lidar-survey") == {"points": "many"}


def test_every_key_of_the_example_pipeline_is_known():
    config = load_pipeline(REPO / "pipelines" / "tavf.toml")
    assert set(config.sections) == {"area", "extract", "netconvert", "opendrive", "mesh", "collision", "check"}
    assert config.section("opendrive") == {"repair": True, "curves": "arcs"}
    assert len(config.section("check")["thresholds"]) == 6


def test_validation_limits_name_known_rules(tmp_path):
    from tavf_mapkit.errors import InputError

    pipeline = tmp_path / "limits.toml"
    pipeline.write_text('[check.validation]\nmax_errors = 3\n'
                        '[check.validation.rules]\n"topology.contact-gap" = 2\n')
    assert load_pipeline(pipeline).section("check")["validation"] == {
        "max_errors": 3, "rules": {"topology.contact-gap": 2}}
    pipeline.write_text('[check.validation.rules]\n"topology.contact-gapp" = 2\n')
    with pytest.raises(InputError) as raised:
        load_pipeline(pipeline)
    assert str(raised.value).startswith(
        f"{pipeline}: [check.validation.rules] unknown key 'topology.contact-gapp' (known: ")
    assert "topology.contact-gap," in str(raised.value)
