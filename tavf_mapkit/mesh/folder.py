"""The mesh folder of a build (or of ``mapkit mesh``): road surface + road marks (+ scene solids) exported as
tiles, ``mesh.json``, ``preview.png`` and the labelled tiles the collision stage reads -- one function shared by
the pipeline stage and the command. The work is done tile by tile (``mesh.tiled``)."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from tavf_mapkit.errors import InputError
from tavf_mapkit.mesh.surface import DEFAULT_EPS
from tavf_mapkit.mesh.tiled import BATCH_WORK, write_tiled_mesh

DEFAULT_TILE = 100.0


def write_mesh_folder(odr, folder: str | Path, eps: float = DEFAULT_EPS, fmt: str = "glb",
                      tile_size: float = DEFAULT_TILE, osm_path: Path | None = None, solids: bool = True,
                      preview: bool = True, batch_work: float = BATCH_WORK) -> dict:
    """Mesh the map and write ``folder`` (tiles/, labelled/, mesh.json, preview.png); return mesh.json's content.
    ``batch_work``: metres of lane meshed at once (memory grows with it; the files do not depend on it)."""
    extra = {}
    if odr.georeference is not None:
        from dataclasses import asdict

        header = odr.header
        extra["georeference"] = {"proj": header.geo_reference,
                                 "offset": None if header.offset is None else asdict(header.offset)}
    return write_tiled_mesh(odr, folder, eps, fmt, tile_size, osm_path=osm_path, solids=solids, preview=preview,
                            batch_work=batch_work, extra=extra)


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
