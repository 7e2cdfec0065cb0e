"""The mesh folder of a build (or of ``mapkit mesh``): road surface + road marks (+ scene solids) exported as
tiles, ``mesh.json``, ``preview.png`` and the labelled tiles the collision stage reads -- one function shared by
the pipeline stage and the command. The work is done tile by tile (``mesh.tiled``)."""

from __future__ import annotations

from pathlib import Path

from tavf_mapkit.fileutil import staged_folder
from tavf_mapkit.mesh.surface import DEFAULT_EPS
from tavf_mapkit.mesh.tiled import BATCH_WORK, write_tiled_mesh
from tavf_mapkit.progress import Progress

DEFAULT_TILE = 100.0


def write_mesh_folder(odr, folder: str | Path, eps: float = DEFAULT_EPS, fmt: str = "glb",
                      tile_size: float = DEFAULT_TILE, osm_path: Path | None = None, solids: bool = True,
                      preview: bool = True, batch_work: float = BATCH_WORK,
                      progress: Progress | None = None, fanout=None) -> dict:
    """Mesh the map and write ``folder`` (tiles/, labelled/, mesh.json, preview.png); return mesh.json's content.
    ``batch_work``: metres of lane meshed at once (memory grows with it; the files do not depend on it).
    ``progress``: told of each pass's units done (``tavf_mapkit.progress``). ``fanout``: a ``cluster.Fanout``, to
    mesh on a Dask cluster (``mesh.remote``; the same files)."""
    extra = {}
    if odr.georeference is not None:
        from dataclasses import asdict

        header = odr.header
        extra["georeference"] = {"proj": header.geo_reference,
                                 "offset": None if header.offset is None else asdict(header.offset)}
    return write_tiled_mesh(odr, folder, eps, fmt, tile_size, osm_path=osm_path, solids=solids, preview=preview,
                            batch_work=batch_work, extra=extra, progress=progress, fanout=fanout)


def replace_folder(target: Path, make) -> dict:
    """Run ``make(staging_folder)`` and put the result at ``target`` atomically (``fileutil.staged_folder``); a
    target that exists must be empty or an earlier mesh folder (with mesh.json), so nothing else is ever deleted."""
    with staged_folder(target, marker="mesh.json", what="the mesh folder",
                       refusal="folder is not empty and holds no mesh.json: refusing to replace it") as staging:
        return make(staging)
