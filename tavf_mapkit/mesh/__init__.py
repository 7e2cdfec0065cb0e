"""Road meshes from OpenDRIVE: lane surfaces, junction surfaces, road marks, and their export.

    from tavf_mapkit.mesh import road_surface, road_marks
    surface = road_surface(odr, eps=0.05)   # LabelledMesh, OpenDRIVE local coordinates, normals up
    marks = road_marks(odr, eps=0.05)       # RoadMarkMesh: + per-face colour index into MARK_COLOURS

See docs/mesh.md.
"""

from tavf_mapkit.mesh.labelled import KIND_CODE, SURFACE_KINDS, LabelledMesh
from tavf_mapkit.mesh.marks import MARK_COLOURS, RoadMarkMesh, road_marks
from tavf_mapkit.mesh.surface import RoadSurface, build_road_surface, road_surface

__all__ = ["KIND_CODE", "MARK_COLOURS", "SURFACE_KINDS", "LabelledMesh", "RoadMarkMesh", "RoadSurface",
           "build_road_surface", "road_marks", "road_surface"]
