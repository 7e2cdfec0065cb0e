"""Dask, only when asked: the connection to a cluster shared by ``mapkit build --workers/--scheduler`` and
``twin sweep``, and the few ways our code hands work to it.

Nothing here imports Dask at module level: without ``--workers``/``--scheduler`` no Dask module is ever loaded
(tests/test_distributed_build.py checks it), and the single-process paths stay exactly as they are.

- ``connect(workers=N)`` starts a LocalCluster of N processes with one thread each (our stages are numpy and
  Python code that holds the GIL; libsumo allows one simulation per process). With ``waiting_tasks`` (``twin
  sweep``, whose tasks only wait on a ``twin drive`` process of their own) the N task slots are threads of at
  most one process per core, and the workers' sampling profiler and fast health ticks are off (see
  ``WAITING_TASKS_CONFIG``); ``connect(scheduler=ADDR)`` joins
  a running scheduler (a laptop, SSH hosts, Slurm via dask-jobqueue, Kubernetes via dask-kubernetes), waiting
  at most ``CONNECT_TIMEOUT`` seconds for it and for its first worker, so a wrong address is one line, not a hang.
- ``Fanout.map`` runs a top-level function over argument tuples and yields the results in order, with a bounded
  number of tasks in flight (the client's memory holds a window of results, not all of them). A task of a worker
  that dies is run again on another one by the scheduler (``distributed.scheduler.allowed-failures``).
- ``Fanout.with_file(path)`` sends a file's bytes to the cluster once (``Client.scatter``, content-addressed by
  sha256); every task of the returned ``FileFanout`` gets (sha256, bytes) first, and ``worker_cached`` keeps
  what a worker made of them (a loaded map) for the next task. ``Fanout.with_object(value)`` sends an object
  the client has made (the loaded map and its mesh units) pickled: a worker unpickles it in a tenth of the time
  it would take to make it again (Krems: 0.3 s, not 2.6 s of reading the OpenDRIVE and cutting units).
  Workers need no shared filesystem. Bytes lost with a worker (Dask's memory manager keeps one replica of a
  broadcast) are sent again and the tasks that needed them rerun.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from tavf_mapkit.errors import InputError, StageError

# s to reach a scheduler, and for it to have a worker (TAVF_CONNECT_TIMEOUT: a slow network's, or a test's)
CONNECT_TIMEOUT = float(os.environ.get("TAVF_CONNECT_TIMEOUT", "10"))
TASKS_PER_WORKER = 3     # tasks in flight per worker: enough to keep each busy while the client takes results
INSTALL_HINT = "pip install 'tavf-mapkit[distributed]'"

# Dask's nanny starts each worker with MALLOC_TRIM_THRESHOLD_=65536 (and sets it in the starting process's own
# environment, where every later worker and child process inherits it): glibc then hands freed memory back to
# the kernel at once and takes it again for the next array. On Krems a build's worker page-faulted 885,000
# times (3.5 s of system time in 28 s) against 58,000 with glibc's own adaptive threshold, and its CPU for the
# same tasks went from 23.6 to 17.9 s; a sweep's `twin drive` processes inherited it from their worker. Our
# workers live as long as a build or a sweep. None: not set (a value in the user's environment still holds).
NO_MALLOC_TRIM = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}

# Workers whose tasks only wait (on a child process) have nothing to profile or watch closely. Dask's defaults
# wake every worker ~150 times a second (a stack sample every 10 ms, an event-loop tick every 20 ms, a memory
# check every 100 ms): an idle LocalCluster of 20 such workers took 0.41 of this 2-core machine's cores, and
# during a sweep of 20 twins at real time a dozen of its threads were runnable at any moment, each wake-up
# delaying the twins and their UDM requests. With this: 0.06 cores for 20 workers, 0.013 for 2 x 10 threads.
WAITING_TASKS_CONFIG = {
    **NO_MALLOC_TRIM,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "2s",
}

# Workers that compute (a build's tile stages): the sampling profiler (a stack sample every 10 ms) measures
# nothing we read; the tasks' modules are imported when a worker starts (``mesh.remote.dask_setup``).
COMPUTING_TASKS_CONFIG = {
    **NO_MALLOC_TRIM,
    "distributed.worker.profile.enabled": False,
    "distributed.worker.preload": ["tavf_mapkit.mesh.remote"],
}


def check_cluster_options(workers: int | None, scheduler: str | None) -> None:
    """--workers and --scheduler exclude each other; N >= 1; an address looks like tcp://HOST:PORT."""
    if workers is not None and scheduler is not None:
        raise InputError("--workers and --scheduler exclude each other (a scheduler brings its own workers)")
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, not {workers}")
    if scheduler is not None and "://" not in scheduler and ":" not in scheduler:
        raise InputError(f"--scheduler {scheduler!r}: expected an address such as tcp://HOST:8786")


