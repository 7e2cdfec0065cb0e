"""``road_surface``: the lane meshes of every road plus one clean surface per junction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tavf_mapkit.mesh.adaptive import AdaptiveSamples, adaptive_samples
from tavf_mapkit.mesh.cleanup import drop_degenerate
from tavf_mapkit.mesh.junctions import junction_surfaces
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.lanes import build_lane_meshes, raised_lane_rows
from tavf_mapkit.mesh.units import MeshUnits, mesh_units
from tavf_mapkit.opendrive.sampling import sample_lanes_at

DEFAULT_EPS = 0.05        # m
JUNCTION_CELL = 5.0       # m: largest junction triangle (the junction is draped at its vertices)
MAX_SEGMENT = 50.0        # m: longest lane quad along s, even on a straight


@dataclass(frozen=True, eq=False)
class RoadSurface:
    """The road surface and what was measured while making it."""

    mesh: LabelledMesh
    samples: AdaptiveSamples
    junction_footprints: dict  # junction id -> shapely (Multi)Polygon of its surface in plan view
    junction_lanes: LabelledMesh  # the connecting lanes' own meshes (overlapping), replaced in ``mesh``
    eps: float


def build_road_surface(odr, eps: float = DEFAULT_EPS, junction_cell: float = JUNCTION_CELL,
                       max_segment: float = MAX_SEGMENT, units: MeshUnits | None = None,
                       roads: np.ndarray | None = None) -> RoadSurface:
    """The road surface of the map, or of the given roads (whole units of ``units``: a batch of the tiled
    mesher). Faces come unit by unit in the order of ``units`` (``mesh.units``), each unit's as it is alone."""
    units = mesh_units(odr) if units is None else units
    arrays = odr.arrays
    sections = None if roads is None else np.flatnonzero(np.isin(arrays.section_road, roads))
    samples = adaptive_samples(odr, eps, max_segment, sections=sections)
    sampling = sample_lanes_at(odr, samples.section, samples.s)
    lanes, face_row = build_lane_meshes(odr, sampling)
    in_junction = np.array([road.in_junction for road in odr.roads] + [False], dtype=bool)
    raised = raised_lane_rows(arrays)
    junction_face = (in_junction[lanes.road_index] & ~raised[face_row] if len(face_row)
                     else np.zeros(0, dtype=bool)) & (lanes.kind != KIND_CODE["curb"])
    junction_lanes = lanes.select(junction_face)
    junctions = junction_surfaces(odr, sampling, junction_lanes, raised, junction_cell, eps,
                                  group_of_road=units.road_unit)
    mesh = drop_degenerate(LabelledMesh.concatenate([lanes.select(~junction_face), junctions.mesh]))
    mesh = mesh.grouped(units.road_unit[mesh.road_index])
    return RoadSurface(mesh, samples, junctions.footprints, junction_lanes, eps)


def road_surface(odr, eps: float = DEFAULT_EPS) -> LabelledMesh:
    """Every lane of every road within ``eps`` metres of the exact OpenDRIVE surface, plus one surface per
    junction; labels road_index, lane_id, kind (``labelled.KIND_CODE``) and uv = (s, t). Normals up."""
    return build_road_surface(odr, eps).mesh
