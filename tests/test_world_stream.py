"""The collision world streamed tile by tile (tavf_mapkit.world.TileStream, twin.sim.world.SimWorld): the tiles
near the covered points are loaded and far ones dropped, queries see what the whole world gives, and a
streamed drive is the whole-world drive, byte for byte."""

from __future__ import annotations

import json

import numpy as np
import pybullet as pb
import pytest

from tavf_mapkit.world import TileStream, load


def _tile_boxes(build) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """tile name -> plan box (low, high) of its bodies' bounds, in the pybullet frame, from world.json."""
    world = json.loads((build / "collision" / "world.json").read_text(encoding="utf-8"))
    boxes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for body in world["bodies"]:
        low, high = np.array(body["bounds"][0][:2]), np.array(body["bounds"][1][:2])
        if body["tile"] in boxes:
            low, high = np.minimum(low, boxes[body["tile"]][0]), np.maximum(high, boxes[body["tile"]][1])
        boxes[body["tile"]] = (low, high)
    return boxes


def _distance(box, square) -> float:
    (low, high), (x0, y0, x1, y1) = box, square
    dx = max(low[0] - x1, x0 - high[0], 0.0)
    dy = max(low[1] - y1, y0 - high[1], 0.0)
    return float(np.hypot(dx, dy))


def test_stream_loads_the_tiles_near_the_points_and_drops_far_ones(sample_build_dir):
    client = pb.connect(pb.DIRECT)
    try:
        stream = TileStream(sample_build_dir, client, radius=20.0, hysteresis=100.0)
        origin, size = stream.catalogue.origin, stream.tile_size
        boxes = _tile_boxes(sample_build_dir)
        assert pb.getNumBodies(physicsClientId=client) == 0 and stream.loaded_tiles() == []
        seen_far = 0
        rng = np.random.default_rng(3)
        low = np.min([b[0] for b in boxes.values()], axis=0)
        high = np.max([b[1] for b in boxes.values()], axis=0)
        previous: set[str] = set()
        for _ in range(40):
            point = rng.uniform(low, high)
            stream.cover((point + origin[:2])[None])
            i, j = np.floor(point / size + 0.5)
            square = ((i - 0.5) * size, (j - 0.5) * size, (i + 0.5) * size, (j + 0.5) * size)
            distance = {name: _distance(box, square) for name, box in boxes.items()}
            loaded = set(stream.loaded_tiles())
            near = {name for name, d in distance.items() if d <= 20.0}
            kept = {name for name in previous if distance[name] <= 120.0}
            # exactly the near tiles, plus earlier ones still within the hysteresis; the rest dropped
            assert loaded == near | kept
            seen_far += len(previous - loaded)
            previous = loaded
            generation, loads = stream.generation, stream.loads
            stream.cover((point + origin[:2])[None])  # the same square again: nothing to do
            assert (stream.generation, stream.loads) == (generation, loads)
            # pybullet holds just those tiles' bodies, each known by its world id
            ids = stream.loaded_ids()
            assert pb.getNumBodies(physicsClientId=client) == len(ids)
            assert sorted(stream.catalogue.bodies[k].tile for k in ids.values()) == \
                sorted(b.tile for b in stream.catalogue.bodies if b.tile in loaded)
        assert seen_far > 0 and len(boxes) > 20
        assert stream.drops > 0 and len(stream.loaded) < len(boxes)
    finally:
        pb.disconnect(client)


def test_world_ids_translate_pybullet_ids(sample_build_dir):
    client = pb.connect(pb.DIRECT)
    try:
        car = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[1, 1, 1],
                                                            physicsClientId=client), physicsClientId=client)
        stream = TileStream(sample_build_dir, client, radius=50.0)
        stream.cover(stream.catalogue.origin[None, :2])
        ids = stream.loaded_ids()
        assert ids and car not in ids
        pybullet_ids = np.array([-1, car, *ids])
        expected = [-1, len(stream.catalogue.bodies) + car, *ids.values()]
        assert stream.world_ids(pybullet_ids).tolist() == expected
        assert int(stream.world_ids(next(iter(ids)))) == next(iter(ids.values()))
    finally:
        pb.disconnect(client)


