"""The build's map, loaded once for the stages that read it (mesh, then check), when it is small.

Each stage used to load NAME.xodr anew: on DLR's TAVF net (11 MB) a load is about a second, once in the mesh
stage and once in the check stage. A map whose file is at most ``KEEP_BYTES`` stays loaded from the mesh stage
to the check stage (the collision stage between them does not read it). A larger one is still loaded by each
stage and let go after it, so a region's map is never held under the next stage's peak. The map is kept for one
build (its BuildContext) and one file (path, size, change time, inode): a rewritten file is loaded anew.
"""

from __future__ import annotations

import weakref

from tavf_mapkit.pipeline.context import BuildContext

#: files up to this size are kept loaded between stages (TAVF 11 MB, Krems 3 MB; a region's are hundreds)
KEEP_BYTES = 32 << 20

_kept: dict[int, tuple[tuple, object]] = {}  # id(context) -> (file key, OpenDriveMap)


def _file_key(context: BuildContext) -> tuple:
    path = context.artifacts["xodr"]
    status = path.stat()
    return str(path), status.st_size, status.st_mtime_ns, status.st_ino


def stage_map(context: BuildContext, keep: bool = True):
    """The build's OpenDRIVE map (``context.opendrive()``), the kept one if this build has it for this file;
    kept for the next stage when ``keep`` and the file is small."""
    key = _file_key(context)
    kept = _kept.get(id(context))
    if kept is not None and kept[0] == key:
        return kept[1]
    odr = context.opendrive()
    if keep and key[1] <= KEEP_BYTES:
        if id(context) not in _kept:
            weakref.finalize(context, _kept.pop, id(context), None)  # gone with the build, failed or not
        _kept[id(context)] = (key, odr)
    return odr


def take_kept_map(context: BuildContext):
    """The map kept for this build and file, or None; no longer kept afterwards (its last reader has it)."""
    kept = _kept.pop(id(context), None)
    if kept is None:
        return None
    try:
        return kept[1] if kept[0] == _file_key(context) else None
    except OSError:
        return None
