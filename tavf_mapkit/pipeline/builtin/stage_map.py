"""The build's map, loaded once for the stages that read it (mesh, then check), when it is small.

Each stage used to load NAME.xodr anew: on DLR's TAVF net (11 MB) a load is about a second, once in the mesh
stage and once in the check stage. A map whose file is at most ``KEEP_BYTES`` stays loaded from the mesh stage
to the check stage (the collision stage between them does not read it); the opendrive stage, which reads the
file it wrote once to snapshot it, keeps that map for the mesh stage. A larger one is still loaded by each
stage and let go after it, so a region's map is never held under the next stage's peak. The map is kept for one
build (its BuildContext) and one file (path, size, change time, inode): a rewritten file is loaded anew.
"""

from __future__ import annotations

from tavf_mapkit.pipeline.context import BuildContext

#: files up to this size are kept loaded between stages (TAVF 11 MB, Krems 3 MB; a region's are hundreds)
KEEP_BYTES = 32 << 20


def _file_key(context: BuildContext, path=None) -> tuple:
    path = context.artifacts["xodr"] if path is None else path
    status = path.stat()
    return str(path), status.st_size, status.st_mtime_ns, status.st_ino


def keep_map(context: BuildContext, path, odr) -> None:
    """Keep ``odr``, the map just read from ``path`` (the build's NAME.xodr), for the next stage that reads it,
    when the file is small (the opendrive stage reads it once to snapshot it: the mesh stage need not again)."""
    key = _file_key(context, path)
    context.kept_map = (key, odr) if key[1] <= KEEP_BYTES else None


def stage_map(context: BuildContext, keep: bool = True):
    """The build's OpenDRIVE map (``context.opendrive()``), the kept one if this build has it for this file;
    kept on the build's context for the next stage when ``keep`` and the file is small (it goes with the build,
    failed or not)."""
    key = _file_key(context)
    if context.kept_map is not None and context.kept_map[0] == key:
        return context.kept_map[1]
    odr = context.opendrive()
    # the check stage running beside the others loads its own: kept, the map would only be held to the end
    keep = keep and "check" not in context.running_beside
    context.kept_map = (key, odr) if keep and key[1] <= KEEP_BYTES else None
    return odr


def take_kept_map(context: BuildContext):
    """The map kept for this build and file, or None; no longer kept afterwards (its last reader has it)."""
    kept, context.kept_map = context.kept_map, None
    if kept is None:
        return None
    try:
        return kept[1] if kept[0] == _file_key(context) else None
    except OSError:
        return None