def test_streamed_rays_and_contacts_are_the_whole_worlds(sample_build_dir):
    """Vertical and slanted rays within the radius, and a car box's contacts, give the same hits as the whole
    world loaded in another client (fractions exactly, bodies by world id)."""
    whole_client, stream_client = pb.connect(pb.DIRECT), pb.connect(pb.DIRECT)
    try:
        whole = load(sample_build_dir, whole_client)
        radius = 30.0
        stream = TileStream(sample_build_dir, stream_client, radius=radius)
        rng = np.random.default_rng(7)
        vertices = np.array([line.split()[1:4] for body in whole.bodies if body.group == "road"
                             for line in (sample_build_dir / "collision" / body.file).read_text().splitlines()
                             if line.startswith("v ")], dtype=float)
        centres = vertices[rng.choice(len(vertices), 60, replace=False)]
        boxes = {c: pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[2.4, 1.0, 0.7], physicsClientId=c)
                 for c in (whole_client, stream_client)}
        cars = {c: pb.createMultiBody(0, boxes[c], physicsClientId=c) for c in boxes}
        hits = 0
        for centre in centres:
            stream.cover((centre[:2] + whole.origin[:2])[None])
            # rays from above the point: straight down, and slanted out to (radius - 1) m in plan
            angle = rng.uniform(0, 2 * np.pi, 64)
            reach = rng.uniform(0, radius - 1.0, 64)
            top = np.tile(centre + [0.0, 0.0, 3.0], (64, 1))
            bottom = centre + np.column_stack([reach * np.cos(angle), reach * np.sin(angle), np.full(64, -4.0)])
            a = pb.rayTestBatch(top.tolist(), bottom.tolist(), physicsClientId=whole_client)
            b = pb.rayTestBatch(top.tolist(), bottom.tolist(), physicsClientId=stream_client)
            assert [r[2] for r in a] == [r[2] for r in b]
            assert [r[3] for r in a] == [r[3] for r in b]
            assert [r[0] for r in a] == stream.world_ids([r[0] for r in b]).tolist()
            hits += sum(r[0] >= 0 for r in a)
            # a car box sunk into the surface at a random heading touches the same bodies as deep
            pose = ((centre + [0.0, 0.0, 0.5]).tolist(), pb.getQuaternionFromEuler([0, 0, float(angle[0])]))
            contacts = {}
            for c, car in cars.items():
                pb.resetBasePositionAndOrientation(car, *pose, physicsClientId=c)
                low, high = pb.getAABB(car, physicsClientId=c)
                found = {}
                for other, _ in pb.getOverlappingObjects(low, high, physicsClientId=c) or ():
                    points = pb.getClosestPoints(car, other, 0.0, physicsClientId=c)
                    if other != car and points:
                        key = other if c == whole_client else int(stream.world_ids(other))
                        found[key] = min(p[8] for p in points)
                contacts[c] = found
            assert contacts[whole_client] == contacts[stream_client]
        assert hits > 1000 and stream.drops > 0
    finally:
        pb.disconnect(whole_client)
        pb.disconnect(stream_client)


@pytest.mark.slow
def test_streamed_drive_is_the_whole_world_drive(sample_build_dir, tmp_path):
    """The same random drive with the world streamed and loaded whole: byte-identical trajectories, the same
    metrics (road surface judged by world ids) and collisions; the last lidar scan (hits by world id) and camera frame too."""
    from twin.session.config import DriveConfig
    from twin.session.loop import Session

    outputs = {}
    for whole in (False, True):
        out = tmp_path / ("whole" if whole else "streamed")
        config = DriveConfig(map=sample_build_dir, out=out, random=True, duration=90.0, seed=1, plot=False,
                             whole_world=whole, lidar=True, lidar_channels=8, lidar_columns=128, lidar_rate=2.0,
                             camera=True, camera_rate=0.5)
        session = Session(config, [])
        assert (session.world.stream is None) == whole
        metrics = session.run()
        for key in ("wall_seconds", "real_time_factor", "setup_seconds"):
            metrics.pop(key)
        scan = session.last_lidar
        outputs[whole] = (metrics, (out / "trajectory.csv").read_bytes(), (out / "collisions.csv").read_bytes(),
                          scan.ranges.tobytes(), scan.bodies.tolist(), session.last_camera.rgb.tobytes())
        if not whole:
            assert session.world.stream.drops > 0  # tiles came and went along the way
    assert outputs[False] == outputs[True]
    assert outputs[True][0]["lidar_scans"] > 100 and outputs[True][0]["distance_m"] > 300


def test_stream_refuses_a_changed_body_file_when_its_tile_comes(sample_build_dir, tmp_path):
    import shutil

    from tavf_mapkit.errors import InputError

    build = tmp_path / "build"
    shutil.copytree(sample_build_dir / "collision", build / "collision")
    client = pb.connect(pb.DIRECT)
    try:
        stream = TileStream(build, client, radius=10.0)
        body = stream.catalogue.bodies[0]
        (build / "collision" / body.file).write_text("v 0 0 0\n", encoding="ascii")
        low, high = (np.array(v[:2]) for v in stream.entries[0]["bounds"])
        with pytest.raises(InputError) as refused:
            stream.cover((0.5 * (low + high) + stream.catalogue.origin[:2])[None])
        assert str(refused.value) == (f"{build / 'collision' / body.file}: collision body {body.name} does not "
                                      "match world.json (changed or truncated)")
        assert pb.getNumBodies(physicsClientId=client) == len(stream.loaded_ids())  # no half-loaded tile
    finally:
        pb.disconnect(client)


def test_tiles_of_bodies_are_each_tiles_bodies_in_file_order_with_the_box_of_their_bounds(sample_build_dir):
    """The stream's tile index (its bodies and the box of their bounds per tile) is what a walk over world.json
    body by body gives."""
    from tavf_mapkit.world.loader import read_world

    entries = read_world(sample_build_dir)["bodies"]
    client = pb.connect(pb.DIRECT)
    try:
        stream = TileStream(sample_build_dir, client, radius=10.0)
    finally:
        pb.disconnect(client)
    names = list(dict.fromkeys(e["tile"] for e in entries))
    assert stream.tile_names == names
    assert stream.tile_bodies == [[k for k, e in enumerate(entries) if e["tile"] == name] for name in names]
    for t, name in enumerate(names):
        bounds = [e["bounds"] for e in entries if e["tile"] == name]
        assert stream.tile_low[t].tolist() == [min(b[0][0] for b in bounds), min(b[0][1] for b in bounds)]
        assert stream.tile_high[t].tolist() == [max(b[1][0] for b in bounds), max(b[1][1] for b in bounds)]
