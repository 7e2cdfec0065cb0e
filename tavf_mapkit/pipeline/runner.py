"""Run a pipeline into a build folder: reuse unchanged stages, run the rest, write manifest.json, swap.

A stage is reused when its fingerprint -- name, code version, options and the sha256 of every artifact it
reads -- equals the one recorded in the existing build's manifest; its outputs are then copied from the
existing build (copies, not hard links: a later stage that rewrote a linked file in place would change
the old build too, and the old build must stay intact until the new one is in place).
"""

from __future__ import annotations

import datetime as _dt
import resource
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tavf_mapkit import __version__
from tavf_mapkit.errors import InputError, MapkitError, StageError
from tavf_mapkit.memory import return_freed_memory
from tavf_mapkit.osm.files import OSM_SUFFIXES, is_osm_file
from tavf_mapkit.pipeline.beside import BesideStage, may_start
from tavf_mapkit.pipeline.buildfolder import BuildFolder
from tavf_mapkit.pipeline.config import PipelineConfig
from tavf_mapkit.pipeline.context import BuildContext
from tavf_mapkit.pipeline.manifest import (
    MANIFEST_VERSION,
    OSM_ATTRIBUTION,
    canonical,
    file_sha256,
    fingerprint,
    path_bytes,
    path_sha256_and_bytes,
    read_manifest,
    stage_record,
    tool_versions,
    write_manifest,
)
from tavf_mapkit.pipeline.stages import get_stage, unavailable_modules
from tavf_mapkit.progress import Progress, silent
from tavf_mapkit.sumonet import SUMO_NET_SUFFIXES, is_sumo_net

EXIT_CODES = {0: "ok", 1: "a stage failed", 2: "bad input or options", 130: "interrupted"}
OPENDRIVE_SUFFIXES = (".xodr",)
INPUT_KINDS = {"osm": "OSM", "sumo-net": "SUMO network", "opendrive": "OpenDRIVE"}


@dataclass(frozen=True)
class BuildResult:
    folder: Path
    manifest: dict


def input_kind(path: Path) -> str:
    """"osm", "sumo-net" or "opendrive" from the file name; anything else is refused."""
    if is_osm_file(path):
        return "osm"
    if is_sumo_net(path):
        return "sumo-net"
    if str(path).lower().endswith(OPENDRIVE_SUFFIXES):
        return "opendrive"
    raise InputError(f"unknown input type: expected OSM ({', '.join(OSM_SUFFIXES)}), a SUMO network "
                     f"({', '.join(SUMO_NET_SUFFIXES)}) or OpenDRIVE ({', '.join(OPENDRIVE_SUFFIXES)})",
                     file=str(path))


def default_build_name(input_path: Path, config: PipelineConfig) -> str:
    """The pipeline's name if a pipeline file was given, else the input's name without its suffixes."""
    if config.file is not None and config.name:
        return config.name
    name = input_path.name
    for suffix in sorted((*OSM_SUFFIXES, *SUMO_NET_SUFFIXES, *OPENDRIVE_SUFFIXES), key=len, reverse=True):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "build"


def run_build(input_path: str | Path, config: PipelineConfig, output: str | Path | None = None, *,
              force: bool = False, progress: Callable[[str], None] | None = None,
              command: str | None = None, notice: Callable[[str], None] | None = None,
              meter: Callable[[str], Progress] | None = None, fanout=None) -> BuildResult:
    """Build ``input_path`` with ``config`` into ``output`` (default build/NAME); return the manifest.

    ``progress`` gets a line per stage; ``notice`` the lines a user must see even without progress (the
    recovery from a killed build), by default also ``progress``. ``meter(label)`` gives the Progress of the
    stage labelled "[4/7] mesh" while it runs (``ProgressLine.task``); without it stages report to nobody.
    ``fanout``: a ``cluster.Fanout``, to run the tile stages' work as Dask tasks (same files)."""
    started = time.perf_counter()
    progress = progress or (lambda line: None)
    input_path = Path(input_path)
    kind = input_kind(input_path)
    if not input_path.is_file():
        raise InputError("file not found" if not input_path.exists() else "is not a file",
                         file=str(input_path))
    if kind == "opendrive" and config.section("area"):
        raise InputError("an area (--bbox, --polygon, [area]) cuts OSM or SUMO input; an OpenDRIVE input is built "
                         "whole", file=str(input_path))
    target = Path(output) if output else Path("build") / default_build_name(input_path, config)
    if target.name in ("", ".", ".."):
        raise InputError("the build folder needs a name (e.g. -o build/tavf)", file=str(target))
    name = target.name
    input_record = {"role": "input", "path": str(input_path.resolve()), "kind": kind,
                    "sha256": file_sha256(input_path), "bytes": input_path.stat().st_size}

    with BuildFolder(target, notify=notice or progress) as folder:
        previous = None if force or folder.existing is None else read_manifest(folder.target)
        context = BuildContext(name=name, folder=folder.staging, input_path=input_path.resolve(),
                               input_kind=kind, config=config, artifacts={"input": input_path.resolve()},
                               notify=progress, fanout=fanout)
        hashes = {"input": input_record["sha256"]}
        if kind == "opendrive":
            # an OpenDRIVE input is the map itself: the stages after netconvert start from it (the opendrive
            # stage puts the build's copy, NAME.xodr, in its place)
            context.artifacts["xodr"] = input_path.resolve()
            hashes["xodr"] = input_record["sha256"]
        records = []
        stages = [get_stage(stage_name) for stage_name in config.stages]
        beside: dict[int, BesideStage] = {}  # stages started early in processes of their own (beside.py)
        try:
            for index, stage_name in enumerate(config.stages, 1):
                _start_beside(stages, index - 1, context, hashes, previous, beside)
                early = beside.pop(index - 1, None)
                try:
                    record = _run_stage(stage_name, context, hashes, previous, folder.target, progress,
                                        f"[{index}/{len(config.stages)}]", meter, early)
                finally:
                    if early is not None:  # taken, or started with options that changed since: ended
                        early.stop()
                records.append(record)
                # each stage loads the map anew: what this one freed must not stay resident under the next one's
                # peak (on Maribor the check stage started from 0.8 GB the mesh stage had freed)
                return_freed_memory()
        finally:
            for early in beside.values():  # the build failed or was interrupted before it reached them
                early.stop()
        _remove_failure_logs(folder.target)
        manifest = _manifest(name, input_record, config, context, records, started, command)
        write_manifest(folder.staging, manifest)
        folder.commit()
    return BuildResult(folder.target, manifest)


