"""mapkit build on a real Dask cluster on loopback (a `dask scheduler` and `dask worker` processes, each with its
own directory): the same mesh, collision world and preview as the single-process build, also when a worker is
killed mid-build; no Dask at all without --workers/--scheduler; one-line errors for a scheduler that is not
there and for contradicting options."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import shared_path
from dask_cluster import free_port, loopback_cluster, wait_until

pytest.importorskip("distributed")

MAPKIT = str(Path(sys.executable).parent / "mapkit")
PERTH = ("zoo", "osm", "AU_perth_peanut_roundabout_LHT.osm.gz")
NEUKOELLN = ("zoo", "osm", "DE_berlin_neukoelln.osm.gz")
BUILD_TIMEOUT = 600

# the build of the CLI in this process's interpreter, reporting at its end which Dask modules it imported
SERIAL_BUILD = """
import json, sys
from tavf_mapkit.cli.main import cli
try:
    cli(sys.argv[1:], standalone_mode=False)
finally:
    print("DASK-MODULES " + json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("dask", "distributed"))))
"""


def serial_build(source: Path, out: Path) -> list[str]:
    """Build without --workers/--scheduler; return the Dask modules the process imported."""
    done = subprocess.run([sys.executable, "-c", SERIAL_BUILD, "build", str(source), "-o", str(out), "-q"],
                          capture_output=True, text=True, timeout=BUILD_TIMEOUT, check=False)
    assert done.returncode == 0, done.stderr
    line = [line for line in done.stdout.splitlines() if line.startswith("DASK-MODULES ")][-1]
    return json.loads(line.removeprefix("DASK-MODULES "))


def files_of(build: Path) -> dict[str, bytes]:
    """Every file of mesh/ and collision/ and the preview, by path in the build."""
    out = {}
    for part in ("mesh", "collision"):
        for path in sorted((build / part).rglob("*")):
            if path.is_file():
                out[path.relative_to(build).as_posix()] = path.read_bytes()
    out["report/mesh_preview.png"] = (build / "report" / "mesh_preview.png").read_bytes()
    return out


def assert_same_files(reference: Path, other: Path) -> None:
    expected, got = files_of(reference), files_of(other)
    assert sorted(got) == sorted(expected)
    different = [name for name in expected if got[name] != expected[name]]
    assert not different, f"{len(different)} files differ, e.g. {different[:5]}"
    assert any(name.startswith("collision/tiles/") for name in expected)
    assert any(name.startswith("mesh/labelled/tile_") for name in expected)


@pytest.fixture(scope="module")
def perth_serial(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("serial") / "perth"
    imported = serial_build(shared_path(*PERTH), out)
    assert imported == [], f"a build without --workers/--scheduler imported {imported}"
    return out


def test_build_without_cluster_options_imports_no_dask(perth_serial):
    # the fixture's build ran in a fresh interpreter and reported no dask / distributed module at its end
    assert (perth_serial / "manifest.json").is_file()


def test_build_on_loopback_cluster_is_byte_identical(perth_serial, tmp_path):
    with loopback_cluster(tmp_path / "cluster", workers=2) as cluster:
        out = tmp_path / "distributed" / "perth"
        done = subprocess.run([MAPKIT, "build", str(shared_path(*PERTH)), "-o", str(out), "-q",
                               "--scheduler", cluster.address], capture_output=True, text=True,
                              timeout=BUILD_TIMEOUT, cwd=tmp_path, check=False)
        assert done.returncode == 0, done.stderr
        # the work ran on the workers: each holds the map (and its mesh units) the client sent it, pickled (no
        # shared filesystem, nothing read again)
        with cluster.client() as client:
            loaded = client.run(lambda: [type(value[0]).__name__ for key, value in
                                         __import__("tavf_mapkit.cluster").cluster._CACHE.items()
                                         if key[0] == "object"])
        assert sum(names == ["OpenDriveMap"] for names in loaded.values()) >= 1, loaded
    assert_same_files(perth_serial, out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "ok"


@pytest.mark.slow
def test_build_survives_a_killed_worker(tmp_path):
    source = shared_path(*NEUKOELLN)
    reference = tmp_path / "serial" / "neukoelln"
    serial_build(source, reference)
    with loopback_cluster(tmp_path / "cluster", workers=2) as cluster:
        out = tmp_path / "distributed" / "neukoelln"
        build = subprocess.Popen([MAPKIT, "build", str(source), "-o", str(out), "-q", "--scheduler",
                                  cluster.address], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 cwd=tmp_path, start_new_session=True)
        try:
            with cluster.client() as client:
                busy = {}

                def a_worker_is_busy() -> bool:
                    busy.update({addr: keys for addr, keys in client.processing().items() if keys})
                    return bool(busy)

                assert wait_until(a_worker_is_busy, timeout=BUILD_TIMEOUT, step=0.02), "no task ever ran"
                victim = next(iter(busy))
                pid = client.run(os.getpid, workers=[victim])[victim]
                os.killpg(os.getpgid(pid), signal.SIGKILL)  # the worker and its nanny: a machine lost
                assert wait_until(lambda: victim not in client.scheduler_info(n_workers=-1)["workers"], 60)
            _, stderr = build.communicate(timeout=BUILD_TIMEOUT)
        finally:
            if build.poll() is None:
                os.killpg(build.pid, signal.SIGKILL)
                build.wait()
        assert build.returncode == 0, stderr
    assert_same_files(reference, out)


def test_unreachable_scheduler_is_one_line(tmp_path):
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    started = time.monotonic()
    done = subprocess.run([MAPKIT, "build", str(shared_path(*PERTH)), "-o", str(tmp_path / "perth"),
                           "--scheduler", address], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "TAVF_CONNECT_TIMEOUT": "2"}, check=False)
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].startswith(f"Error: cannot reach the Dask scheduler at {address} within 2 s")
    assert time.monotonic() - started < 30
    assert not (tmp_path / "perth").exists()


def test_workers_and_scheduler_exclude_each_other(tmp_path):
    done = subprocess.run([MAPKIT, "build", str(shared_path(*PERTH)), "-o", str(tmp_path / "perth"),
                           "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 2
    assert done.stderr.strip() == ("Error: --workers and --scheduler exclude each other (a scheduler brings its "
                                   "own workers)")


def test_scheduler_address_of_unknown_scheme_is_one_line(tmp_path):
    done = subprocess.run([MAPKIT, "build", str(shared_path(*PERTH)), "-o", str(tmp_path / "perth"),
                           "--scheduler", "foo://127.0.0.1:1"], capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr  # the known schemes it lists depend on the installed Dask
    assert lines[0].startswith("Error: --scheduler foo://127.0.0.1:1: unknown address scheme 'foo' (known schemes: ")


def test_waiting_tasks_share_few_quiet_processes():
    """twin sweep's tasks only wait on their own drive process: 3 slots are threads of at most one process per
    core, whose workers do not profile (a profiler wakes each worker every 10 ms)."""
    import dask

    from tavf_mapkit.cluster import connect, local_processes

    assert local_processes(20) == min(20, os.cpu_count()) and local_processes(1) == 1
    with connect(workers=3, waiting_tasks=True) as fanout:
        info = fanout.client.scheduler_info(n_workers=-1)["workers"]
        assert len(info) == local_processes(3)
        assert sum(worker["nthreads"] for worker in info.values()) >= 3
        profiling = fanout.client.run(lambda: dask.config.get("distributed.worker.profile.enabled"))
        assert set(profiling.values()) == {False}
        # the drives (children of the workers) do not inherit Dask's aggressive malloc trimming
        trimming = fanout.client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
        assert set(trimming.values()) == {None}
    assert dask.config.get("distributed.worker.profile.enabled") is True  # this process's config is untouched



@pytest.mark.slow
def test_shared_bytes_lost_with_their_only_worker_are_sent_again(tmp_path):
    """Dask's memory manager keeps one replica of a broadcast; when that worker dies the bytes are gone and the
    scheduler cancels every task that needs them ("already forgotten": CI's killed-worker build, once). The
    FileFanout sends the file again and reruns the unfinished tasks."""
    from tavf_mapkit.cluster import connect, worker_map
    from tavf_mapkit.opendrive import load_opendrive

    source = shared_path("xodr", "esmini", "multi_intersections.xodr")
    with loopback_cluster(tmp_path / "cluster", workers=3) as cluster, \
            connect(scheduler=cluster.address) as fanout:
        cluster.wait_for_workers(3)
        shared = fanout.with_file(source)
        client = fanout.client

        def holders() -> set:
            return set(client.who_has([shared.future])[shared.future.key])

        assert wait_until(lambda: len(holders()) == 3, 60)
        client.amm.run_once()  # ReduceReplicas: one copy left
        assert wait_until(lambda: len(holders()) == 1, 60)
        (holder,) = holders()
        pid = client.run(os.getpid, workers=[holder])[holder]
        os.killpg(os.getpgid(pid), signal.SIGKILL)  # the worker and its nanny
        assert wait_until(lambda: holder not in client.scheduler_info(n_workers=-1)["workers"], 60)
        maps = list(shared.map(worker_map, (() for _ in range(4))))
    assert [len(odr.roads) for odr in maps] == [len(load_opendrive(source).roads)] * 4


def test_computing_workers_and_a_map_that_starts_before_it_is_read(tmp_path):
    """A build's local workers run with glibc's own malloc trimming (Dask's MALLOC_TRIM_THRESHOLD_=65536 made a
    worker page-fault 15x as often on Krems), without the sampling profiler and with the tasks' modules imported
    when they start; a map's first tasks run before its first result is asked for (the workers make the junction
    curbs while the client places buildings), and its results still come in order."""
    from tavf_mapkit.cluster import connect
    from tavf_mapkit.mesh.remote import TASK_MODULES

    marks = [tmp_path / f"ran-{k}" for k in range(3)]
    with connect(workers=1) as fanout:
        settings = fanout.client.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"),
                                              __import__("dask").config.get("distributed.worker.profile.enabled"),
                                              all(name in sys.modules for name in TASK_MODULES)))
        assert set(settings.values()) == {(None, False, True)}, settings
        results = fanout.map(Path.write_text, [(mark, str(k)) for k, mark in enumerate(marks)])
        # no result read yet: the tasks were submitted, and ran
        assert wait_until(lambda: all(mark.is_file() for mark in marks), 60), "the tasks waited to be read"
        assert list(results) == [1, 1, 1]
    assert [mark.read_text() for mark in marks] == ["0", "1", "2"]
