"""The city scene around the road as watertight solids (manifold3d): curbs and raised sidewalks, curbs along
the open sides of junctions, OpenDRIVE objects, signals (pole + plate) and, for OSM input, buildings extruded
from their footprints.

``scene_solids`` returns one LabelledMesh (faces labelled curb / object / signal / building) for the mesh
exporter and the collision world; ``scene_solid_parts`` keeps every solid apart, with what it was made from
and what could not be made (for reports and tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit.mesh.labelled import LabelledMesh
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