def _start_beside(stages: list, position: int, context: BuildContext, hashes: dict, previous: dict | None,
                  beside: dict) -> None:
    """Start the later stages that may run beside ``stages[position]`` and those after it (beside.py) and would
    run at all (not reused from the previous build)."""
    for candidate in range(position + 1, len(stages)):
        if candidate in beside or not may_start(stages, position, candidate, context):
            continue
        stage = stages[candidate]
        try:
            stage_fingerprint = _identity(stage, context, hashes)[2]
        except MapkitError:
            continue  # its options are wrong: it fails in its turn, after the stages before it
        old = stage_record(previous, stage.name)
        if old and old.get("fingerprint") == stage_fingerprint:
            continue  # reused when its turn comes
        beside[candidate] = BesideStage(stage, context, stage_fingerprint)
        context.running_beside.add(stage.name)


def _identity(stage, context: BuildContext, hashes: dict) -> tuple[dict, dict, str]:
    """(the hashes of the artifacts it reads, its options, its fingerprint) as the build stands."""
    used = {artifact: hashes[artifact] for artifact in (*stage.inputs, *stage.optional_inputs)
            if artifact in context.artifacts}
    options = canonical(stage.options(context))
    return used, options, fingerprint(stage.name, stage.version, options, used)


def _run_stage(stage_name: str, context: BuildContext, hashes: dict, previous: dict | None, target: Path,
               progress: Callable[[str], None], counter: str,
               meter: Callable[[str], Progress] | None = None, early: BesideStage | None = None) -> dict:
    stage = get_stage(stage_name)
    if stage is None:
        reason = unavailable_modules().get(stage_name)
        note = f"stage {stage_name} not available" + (f": {reason}" if reason else "")
        progress(f"{counter} {stage_name}: {note}")
        return {"name": stage_name, "status": "unavailable", "note": note}
    if context.input_kind not in stage.input_kinds:
        note = f"not for {INPUT_KINDS.get(context.input_kind, context.input_kind)} input"
        progress(f"{counter} {stage_name}: skipped, {note}")
        return {"name": stage_name, "status": "skipped", "note": note}
    missing = [artifact for artifact in stage.inputs if artifact not in context.artifacts]
    if missing:
        note = f"needs {', '.join(missing)}, which no earlier stage made"
        progress(f"{counter} {stage_name}: skipped, {note}")
        return {"name": stage_name, "status": "skipped", "note": note}

    started, seconds_beside = time.perf_counter(), None
    try:
        used, options, stage_fingerprint = _identity(stage, context, hashes)
        old = stage_record(previous, stage_name)
        if old and old.get("fingerprint") == stage_fingerprint and _copy_outputs(old, target, context.folder):
            status, outputs, facts = "unchanged", old["outputs"], old.get("facts", {})
        else:
            if early is not None and early.fingerprint == stage_fingerprint:
                result, seconds_beside = early.result(context.note)
            else:
                if early is not None:  # started with options that changed since: it would write beside this run
                    early.stop()
                context.progress = meter(f"{counter} {stage_name}") if meter is not None else silent
                try:
                    result = stage.run(context)
                finally:
                    context.progress = silent
            status, facts = "ran", result.facts
            outputs = {}
            for artifact, relative in result.files.items():
                path = context.folder / relative
                if not path.exists():
                    raise StageError(f"stage {stage_name} reported {relative} but did not write it")
                sha256, size = path_sha256_and_bytes(path)
                outputs[artifact] = {"path": relative, "sha256": sha256, "bytes": size}
    except MapkitError as error:
        _point_at_user_files(error, context)
        _keep_failure_log(error, stage_name, context, target)
        raise
    except OSError as error:
        raise StageError(f"stage {stage_name}: {error.strerror or error}",
                         file=getattr(error, "filename", None)) from None
    # a stage that ran beside others took its own time, not the time the pipeline waited for it
    seconds = seconds_beside if seconds_beside is not None else time.perf_counter() - started

    for artifact, info in outputs.items():
        context.artifacts[artifact] = context.folder / info["path"]
        hashes[artifact] = info["sha256"]
    context.facts[stage_name] = facts
    wording = f"ran in {seconds:.2f} s" if status == "ran" else "unchanged, reused"
    if seconds_beside is not None:
        wording += " beside the stages before it"
    progress(f"{counter} {stage_name}: {wording}")
    usage_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    usage_children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    record = {
        "name": stage_name, "status": status, "version": stage.version, "fingerprint": stage_fingerprint,
        "inputs": used, "options": options, "outputs": outputs, "facts": facts, "seconds": round(seconds, 4),
        # ru_maxrss is in KiB on Linux; both are maxima so far in this build, not per stage
        "peak_rss_mib": {"mapkit": round(usage_self / 1024, 1),
                         "subprocesses": round(usage_children / 1024, 1)},
    }
    if seconds_beside is not None:
        record["beside"] = True  # in a process of its own while the stages before it ran (pipeline/beside.py)
    return record


