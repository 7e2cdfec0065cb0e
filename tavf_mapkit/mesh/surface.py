"""``road_surface``: the lane meshes of every road plus one clean surface per junction."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from tavf_mapkit.mesh.adaptive import AdaptiveSamples, adaptive_samples
from tavf_mapkit.mesh.cleanup import drop_degenerate
from tavf_mapkit.mesh.junctions import junction_surfaces
from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.lanes import build_lane_meshes
from tavf_mapkit.mesh.stacked import cut_stacked_roadside
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
    # road index -> plan region cut out of its road-side lanes, which stood on another road's driving lane
    given_way: dict = field(default_factory=dict)


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
    in_junction = np.r_[units.in_junction, False]
    raised = units.raised_rows
    junction_face = (in_junction[lanes.road_index] & ~raised[face_row] if len(face_row)
                     else np.zeros(0, dtype=bool)) & (lanes.kind != KIND_CODE["curb"])
    junction_lanes = lanes.select(junction_face)
    # road-side faces standing on another road's driving lane give way to it (mesh.stacked); where that cuts a
    # raised connecting lane, its junction's surface is not cut out under it either
    own_lanes, stacked = cut_stacked_roadside(lanes.select(~junction_face),
                                              _driving_around(odr, lanes, units, roads, eps, max_segment))
    uncovered = [region for road, region in sorted(stacked.items()) if in_junction[road]]
    junctions = junction_surfaces(odr, sampling, junction_lanes, raised, junction_cell, eps,
                                  group_of_road=units.road_unit, units=units,
                                  uncovered=shapely.union_all(uncovered) if uncovered else None)
    mesh = drop_degenerate(LabelledMesh.concatenate([own_lanes, junctions.mesh]))
    mesh = mesh.grouped(units.road_unit[mesh.road_index])
    return RoadSurface(mesh, samples, junctions.footprints, junction_lanes, eps, stacked)


def _driving_around(odr, lanes: LabelledMesh, units: MeshUnits, roads: np.ndarray | None, eps: float,
                    max_segment: float) -> LabelledMesh:
    """The driving-lane faces of the roads meshed here and of every other road whose coarse box meets one of
    theirs with road-side lanes (meshed the same way they are in their own batch: a unit's surface never
    depends on its batch)."""
    driving = lanes.kind == KIND_CODE["driving"]
    roadside = np.unique(lanes.road_index[~driving & (lanes.kind != KIND_CODE["curb"])])
    meshed = np.unique(lanes.road_index) if roads is None else np.asarray(roads)
    if not len(roadside):
        return lanes.select(driving)
    missing = np.setdiff1d(units.roads_meeting(roadside), meshed)
    missing = missing[np.isin(missing, odr.arrays.section_road[odr.arrays.lane_section[
        units.lane_kind == KIND_CODE["driving"]]])]
    if not len(missing):
        return lanes.select(driving)
    sections = np.flatnonzero(np.isin(odr.arrays.section_road, missing))
    samples = adaptive_samples(odr, eps, max_segment, sections=sections)
    around, _ = build_lane_meshes(odr, sample_lanes_at(odr, samples.section, samples.s))
    around_driving = around.select(around.kind == KIND_CODE["driving"])
    return LabelledMesh.concatenate([lanes.select(driving), around_driving])


def road_surface(odr, eps: float = DEFAULT_EPS) -> LabelledMesh:
    """Every lane of every road within ``eps`` metres of the exact OpenDRIVE surface, plus one surface per
    junction; labels road_index, lane_id, kind (``labelled.KIND_CODE``) and uv = (s, t). Normals up."""
    return build_road_surface(odr, eps).mesh
