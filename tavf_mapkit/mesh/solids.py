"""The city scene around the road as watertight solids (manifold3d): curbs and raised sidewalks, curbs along
the open sides of junctions, OpenDRIVE objects, signals (pole + plate) and, for OSM input, buildings extruded
from their footprints.

``scene_solids`` returns one LabelledMesh (faces labelled curb / object / signal / building) for the mesh
exporter and the collision world; ``scene_solid_parts`` keeps every solid apart, with what it was made from
and what could not be made (for reports and tests). ``SceneSolids`` round-trips through an ``.npz`` file, so
the collision stage reads the mesh stage's solids instead of making them again.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tavf_mapkit.mesh.labelled import LabelledMesh, npz_bytes
from tavf_mapkit.mesh.solid_kit import Solid

SOLID_KINDS = ("curb", "object", "signal", "building")


@dataclass(frozen=True, eq=False)
class SceneSolids:
    solids: tuple[Solid, ...]
    skipped: tuple[str, ...]  # "where: why" for every part that got no solid

    def mesh(self) -> LabelledMesh:
        return LabelledMesh.concatenate([solid.mesh for solid in self.solids])

    def counts(self) -> dict[str, int]:
        return {kind: sum(1 for solid in self.solids if solid.kind == kind) for kind in SOLID_KINDS}

    def to_npz_bytes(self) -> bytes:
        """Every solid (its mesh, kind and source) and the skipped parts as one byte-reproducible ``.npz``."""
        return npz_bytes(self.arrays())

    def arrays(self) -> dict:
        mesh = self.mesh()
        return {
            "vertices": mesh.vertices, "faces": mesh.faces, "road_index": mesh.road_index,
            "lane_id": mesh.lane_id, "kind": mesh.kind,
            "solid_vertices": np.array([len(s.mesh.vertices) for s in self.solids], dtype=np.int64),
            "solid_faces": np.array([s.triangles for s in self.solids], dtype=np.int64),
            "solid_kind": np.array([s.kind for s in self.solids], dtype=str),
            "solid_source": np.array([s.source for s in self.solids], dtype=str),
            "skipped": np.array(self.skipped, dtype=str)}

    @classmethod
    def load_npz(cls, path: str | Path) -> SceneSolids:
        with np.load(path, allow_pickle=False) as data:
            return cls.from_arrays({name: data[name] for name in data.files})

    @classmethod
    def from_arrays(cls, arrays: dict, prefix: str = "") -> SceneSolids:
        arrays = {name[len(prefix):]: value for name, value in arrays.items() if name.startswith(prefix)}
        if "solid_kind" not in arrays:
            return cls((), ())
        vertex_end = np.cumsum(arrays["solid_vertices"])
        face_end = np.cumsum(arrays["solid_faces"])
        solids = []
        for k, (kind, source) in enumerate(zip(arrays["solid_kind"].tolist(), arrays["solid_source"].tolist())):
            v0 = vertex_end[k] - arrays["solid_vertices"][k]
            faces = slice(face_end[k] - arrays["solid_faces"][k], face_end[k])
            solids.append(Solid(kind, LabelledMesh(
                arrays["vertices"][v0:vertex_end[k]], arrays["faces"][faces] - v0, arrays["road_index"][faces],
                arrays["lane_id"][faces], arrays["kind"][faces]), source))
        return cls(tuple(solids), tuple(arrays.get("skipped", np.zeros(0, dtype=str)).tolist()))


def scene_solid_parts(odr, surface: LabelledMesh | None, osm_path: Path | None = None,
                      eps: float = 0.05) -> SceneSolids:
    """Every solid of the scene, in a deterministic order (curbs, junction curbs, objects, signals, buildings)."""
    from tavf_mapkit.mesh.solid_buildings import building_solids
    from tavf_mapkit.mesh.solid_curbs import curb_solids
    from tavf_mapkit.mesh.solid_junction_curbs import junction_curb_solids
    from tavf_mapkit.mesh.solid_objects import object_solids
    from tavf_mapkit.mesh.solid_signals import signal_solids

    solids, skipped = [], []
    for built, missing in (curb_solids(odr, surface), junction_curb_solids(odr, surface),
                           object_solids(odr, eps), signal_solids(odr, eps), building_solids(odr, surface, osm_path)):
        solids.extend(built)
        skipped.extend(missing)
    return SceneSolids(tuple(solids), tuple(skipped))


def scene_solids(odr, surface: LabelledMesh | None, osm_path: Path | None = None, eps: float = 0.05) -> LabelledMesh:
    """All scene solids as one LabelledMesh in OpenDRIVE local coordinates."""
    return scene_solid_parts(odr, surface, osm_path, eps).mesh()