def _copy_outputs(record: dict, previous: Path, staging: Path) -> bool:
    """Copy a reused stage's outputs from the existing build; False if any is missing or changed size."""
    outputs = record.get("outputs") or {}
    for info in outputs.values():
        source = previous / info["path"]
        if not source.exists() or path_bytes(source) != info.get("bytes"):
            return False
    for info in outputs.values():
        source, destination = previous / info["path"], staging / info["path"]
        destination.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, destination, dirs_exist_ok=True)
        else:
            shutil.copy2(source, destination)
    return True


def _point_at_user_files(error: MapkitError, context: BuildContext) -> None:
    """Errors about the build's private copy of the input (source/...) name the user's file instead."""
    if not error.file:
        return
    path = Path(error.file)
    path = path if path.is_absolute() else context.folder / path
    if context.input_kind == "opendrive" and path == context.folder / f"{context.name}.xodr":
        error.file = str(context.input_path)  # the build's copy of the user's map
        return
    try:
        path.relative_to(context.folder / "source")
    except ValueError:
        return
    error.file = str(context.input_path)


def _keep_failure_log(error: MapkitError, stage_name: str, context: BuildContext, target: Path) -> None:
    """The staging folder is about to be removed; keep the failed stage's log next to the build folder."""
    log = context.folder / "logs" / f"{stage_name}.log"
    if not log.is_file():
        return
    kept = target.parent / f"{target.name}.failed-{stage_name}.log"
    try:
        shutil.copyfile(log, kept)
    except OSError:
        return
    error.message = f"{error.message} (log: {kept})"


def _remove_failure_logs(target: Path) -> None:
    for log in target.parent.glob(f"{target.name}.failed-*.log"):
        log.unlink(missing_ok=True)


def _manifest(name: str, input_record: dict, config: PipelineConfig, context: BuildContext,
              records: list[dict], started: float, command: str | None) -> dict:
    from tavf_mapkit.pipeline.summary import derived_from_osm

    inputs = [input_record]
    if config.file is not None:
        inputs.append({"role": "pipeline", "path": str(config.file), "sha256": file_sha256(config.file),
                       "bytes": config.file.stat().st_size})
    for role, path in config.path_options().items():
        exists = path.is_file()
        inputs.append({"role": role, "path": str(path), "sha256": file_sha256(path) if exists else None,
                       "bytes": path.stat().st_size if exists else None})
    netconvert = context.facts.get("netconvert", {}).get("netconvert")
    if netconvert is None and any(r.get("name") == "netconvert" for r in records):
        from tavf_mapkit.netconvert import netconvert_version

        netconvert = netconvert_version()
    georeference = driving_side = None
    for record in records:
        georeference = (record.get("facts") or {}).get("georeference") or georeference
        driving_side = (record.get("facts") or {}).get("driving_side") or driving_side
    artifacts = {artifact: {**info, "stage": record["name"]}
                 for record in records for artifact, info in (record.get("outputs") or {}).items()}
    return {
        "manifest_version": MANIFEST_VERSION,
        "name": name,
        "built_at": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "mapkit": __version__,
        "command": command,
        "status": "ok",
        "input": input_record,
        "inputs": inputs,
        "pipeline": config.to_dict(),
        "tools": tool_versions(netconvert),
        "stages": records,
        "artifacts": artifacts,
        "georeference": georeference,
        "driving_side": driving_side,
        "attribution": OSM_ATTRIBUTION if derived_from_osm(context.input_path, context.input_kind) else None,
        "seconds": round(time.perf_counter() - started, 4),
        "python_executable": sys.executable,
    }
