"""The pybullet collision world of real builds: rays at lane centres find the OpenDRIVE surface, boxes come to
rest on every tile, bodies load from OBJ, and the world is deterministic."""

from __future__ import annotations

import csv
import hashlib
import io
import json

import numpy as np
import pybullet
import pytest
import trimesh
from click.testing import CliRunner

from tavf_mapkit.cli.main import cli
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.world import build_collision_world, load, read_world

PYBULLET_VERTEX_CAP = 131_072


@pytest.fixture
def client():
    cid = pybullet.connect(pybullet.DIRECT)
    yield cid
    pybullet.disconnect(cid)


def lane_centres(xodr, lane_type="driving", step=0.5) -> np.ndarray:
    """Lane-centre samples of every lane of a type, through the public command (`mapkit export`)."""
    result = CliRunner().invoke(cli, ["export", str(xodr), "--layer", "lane-center", "--format", "csv",
                                      "--step", str(step), "-o", "-"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    reader = csv.reader(io.StringIO(result.output))
    header = next(reader)
    kind, x, y, z = (header.index(name) for name in ("type", "x", "y", "z"))
    return np.array([(row[x], row[y], row[z]) for row in reader if row[kind] == lane_type], dtype=float)


BUILDS = ["sample_build_dir", "jungfernstieg_build", "tavf_dlr_build"]


@pytest.fixture(params=BUILDS)
def build(request):
    folder = request.getfixturevalue(request.param)
    return folder, folder / f"{folder.name}.xodr"


def test_world_json_describes_the_files(build):
    folder, _ = build
    world = read_world(folder)
    collision = folder / "collision"
    assert set(world) >= {"origin", "tiles", "bodies", "frame", "eps", "tile_size", "totals"}
    names = {body["name"] for body in world["bodies"]}
    assert {name for tile in world["tiles"] for name in tile["bodies"]} == names
    for body in world["bodies"]:
        data = (collision / body["file"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == body["sha256"]
        assert body["vertices"] <= PYBULLET_VERTEX_CAP
        mesh = trimesh.load(collision / body["file"], file_type="obj", process=False, force="mesh")
        assert (len(mesh.vertices), len(mesh.faces)) == (body["vertices"], body["triangles"])
        # float32-safe: the world is recentred, so coordinates stay small
        assert np.abs(mesh.vertices).max() < 10_000
    assert world["totals"]["triangles"] == sum(body["triangles"] for body in world["bodies"])
    manifest = json.loads((folder / "manifest.json").read_text())
    stage = next(stage for stage in manifest["stages"] if stage["name"] == "collision")
    assert stage["status"] == "ran"
    for key in ("tiles", "bodies", "vertices", "triangles"):
        assert stage["facts"][key] == world["totals"][key]


@pytest.mark.slow
def test_rays_at_lane_centres_hit_the_opendrive_surface(build, client):
    folder, xodr = build
    world = load(folder, client)
    centres = lane_centres(xodr)
    assert len(centres) > 1000
    z, body = world.cast_down(centres, above=1.0, below=1.0)
    close = np.abs(z - centres[:, 2]) <= 0.05
    assert np.mean(close) >= 0.999, f"{np.count_nonzero(~close)} of {len(centres)} lane-centre rays missed"
    groups = {world.group_of(b) for b in body[close]}
    assert groups <= {"road", "curb"}  # drivable surface (a raised driving lane is closed by a curb solid)


@pytest.mark.slow
def test_driving_lanes_are_free_at_car_height(build, client):
    """Nothing of the scene (buildings over passages, traffic lights at lane centres) blocks a driving lane
    between 0.3 m and 2.0 m above it."""
    folder, xodr = build
    world = load(folder, client)
    centres = lane_centres(xodr, step=1.0)
    z, body = world.cast_down(centres + [0.0, 0.0, 1.15], above=0.85, below=0.85)
    blocked = ~np.isnan(z)
    assert np.mean(blocked) <= 0.001, {world.group_of(b) for b in body[blocked]}


@pytest.mark.slow
def test_a_box_dropped_on_every_tile_comes_to_rest(build, client):
    folder, _ = build
    world = load(folder, client)
    description = read_world(folder)
    drops = []
    for tile in description["tiles"]:
        surface = [b for b in description["bodies"] if b["tile"] == tile["name"] and b["group"] in ("road", "roadside")]
        if not surface:
            continue
        mesh = trimesh.load(folder / "collision" / surface[0]["file"], file_type="obj", process=False, force="mesh")
        upward = np.flatnonzero(mesh.face_normals[:, 2] > 0.9)
        face = upward[np.argmax(mesh.area_faces[upward])]
        point = world.to_local(mesh.triangles_center[face])
        drops.append(point)
    assert len(drops) == len({b["tile"] for b in description["bodies"] if b["group"] in ("road", "roadside")})
    drops = np.array(drops)
    ground, _ = world.cast_down(drops, above=0.5, below=0.5)
    half = 0.2
    box = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[half] * 3, physicsClientId=client)
    ids = [pybullet.createMultiBody(1.0, box, basePosition=world.to_pybullet(p + [0.0, 0.0, half + 0.3]).tolist(),
                                    physicsClientId=client) for p in drops]
    pybullet.setGravity(0, 0, -9.81, physicsClientId=client)
    for _ in range(480):  # 2 s at 240 Hz
        pybullet.stepSimulation(physicsClientId=client)
    for k, body in enumerate(ids):
        position, _ = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
        velocity, spin = pybullet.getBaseVelocity(body, physicsClientId=client)
        bottom = world.to_local(np.array(position))[2] - half
        assert np.linalg.norm(velocity) < 0.05 and np.linalg.norm(spin) < 0.1, f"box {k} still moving"
        assert bottom == pytest.approx(ground[k], abs=0.05), f"box {k} did not come to rest on the surface"


def test_load_is_deterministic_and_converts_coordinates(sample_build_dir):
    ids = []
    for _ in range(2):
        cid = pybullet.connect(pybullet.DIRECT)
        try:
            world = load(sample_build_dir, cid)
            ids.append([(b.name, b.body_id) for b in world.bodies])
            assert pybullet.getNumBodies(physicsClientId=cid) == len(world.bodies)
        finally:
            pybullet.disconnect(cid)
    assert ids[0] == ids[1]
    points = np.array([[12.5, -3.25, 0.5], [1000.0, 2000.0, -4.0]])
    assert np.allclose(world.to_local(world.to_pybullet(points)), points, atol=1e-12)
    assert np.allclose(world.to_pybullet(world.origin), 0.0)
    assert np.allclose(world.to_pybullet(points[:, :2]), points[:, :2] - world.origin[:2])
    assert set(world.by_group) >= {"road", "building", "signal"}


def test_rebuilding_gives_identical_files(sample_build_dir, tmp_path):
    odr = load_opendrive(sample_build_dir / "sample.xodr")
    osm = sample_build_dir / "source" / "sample.osm"
    # the stage recentres on the exported meshes' origin, so visual and collision world coincide
    origin = json.loads((sample_build_dir / "mesh" / "mesh.json").read_text())["origin"]
    origin = [origin["x"], origin["y"], origin["z"]]
    assert read_world(sample_build_dir)["origin"] == origin
    first = build_collision_world(odr, tmp_path / "a", eps=0.05, osm_path=osm, origin=origin)
    second = build_collision_world(odr, tmp_path / "b", eps=0.05, osm_path=osm, origin=origin)
    assert first == second
    assert (tmp_path / "a/collision/world.json").read_bytes() == (tmp_path / "b/collision/world.json").read_bytes()
    assert first == read_world(sample_build_dir)  # the stage used the same defaults
    # building again into the same folder replaces the old world in one piece
    build_collision_world(odr, tmp_path / "a", eps=0.1, osm_path=osm)
    assert read_world(tmp_path / "a")["eps"] == 0.1
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["collision"]


def test_broken_worlds_are_refused_with_one_line(sample_build_dir, tmp_path, client):
    with pytest.raises(InputError, match="no collision world here"):
        load(tmp_path, client)
    odr = load_opendrive(sample_build_dir / "sample.xodr")
    build_collision_world(odr, tmp_path, eps=0.1)
    world = read_world(tmp_path)
    victim = tmp_path / "collision" / world["bodies"][0]["file"]
    victim.write_bytes(victim.read_bytes()[:-40])
    with pytest.raises(InputError) as error:
        load(tmp_path, client)
    assert str(victim) in str(error.value) and "changed or truncated" in str(error.value)
    (tmp_path / "collision" / "world.json").write_text('{"format": "something else"}')
    with pytest.raises(InputError, match="not a collision world"):
        load(tmp_path, client)
    (tmp_path / "collision" / "world.json").write_text("{")
    with pytest.raises(InputError, match="unreadable collision world"):
        load(tmp_path, client)


def test_bad_options_are_refused(sample_build_dir, tmp_path):
    odr = load_opendrive(sample_build_dir / "sample.xodr")
    with pytest.raises(ValueError, match="eps"):
        build_collision_world(odr, tmp_path, eps=0.0)
    with pytest.raises(ValueError, match="tile"):
        build_collision_world(odr, tmp_path, tile=float("nan"))
    assert not (tmp_path / "collision").exists()
