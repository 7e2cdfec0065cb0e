"""Write the road surface, road marks and scene solids as tiled glTF binary (.glb) or OBJ+MTL files, plus
``mesh.json`` (origin, axes, tiles, triangle counts, measured deviation) and a top-view ``preview.png``.

Axes: OpenDRIVE is x east, y north, z up. glTF is +Y up, +Z towards the viewer, right-handed, in metres, so
a file holds (X, Y, Z) = (x - ox, z - oz, -(y - oy)) where (ox, oy, oz) is ``mesh.json``'s origin in
OpenDRIVE local coordinates -- a proper rotation, so winding (counter-clockwise = front) is unchanged.
OBJ files use the same axes (Blender's and Unity's OBJ importers expect +Y up). Recentring keeps float32
coordinates millimetre-exact for maps up to ~30 km across.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tavf_mapkit.fileutil import write_bytes_atomic, write_text_atomic
from tavf_mapkit.mesh.labelled import KIND_CODE, SURFACE_KINDS, LabelledMesh
from tavf_mapkit.mesh.materials import mark_material, material_rgba
from tavf_mapkit.mesh.tiles import face_tiles, map_origin
from tavf_mapkit.tilegrid import TileGrid, group_by_tile, tile_name

FORMATS = ("glb", "obj")
AXES = "glTF +Y up: (X, Y, Z) = (x - origin.x, z - origin.z, -(y - origin.y)), metres"


@dataclass
class ExportLayers:
    """What goes into the files: each layer is grouped by material (lane type, mark colour, solid kind)."""

    surface: LabelledMesh
    marks: LabelledMesh | None = None          # a RoadMarkMesh keeps its colours
    solids: LabelledMesh | None = None
    extra: dict = field(default_factory=dict)  # more facts for mesh.json (eps, deviation, ...)

    def groups(self) -> list[tuple[str, str, LabelledMesh]]:
        """(layer, material, mesh) in a fixed order."""
        out = []
        for layer, mesh in (("lanes", self.surface), ("marks", self.marks), ("solids", self.solids)):
            if mesh is None or not len(mesh.faces):
                continue
            colour = getattr(mesh, "colour", None)
            if layer == "marks" and colour is not None:
                from tavf_mapkit.mesh.marks import MARK_COLOURS

                for code in np.unique(colour):
                    out.append((layer, mark_material(MARK_COLOURS[int(code)]), mesh.select(colour == code)))
                continue
            for code in np.unique(mesh.kind):
                out.append((layer, SURFACE_KINDS[int(code)], mesh.select(mesh.kind == code)))
        return out


def to_file_axes(vertices: np.ndarray, origin) -> np.ndarray:
    """OpenDRIVE local (x, y, z) -> recentred glTF (X, Y, Z) as float32."""
    v = vertices - np.asarray(origin, dtype=float)
    return np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]).astype(np.float32)


def from_file_axes(points: np.ndarray, origin) -> np.ndarray:
    """Inverse of ``to_file_axes`` (float64 OpenDRIVE local coordinates)."""
    p = np.asarray(points, dtype=float)
    return np.column_stack([p[:, 0], -p[:, 2], p[:, 1]]) + np.asarray(origin, dtype=float)


def export_meshes(layers: ExportLayers, folder: str | Path, fmt: str = "glb", tile_size: float = 100.0,
                  origin=None, preview: bool = True) -> dict:
    """Write tiles, ``mesh.json`` and ``preview.png`` into ``folder``; return the mesh.json content."""
    check_export_options(fmt, tile_size)
    folder = Path(folder)
    (folder / "tiles").mkdir(parents=True, exist_ok=True)
    groups = layers.groups()
    grid = TileGrid(tuple(origin) if origin is not None else map_origin([g[2] for g in groups]), float(tile_size))
    # which tile every face of every group falls into, and the faces of each tile (one sort per group)
    per_group = [group_by_tile(face_tiles(grid, mesh)) for _, _, mesh in groups]
    tiles = sorted({tile for by_tile in per_group for tile in by_tile})
    if fmt == "obj":
        write_materials(folder, [g[1] for g in groups])
    tile_entries = []
    for index in tiles:
        members = [(layer, material, mesh.select(by_tile[index]))
                   for (layer, material, mesh), by_tile in zip(groups, per_group) if index in by_tile]
        tile_entries.append(write_tile(folder, fmt, grid, index, members))
    summary = mesh_summary(fmt, grid, tile_entries, triangle_counts(layers), {g[1] for g in groups}, layers.extra)
    if preview:
        from tavf_mapkit.mesh.preview import write_preview

        write_preview(layers, folder / "preview.png")
        summary["preview"] = "preview.png"
    write_text_atomic(folder / "mesh.json", json.dumps(summary, indent=2) + "\n")
    return summary


def check_export_options(fmt: str, tile_size: float) -> None:
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}")
    if not (tile_size > 0 and np.isfinite(tile_size)):
        raise ValueError("tile size must be a positive number of metres")


def write_materials(folder: Path, materials) -> None:
    """tiles/materials.mtl of an OBJ export."""
    write_text_atomic(Path(folder) / "tiles" / "materials.mtl", _mtl(list(materials)))


def write_tile(folder: Path, fmt: str, grid: TileGrid, index, members) -> dict:
    """Write one tile file from its (layer, material, mesh) members (in group order); return its mesh.json entry."""
    relative, data, entry = tile_file(fmt, grid, index, members)
    write_bytes_atomic(Path(folder) / relative, data)
    return entry


def tile_file(fmt: str, grid: TileGrid, index, members) -> tuple[str, bytes, dict]:
    """(path relative to the mesh folder, bytes, mesh.json entry) of one tile file from its (layer, material,
    mesh) members (in group order)."""
    counts = {"lanes": 0, "marks": 0, "solids": 0}
    for layer, _, part in members:
        counts[layer] += len(part.faces)
    relative = f"tiles/{tile_name(index)}.{fmt}"
    data = _glb(members, grid.origin) if fmt == "glb" else _obj(members, grid.origin).encode("utf-8")
    return relative, data, {"file": relative, "index": [int(index[0]), int(index[1])],
                            "bounds": grid.tile_bounds(index), "triangles": counts,
                            "materials": sorted({material for _, material, _ in members})}


def mesh_summary(fmt: str, grid: TileGrid, tile_entries: list, triangles: dict, materials, extra: dict) -> dict:
    """The content of mesh.json (without "preview")."""
    return {
        "format": fmt,
        "origin": {"x": grid.origin[0], "y": grid.origin[1], "z": grid.origin[2]},
        "axes": AXES if fmt == "glb" else AXES.replace("glTF", "OBJ"),
        "tile_size": grid.size,
        "tiles": tile_entries,
        "triangles": triangles,
        "materials": {material: [round(c, 4) for c in material_rgba(material)] for material in sorted(materials)},
        **extra,
    }


def triangle_counts(layers: ExportLayers) -> dict:
    surface = layers.surface
    junction = int(np.count_nonzero(surface.kind == KIND_CODE["junction"]))
    curb = int(np.count_nonzero(surface.kind == KIND_CODE["curb"]))
    return {
        "lanes": len(surface.faces) - junction - curb,
        "junctions": junction,
        "curb_faces": curb,
        "marks": 0 if layers.marks is None else len(layers.marks.faces),
        "solids": 0 if layers.solids is None else len(layers.solids.faces),
        "total": len(surface.faces) + sum(0 if m is None else len(m.faces)
                                                for m in (layers.marks, layers.solids)),
    }


def _glb(members, origin) -> bytes:
    from tavf_mapkit.mesh.gltf import glb_bytes

    return glb_bytes([{"name": f"{layer}_{material}", "positions": to_file_axes(mesh.vertices, origin),
                       "indices": mesh.faces, "uv": mesh.uv, "rgba": material_rgba(material),
                       "double_sided": layer == "marks"} for layer, material, mesh in members])


def _mtl(materials: list[str]) -> str:
    lines = ["# tavf-mapkit road materials"]
    for material in sorted(set(materials)):
        r, g, b, a = material_rgba(material)
        lines += [f"newmtl {material}", f"Kd {r:.4f} {g:.4f} {b:.4f}", "Ka 0 0 0", "Ks 0 0 0", f"d {a:.3f}",
                  "illum 1", ""]
    return "\n".join(lines)


def _obj(members, origin) -> str:
    out = io.StringIO()
    out.write("# tavf-mapkit road mesh (" + AXES.replace("glTF", "OBJ") + ")\nmtllib materials.mtl\n")
    offset, uv_offset = 1, 1
    for layer, material, mesh in members:
        vertices = to_file_axes(mesh.vertices, origin)
        out.write(f"o {layer}_{material}\nusemtl {material}\n")
        np.savetxt(out, vertices, fmt="v %.4f %.4f %.4f")
        faces = mesh.faces + offset
        if mesh.uv is not None:
            np.savetxt(out, mesh.uv, fmt="vt %.4f %.4f")
            texture = mesh.faces + uv_offset
            np.savetxt(out, np.stack([faces, texture], axis=2).reshape(-1, 6), fmt="f %d/%d %d/%d %d/%d")
            uv_offset += len(mesh.uv)
        else:
            np.savetxt(out, faces, fmt="f %d %d %d")
        offset += len(vertices)
    return out.getvalue()
