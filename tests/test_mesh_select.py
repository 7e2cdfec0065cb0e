"""labelled.used_vertices, behind every LabelledMesh.select and spilled-piece selection of the tiled mesher, is
np.unique(faces, return_inverse=True) on a real map's surface: the same vertices, the same renumbered faces."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.mesh.labelled import used_vertices
from tavf_mapkit.mesh.surface import build_road_surface
from tavf_mapkit.opendrive import load_opendrive


def test_used_vertices_is_unique_with_inverse(shared):
    mesh = build_road_surface(load_opendrive(shared("xodr", "esmini", "fabriksgatan.xodr")), 0.05).mesh
    rng = np.random.default_rng(3)
    masks = [rng.random(len(mesh.faces)) < share for share in (0.0, 0.01, 0.3, 1.0)]
    masks += [np.flatnonzero(mesh.road_index == mesh.road_index[0]), mesh.kind == mesh.kind[-1]]
    for mask in masks:
        faces = mesh.faces[mask]
        used, renumbered = used_vertices(faces, len(mesh.vertices))
        expected_used, inverse = np.unique(faces, return_inverse=True)
        assert np.array_equal(used, expected_used)
        assert renumbered.dtype == np.int64 and np.array_equal(renumbered, inverse.reshape(-1, 3))
        selected = mesh.select(mask)
        assert np.array_equal(selected.vertices[selected.faces], mesh.vertices[faces])
