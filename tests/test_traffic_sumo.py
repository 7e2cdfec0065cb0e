"""SUMO traffic on real builds: vehicles on OpenDRIVE lanes, reproducible from the seed, clean removal."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.locate import LaneLocator
from tavf_mapkit.opendrive.sampling import sample_lanes
from tests.conftest import shared_path
from twin.traffic.buildfiles import build_files
from twin.traffic.demand import generate_demand, read_demand
from twin.traffic.sumo import SumoTraffic, TrafficConfig

CENTRE_SAMPLE_STEP_M = 0.2  # nearest-sample distance overestimates the distance to the line by <= 10 cm


def centre_line_tree(xodr, exclude_types=("sidewalk",)):
    """KD-tree over densely sampled OpenDRIVE lane centre lines (all lanes except ``exclude_types``)."""
    sampling = sample_lanes(load_opendrive(xodr), CENTRE_SAMPLE_STEP_M)
    keep = ~np.isin(sampling.lane_type, list(exclude_types))
    return cKDTree(sampling.center_points(with_height=False)[keep][:, :2])


def run(build, config, steps, every=1):
    """Positions (step, id, x, y) of SUMO vehicles in the OpenDRIVE frame, sampled every ``every`` steps."""
    rows = []
    with SumoTraffic.from_build(build, config) as traffic:
        for _ in range(steps):
            snapshot = traffic.step()
            if snapshot.step % every == 0:
                actors = snapshot.actors
                for i in np.flatnonzero(~actors.is_person):
                    rows.append((snapshot.step, actors.ids[i], actors.x[i], actors.y[i], actors.yaw[i]))
        stats = traffic.stats
    return rows, stats


@pytest.fixture(scope="module")
def jungfernstieg_full_build(tmp_path_factory):
    """Jungfernstieg built with the "full" netconvert profile: sidewalks and crossings for pedestrians."""
    from tavf_mapkit.cli.main import cli

    source = shared_path("hamburg", "jungfernstieg_osm", "jungfernstieg_2023-03-10.osm")
    out = tmp_path_factory.mktemp("jf-full") / "jungfernstieg-full"
    result = CliRunner().invoke(cli, ["build", str(source), "--profile", "full", "-o", str(out), "-q"],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
@pytest.mark.parametrize("fixture, vehicles", [("jungfernstieg_build", 40), ("tavf_dlr_build", 100)])
def test_sumo_vehicles_lie_on_opendrive_lanes(fixture, vehicles, request):
    build = request.getfixturevalue(fixture)
    rows, stats = run(build, TrafficConfig(vehicles=vehicles, seed=11), steps=1200, every=10)
    assert len(rows) > 50 * vehicles  # the population was kept up
    assert stats.inserted_vehicles >= vehicles
    xy = np.array([(r[2], r[3]) for r in rows])
    distance, _ = centre_line_tree(build_files(build).xodr).query(xy)
    on_lane = np.mean(distance <= 0.5)
    assert on_lane >= 0.99, f"{on_lane:.4f} of {len(xy)} samples within 0.5 m, p99 {np.quantile(distance, 0.99):.2f} m"


@pytest.mark.slow
def test_same_seed_same_positions(tavf_dlr_build):
    config = TrafficConfig(vehicles=60, pedestrians=10, seed=5)
    first, _ = run(tavf_dlr_build, config, steps=400)
    second, _ = run(tavf_dlr_build, config, steps=400)
    assert first == second  # exact: ids, order and every coordinate bit


def test_another_seed_gives_other_traffic(sample_build_dir):
    first, _ = run(sample_build_dir, TrafficConfig(vehicles=8, seed=5), steps=200)
    assert first == run(sample_build_dir, TrafficConfig(vehicles=8, seed=5), steps=200)[0]
    assert first != run(sample_build_dir, TrafficConfig(vehicles=8, seed=6), steps=200)[0]


@pytest.mark.slow
def test_pedestrians_walk_on_sidewalks_of_a_full_build(jungfernstieg_full_build):
    build = jungfernstieg_full_build
    samples = []
    with SumoTraffic.from_build(build, TrafficConfig(vehicles=10, pedestrians=30, seed=3)) as traffic:
        assert traffic.crossings  # the full profile guesses crossings
        for _ in range(600):
            snapshot = traffic.step()
            actors = snapshot.actors
            assert int(actors.is_person.sum()) <= 30
            if snapshot.step % 10 == 0:
                people = actors.select(actors.is_person)
                # crossings and walking areas are objects / junction surface in OpenDRIVE, not lanes
                on_edges = np.array([not road.startswith(":") for road in people.road_id], dtype=bool)
                samples.extend(zip(people.x[on_edges], people.y[on_edges]))
        assert traffic.stats.inserted_persons >= 30
    assert len(samples) > 500
    odr = load_opendrive(build_files(build).xodr)
    xy = np.array(samples)
    found = LaneLocator(odr).locate(xy[:, 0], xy[:, 1])
    # SUMO's striping model spreads people across their lane's width: inside a lane is the property
    assert np.mean(found.distance <= 0.25) >= 0.99
    row_of = {(int(section), int(lane)): row for row, (section, lane)
              in enumerate(zip(odr.arrays.lane_section, odr.arrays.lane_id))}
    lane_type = odr.arrays.lane_type[[row_of[(int(a), int(b))] for a, b in zip(found.section_index, found.lane_id)]]
    assert np.mean(lane_type == "sidewalk") > 0.6  # most walk on sidewalks, the rest on streets without one


def test_population_is_kept_and_departures_are_replaced(sample_build_dir):
    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=8, seed=2)) as traffic:
        counts = []
        for _ in range(2400):  # 120 s: the sample's routes are short, many cars arrive
            counts.append(len(traffic.step().actors))
        stats = traffic.stats
    assert stats.arrived_vehicles > 5
    assert stats.inserted_vehicles == 8 + stats.arrived_vehicles + stats.teleports_removed
    assert max(counts) <= 8 and np.mean(counts[200:]) >= 6


def test_only_one_simulation_per_process(sample_build_dir):
    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=2, seed=1)), \
            pytest.raises(StageError, match="already open"):
        SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=2, seed=1))
    with SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=2, seed=1)) as traffic:
        traffic.step()  # the first one closed cleanly, so a new one starts


def test_demand_from_seed_is_reproducible_and_from_file_is_read(sample_build_dir, tmp_path):
    net = build_files(sample_build_dir).net
    first = generate_demand(net, 4, 10, 0, tmp_path / "a")
    assert first == generate_demand(net, 4, 10, 0, tmp_path / "b")
    assert first.vehicle_routes != generate_demand(net, 5, 10, 0).vehicle_routes
    again = read_demand(tmp_path / "a" / "vehicles.rou.xml")
    assert again.vehicle_routes == first.vehicle_routes


def test_bad_routes_files(tmp_path):
    trips = tmp_path / "trips.rou.xml"
    trips.write_text('<routes>\n  <trip id="a" depart="0" from="e1" to="e2"/>\n</routes>\n')
    with pytest.raises(InputError, match="<trip> has no routed edges; route the file with duarouter first") as info:
        read_demand(trips)
    assert info.value.line == 2
    empty = tmp_path / "empty.rou.xml"
    empty.write_text("<routes/>")
    with pytest.raises(InputError, match="no <route edges"):
        read_demand(empty)
    broken = tmp_path / "broken.rou.xml"
    broken.write_text("<routes><route edges='a'></routes>")
    with pytest.raises(InputError):
        read_demand(broken)


def test_unknown_edge_in_demand_is_a_clear_error(sample_build_dir, tmp_path):
    routes = tmp_path / "r.rou.xml"
    routes.write_text('<routes><route id="x" edges="no_such_edge"/></routes>')
    with pytest.raises(InputError, match="no_such_edge"):
        SumoTraffic.from_build(sample_build_dir, TrafficConfig(vehicles=1, demand=routes))
