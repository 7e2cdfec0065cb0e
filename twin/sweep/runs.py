"""One run of a sweep: ``twin drive`` in its own process with a deadline, and what it left (metrics.json,
collisions.csv, udm_latency.csv) read back as bytes, so a run on a Dask worker sends its results home.

On a cluster the build reaches a worker as one archive of the files a drive reads (``pack_build``; no mesh
tiles, report, logs or OSM copy), sent once (``cluster.FileFanout``-style scatter) and unpacked into a folder
named after its sha256 under the worker's temporary directory (``unpacked_build``), so runs on the same worker
share it and no shared filesystem is needed.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from tavf_mapkit.errors import InputError
from twin.sweep.plan import DriveOptions

KEPT = ("metrics.json", "collisions.csv", "udm_latency.csv")  # what a run sends back
LEFT_OUT = ("report", "logs", "source", "mesh/tiles", "mesh/preview.png")  # what a drive never reads
ERROR_TAIL = 2000  # characters of a failed run's stderr kept


def drive_once(build: str | Path, seed: int, options: DriveOptions, deadline: float | None = None) -> dict:
    """Run ``twin drive --map BUILD`` for one seed in a fresh process (its own session, killed whole past the
    deadline). Returns {"seed", "exit", "status" ("ok", "failed", "timeout"), "wall_s", "files": {name:
    bytes}, "error": last stderr line or ""}."""
    deadline = options.deadline() if deadline is None else deadline
    command = [sys.executable, "-m", "twin.cli.main", "drive", "--map", str(build)]
    with tempfile.TemporaryDirectory(prefix=f"tavf-sweep-{seed}-") as scratch:
        out = Path(scratch) / "run"
        command += ["-o", str(out), *options.arguments(seed)]
        started = time.perf_counter()
        with batch_policy():
            process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                       stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            _, stderr = process.communicate(timeout=deadline)
            status = "ok" if process.returncode == 0 else "failed"
        except subprocess.TimeoutExpired:
            _kill_group(process)
            _, stderr = process.communicate()
            status = "timeout"
        finally:
            _kill_group(process)  # helpers it left behind (the UDM client, SUMO tools)
        wall = time.perf_counter() - started
        files = {name: (out / name).read_bytes() for name in KEPT if (out / name).is_file()}
    text = stderr.decode("utf-8", "replace")
    error = ""
    if status == "timeout":
        error = f"no result within {deadline:g} s (killed)"
    elif status == "failed":
        lines = [line for line in text.strip().splitlines() if line.strip()]
        error = lines[-1][:300] if lines else f"exit {process.returncode}"
    return {"seed": int(seed), "exit": process.returncode, "status": status, "wall_s": round(wall, 3),
            "files": files, "error": error}


@contextlib.contextmanager
def batch_policy() -> Iterator[None]:
    """Processes started inside run under SCHED_BATCH (Linux; elsewhere nothing changes): the calling thread
    takes the policy for the moment of the fork and the child inherits it.

    Why: a sweep puts many drives on few cores, and their simulation steps are throughput work -- a paced drive
    sleeps most of every step, an unpaced one only wants the most steps per second. A batch thread never
    preempts another when it wakes, so with a fleet against a UDM (``--udm``) a woken simulation step does not
    interrupt a UDM request in flight: the UDM client's process sets itself back to the normal policy
    (twin.udm.process_client), as does the UDM server, which runs outside the sweep. The policy changes when
    a step runs, never what it computes."""
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux, or not allowed here: run with the policy we have
        yield
        return
    try:
        yield
    finally:
        os.sched_setscheduler(0, *before)


def _kill_group(process: subprocess.Popen) -> None:
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


# -- the build on a worker ---------------------------------------------------------------------------------------

def pack_build(build: str | Path) -> bytes:
    """The build folder's files a drive reads, as an uncompressed tar (sorted names, zeroed times and owners: the
    same build gives the same bytes, so its sha256 names it)."""
    folder = Path(build)
    if not (folder / "manifest.json").is_file():
        raise InputError("not a build folder (no manifest.json); make one with `mapkit build INPUT -o FOLDER`",
                         file=str(folder))
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as archive:
        for path in sorted(folder.rglob("*")):
            relative = path.relative_to(folder).as_posix()
            if any(relative == skip or relative.startswith(skip + "/") for skip in LEFT_OUT) or not path.is_file():
                continue
            info = tarfile.TarInfo(relative)
            info.size = path.stat().st_size
            info.mode = 0o644
            with path.open("rb") as handle:
                archive.addfile(info, handle)
    return buffer.getvalue()


def unpacked_build(digest: str, data: bytes, name: str) -> Path:
    """The packed build, unpacked once per machine into TMPDIR/tavf-sweep-builds/SHA256/NAME (a staging folder
    renamed into place, so concurrent runs never see half of it)."""
    root = Path(tempfile.gettempdir()) / "tavf-sweep-builds" / digest
    target = root / name
    if target.is_dir():
        return target
    if hashlib.sha256(data).hexdigest() != digest:
        raise RuntimeError(f"build archive {name} arrived damaged (sha256 differs)")
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=root))
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r") as archive:
            archive.extractall(staging, filter="data")
        try:
            os.rename(staging, target)
        except OSError:
            if not target.is_dir():  # another run won the race: use its copy
                raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def drive_task(digest: str, data: bytes, name: str, seed: int, options: DriveOptions, deadline: float) -> dict:
    """A Dask task: one run on the build sent as (sha256, archive, name)."""
    result = drive_once(unpacked_build(digest, data, name), seed, options, deadline)
    result["worker"] = os.uname().nodename
    return result