def wants_cluster(workers: int | None, scheduler: str | None) -> bool:
    """Whether the options ask for Dask: a scheduler, or more than one worker (one worker is this process)."""
    return scheduler is not None or (workers is not None and workers > 1)


@contextmanager
def connect(workers: int | None = None, scheduler: str | None = None,
            timeout: float | None = None, waiting_tasks: bool = False) -> Iterator[Fanout]:
    """A Fanout on a LocalCluster of ``workers`` processes, or on the scheduler at ``scheduler``; closed (and the
    local cluster stopped) when the block ends. ``waiting_tasks``: the tasks wait on processes of their own
    (a sweep's drives), so ``workers`` slots are threads of ``local_processes(workers)`` quiet processes."""
    check_cluster_options(workers, scheduler)
    timeout = CONNECT_TIMEOUT if timeout is None else timeout
    try:
        import logging

        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise StageError(f"--workers/--scheduler need Dask: {INSTALL_HINT}") from None
    # a task's arguments are its tiles' data (a few MB): no warning about it on every build
    dask.config.set({"distributed.admin.large-graph-warning-threshold": "1GB"})
    # Dask gives its loggers their own handler at INFO: a local scheduler's start and stop were ~35 lines on
    # stderr of every `twin sweep --workers N`, even with -q. They follow the command's -v/-q like ours.
    logging.getLogger("distributed").setLevel(logging.getLogger().getEffectiveLevel())
    cluster = None
    try:
        if scheduler is not None:
            _check_address(scheduler)
            client = Client(scheduler, timeout=timeout, set_as_default=False)
        else:
            processes = local_processes(workers) if waiting_tasks else workers
            with dask.config.set(WAITING_TASKS_CONFIG if waiting_tasks else COMPUTING_TASKS_CONFIG):  # per worker
                cluster = LocalCluster(n_workers=processes, threads_per_worker=-(-workers // processes),
                                       processes=True, dashboard_address=None, silence_logs=logging.ERROR)
            client = Client(cluster, set_as_default=False)
    except (OSError, TimeoutError) as error:
        if cluster is not None:
            cluster.close()
        where = f"the Dask scheduler at {scheduler}" if scheduler else "a local Dask cluster"
        raise StageError(f"cannot reach {where} within {timeout:g} s ({_reason(error)})") from None
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (OSError, TimeoutError):
            where = f"the Dask scheduler at {scheduler}" if scheduler else "the local Dask cluster"
            raise StageError(f"{where} has no worker (waited {timeout:g} s)") from None
        yield Fanout(client)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def local_processes(slots: int) -> int:
    """Worker processes for ``slots`` tasks that only wait: one per core at most (a process per slot would only
    add processes that compete with the tasks' own for the cores), and at least one."""
    return max(1, min(slots, os.cpu_count() or 1))


def _check_address(address: str) -> None:
    """An address Dask cannot use (an unknown scheme) is refused before a Client is made: a half-made Client
    complains again when the interpreter exits."""
    from distributed.comm import parse_address
    from distributed.comm.registry import get_backend

    try:
        get_backend(parse_address(address)[0])
    except ValueError as error:
        raise InputError(f"--scheduler {address}: {_reason(error)}") from None


def _reason(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


class Fanout:
    """Work handed to a Dask client, results back in order."""

    def __init__(self, client):
        self.client = client
        self._shared: dict[str, object] = {}  # sha256 -> future of the scattered bytes
        self._kept: list = []                 # futures of work started ahead (a released future is cancelled)

    @property
    def workers(self) -> int:
        return max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))

    def map(self, function: Callable, arguments: Iterable[tuple], window: int | None = None,
            recover: Callable[[list[tuple]], list[tuple]] | None = None) -> Iterator:
        """``function(*args)`` for every tuple, on the cluster; results in the order of ``arguments``, at most
        ``window`` tasks in flight (default TASKS_PER_WORKER per worker). The first ``window`` tasks are
        submitted at once, before the first result is asked for: the client can do other work meanwhile.

        ``recover`` is for tasks that read shared data: when the scheduler cancels a task because data it needs
        was lost with a worker (``FutureCancelledError``; scattered data has no task to make it again, and Dask's
        memory manager keeps one replica of a broadcast), it gets the unfinished tasks' arguments and returns
        them with the data placed anew; they are submitted again (at most MAX_RECOVERIES times)."""
        window = window or TASKS_PER_WORKER * self.workers
        pending: deque = deque()  # (future, args)
        arguments = iter(arguments)
        self._submit(function, arguments, pending, window)
        return self._results(function, arguments, pending, window, recover)

    def _submit(self, function: Callable, arguments: Iterator, pending: deque, window: int) -> None:
        while len(pending) < window:
            args = next(arguments, _END)
            if args is _END:
                return
            pending.append((self.client.submit(function, *args, pure=False), args))

    def _results(self, function: Callable, arguments: Iterator, pending: deque, window: int,
                 recover: Callable[[list[tuple]], list[tuple]] | None) -> Iterator:
        from distributed.client import FutureCancelledError

        recoveries = 0
        try:
            while pending:
                future = pending[0][0]
                try:
                    result = future.result()
                except FutureCancelledError:
                    if recover is None or recoveries >= MAX_RECOVERIES:
                        raise
                    recoveries += 1
                    unfinished = [a for _, a in pending]
                    _cancel(pending)
                    pending = deque((self.client.submit(function, *a, pure=False), a) for a in recover(unfinished))
                    continue
                pending.popleft()
                future.release()
                self._submit(function, arguments, pending, window)
                yield result
        finally:
            _cancel(pending)  # the caller stopped early or a task failed: nothing left running

    def everywhere(self, function: Callable, *args) -> None:
        """Start ``function(*args)`` once on every worker there is now, without waiting for it: work a worker's
        later tasks need (loading the map) done while the client still prepares them."""
        for address in self.client.scheduler_info(n_workers=-1).get("workers", {}):
            self._kept.append(self.client.submit(function, *args, workers=[address], allow_other_workers=True,
                                                 pure=False))

    def share(self, data: bytes, again: bool = False) -> tuple[str, object]:
        """(sha256, future) of bytes placed on the cluster once. On every worker there is now (broadcast): data
        scattered to one worker only would be lost with it, and tasks cannot make it again; a worker that joins
        later fetches it from another. ``again``: placed anew (the copy there was lost with a worker)."""
        digest = hashlib.sha256(data).hexdigest()
        if again or digest not in self._shared:
            self._shared[digest] = self.client.scatter(data, hash=False, broadcast=True)
        return digest, self._shared[digest]

    def with_file(self, path: str | Path) -> FileFanout:
        path = Path(path)
        return FileFanout(self, *self.share(path.read_bytes()), path.name, reread=path.read_bytes)

    def with_object(self, value, name: str) -> FileFanout:
        """A FileFanout of ``value`` pickled (``worker_object`` gives it back on a worker, made once there):
        an object the client has already made (a loaded map) reaches the workers without each making it
        again. Its bytes are kept here in case a copy is lost with a worker."""
        import pickle

        data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        return FileFanout(self, *self.share(data), name, reread=lambda: data)


