"""tile_bodies: one tile's road surface and solids as collision bodies -- every face in exactly one body of its
group, no vertex a body does not use, bodies over MAX_BODY_VERTICES cut into quarters."""

import numpy as np

from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.solid_kit import Solid
from tavf_mapkit.world import parts
from tavf_mapkit.world.build import tile_bodies


def _grid_surface(n: int) -> LabelledMesh:
    """An n x n grid of squares (two triangles each) with alternating drivable and sidewalk kinds."""
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([corner, corner + 1, corner + n + 2]),
                            np.column_stack([corner, corner + n + 2, corner + n + 1])])
    kind = np.where(np.arange(len(faces)) % 3 == 0, KIND_CODE["sidewalk"], KIND_CODE["driving"]).astype(np.int16)
    return LabelledMesh(vertices, faces, np.arange(len(faces), dtype=np.int32), np.ones(len(faces), dtype=np.int32),
                        kind)


def _face_keys(mesh: LabelledMesh) -> set:
    """Each face as its corner coordinates and labels (independent of vertex numbering)."""
    corners = mesh.vertices[mesh.faces].reshape(len(mesh.faces), 9)
    return {(*row.tolist(), int(r), int(k)) for row, r, k in zip(corners, mesh.road_index, mesh.kind)}


def test_every_surface_face_is_in_one_body_of_its_group():
    surface = _grid_surface(12)
    bodies = tile_bodies((2, -1), surface, [])
    assert [b.name for b in bodies] == ["tile_+2_-1_road", "tile_+2_-1_roadside"]
    drivable = np.isin(surface.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
    for body, mask in zip(bodies, (drivable, ~drivable)):
        assert body.tile == "tile_+2_-1" and body.index == (2, -1)
        assert _face_keys(body.mesh) == _face_keys(surface.select(mask))
        assert len(body.mesh.faces) == mask.sum()
        assert np.unique(body.mesh.faces).tolist() == list(range(len(body.mesh.vertices)))  # every vertex used


def test_a_body_over_the_vertex_limit_is_cut_into_quarters(monkeypatch):
    monkeypatch.setattr(parts, "MAX_BODY_VERTICES", 60)
    surface = _grid_surface(12)
    bodies = [b for b in tile_bodies((0, 0), surface, []) if b.group == "road"]
    assert len(bodies) > 1 and all(b.name.startswith("tile_+0_+0_road_q") for b in bodies)
    assert all(len(b.mesh.vertices) <= 60 for b in bodies)
    drivable = np.isin(surface.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
    found = [key for b in bodies for key in _face_keys(b.mesh)]
    assert len(found) == drivable.sum() and set(found) == _face_keys(surface.select(drivable))


def test_solids_of_a_group_are_one_body_in_their_order_without_unused_vertices():
    def box(x0: float, spare: int) -> LabelledMesh:
        # a tetrahedron at x0 with ``spare`` vertices no face uses
        vertices = np.array([[x0, 0, 0], [x0 + 1, 0, 0], [x0, 1, 0], [x0, 0, 1]] + [[99.0, 99, 99]] * spare)
        faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
        return LabelledMesh(vertices, faces, np.full(4, -1, dtype=np.int32), np.zeros(4, dtype=np.int32),
                            np.full(4, KIND_CODE["curb"], dtype=np.int16))

    solids = [Solid("curb", box(0, 2), "a"), Solid("signal", box(5, 0), "b"), Solid("curb", box(10, 1), "c")]
    bodies = tile_bodies((0, 0), None, solids)
    assert [b.name for b in bodies] == ["tile_+0_+0_curb", "tile_+0_+0_signal"]
    curb = bodies[0].mesh
    assert len(curb.vertices) == 8 and not np.any(curb.vertices == 99.0)
    assert curb.vertices[:, 0].tolist() == [0, 1, 0, 0, 10, 11, 10, 10]
    assert curb.faces.tolist() == [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3],
                                   [4, 6, 5], [4, 5, 7], [4, 7, 6], [5, 6, 7]]
