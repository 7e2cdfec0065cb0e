"""The mesh folder of a build (or of ``mapkit mesh``): road surface + road marks (+ scene solids) exported as
tiles, ``mesh.json`` and ``preview.png`` -- one function shared by the pipeline stage and the command."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from tavf_mapkit.errors import InputError
from tavf_mapkit.fileutil import write_bytes_atomic
from tavf_mapkit.mesh.export import ExportLayers, export_meshes
from tavf_mapkit.mesh.marks import MARK_COLOURS, road_marks
from tavf_mapkit.mesh.solids import scene_solid_parts
from tavf_mapkit.mesh.surface import DEFAULT_EPS, build_road_surface

DEFAULT_TILE = 100.0
SURFACE_FILE = "surface.npz"
SOLIDS_FILE = "solids.npz"


def write_mesh_folder(odr, folder: str | Path, eps: float = DEFAULT_EPS, fmt: str = "glb",
                      tile_size: float = DEFAULT_TILE, osm_path: Path | None = None, solids: bool = True,
                      preview: bool = True) -> dict:
    """Mesh the map and write ``folder`` (tiles/, mesh.json, preview.png); return mesh.json's content."""
    surface = build_road_surface(odr, eps)
    marks = road_marks(odr, eps, surface.samples)
    scene = scene_solid_parts(odr, surface.mesh, osm_path, eps) if solids else None
    samples = surface.samples
    extra = {
        "eps": eps,
        "deviation": {
            "max_m": round(samples.max_deviation, 6),
            "method": "largest distance between mesh and exact OpenDRIVE point at the same (s, t), at 1/4, 1/2 "
                      "and 3/4 of every segment on every lane border and quad diagonal",
            "discontinuities": samples.discontinuities,
            "unresolved_segments": samples.unresolved,
        },
        "junctions": len(surface.junction_footprints),
        "mark_colours": list(MARK_COLOURS),
        "solids": scene is not None,
        # the labelled road surface and the scene solids, so the collision stage can reuse them
        "surface": {"file": SURFACE_FILE, "eps": eps},
    }
    if scene is not None:
        extra["scene_solids"] = {"file": SOLIDS_FILE, "eps": eps,
                                 "buildings_from": None if osm_path is None else Path(osm_path).name}
    if odr.georeference is not None:
        from dataclasses import asdict

        header = odr.header
        extra["georeference"] = {"proj": header.geo_reference,
                                 "offset": None if header.offset is None else asdict(header.offset)}
    summary = export_meshes(ExportLayers(surface.mesh, marks, None if scene is None else scene.mesh(), extra),
                            folder, fmt, tile_size, preview=preview)
    write_bytes_atomic(Path(folder) / SURFACE_FILE, surface.mesh.to_npz_bytes())
    if scene is not None:
        write_bytes_atomic(Path(folder) / SOLIDS_FILE, scene.to_npz_bytes())
    return summary


def replace_folder(target: Path, make) -> dict:
    """Run ``make(staging_folder)`` and put the result at ``target`` atomically (rename); a target that
    exists must be empty or an earlier mesh folder (with mesh.json), so nothing else is ever deleted."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise InputError("exists and is not a folder", file=str(target))
    if target.is_dir() and any(target.iterdir()) and not (target / "mesh.json").is_file():
        raise InputError("folder is not empty and holds no mesh.json: refusing to replace it", file=str(target))
    parent = target.parent if str(target.parent) else Path(".")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.staging-", dir=parent))
    except OSError as error:
        raise InputError(f"cannot write there ({error.strerror})", file=str(target)) from None
    try:
        os.chmod(staging, 0o755)
        result = make(staging)
        old = None
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=parent))
            os.replace(target, old / "previous")
        os.replace(staging, target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return result
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