class FileFanout:
    """A Fanout whose every task gets a file's (sha256, bytes, name) before its own arguments; bytes lost with a
    worker are sent again and the unfinished tasks rerun."""

    def __init__(self, fanout: Fanout, digest: str, future, name: str, reread: Callable[[], bytes] | None = None):
        """``reread`` gives the bytes again when a copy is lost (None: a lost copy fails the map)."""
        self.fanout, self.digest, self.future, self.name, self.reread = fanout, digest, future, name, reread

    @property
    def workers(self) -> int:
        return self.fanout.workers

    def map(self, function: Callable, arguments: Iterable[tuple], window: int | None = None) -> Iterator:
        # a generator: tasks not yet submitted take the future of the latest copy
        return self.fanout.map(function, ((self.digest, self.future, self.name, *args) for args in arguments),
                               window, recover=None if self.reread is None else self._share_again)

    def _share_again(self, unfinished: list[tuple]) -> list[tuple]:
        digest, self.future = self.fanout.share(self.reread(), again=True)
        if digest != self.digest:
            raise StageError(f"{self.name} changed while the cluster worked on it")
        return [(args[0], self.future, *args[2:]) for args in unfinished]

    def everywhere(self, function: Callable, *args) -> None:
        self.fanout.everywhere(function, self.digest, self.future, self.name, *args)


MAX_RECOVERIES = 3  # times a map sends its shared data again after losing it with workers
_END = object()


def _cancel(pending: deque) -> None:
    for future, _ in pending:
        future.cancel()


# -- the worker's side --------------------------------------------------------------------------------------

_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = int(os.environ.get("TAVF_WORKER_CACHE", "4"))  # a map and what is derived from it


def worker_cached(key, make: Callable):
    """``make()``, kept in this process for the next task with the same key (a few entries, least recently used
    dropped): a worker loads a map once per build, not once per task."""
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    value = make()
    _CACHE[key] = value
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return value


def worker_map(digest: str, data: bytes, name: str):
    """The OpenDRIVE map of (sha256, bytes) in this worker, loaded once."""
    from tavf_mapkit.opendrive.reader import loads_opendrive

    return worker_cached(("opendrive", digest), lambda: loads_opendrive(data, name))


def worker_object(digest: str, data: bytes, name: str):
    """The object ``Fanout.with_object`` pickled into (sha256, bytes), unpickled once in this worker."""
    import pickle

    return worker_cached(("object", digest), lambda: pickle.loads(data))


def batches_for(count: int, workers: int, at_most: int, per_worker: int = 4) -> int:
    """How many items a task takes so that ``count`` items make at least ``per_worker`` tasks per worker (load
    balance) and a task never takes more than ``at_most`` (its memory)."""
    return max(1, min(at_most, -(-count // max(1, per_worker * workers))))
