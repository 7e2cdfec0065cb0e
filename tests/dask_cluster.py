"""A real Dask cluster on loopback for tests: ``dask scheduler`` and ``dask worker`` processes (each in its own
process group, on free ports), bounded by timeouts and always stopped."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

START_TIMEOUT = 60.0
DASK = Path(sys.executable).parent / "dask"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class LoopbackCluster:
    def __init__(self, workers: int, scratch: Path):
        pytest.importorskip("distributed")
        self.address = f"tcp://127.0.0.1:{free_port()}"
        self.scratch = scratch
        self.processes: list[subprocess.Popen] = []
        self.count = workers
        self.workers: list[subprocess.Popen] = []

    def start(self) -> None:
        self.scheduler = self._start([str(DASK), "scheduler", "--host", "127.0.0.1", "--port",
                                      self.address.rsplit(":", 1)[1], "--no-dashboard"], "scheduler")
        self.workers = [self.add_worker(k) for k in range(self.count)]
        self.wait_for_workers(self.count)

    def _start(self, command: list[str], name: str) -> subprocess.Popen:
        log = open(self.scratch / f"{name}.log", "wb")  # noqa: SIM115 -- open while the process runs
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                   start_new_session=True, cwd=self.scratch)
        log.close()
        self.processes.append(process)
        return process

    def add_worker(self, number: int) -> subprocess.Popen:
        # its own directory: workers share no files with the client or each other
        directory = self.scratch / f"worker-{number}"
        directory.mkdir(exist_ok=True)
        return self._start([str(DASK), "worker", self.address, "--nthreads", "1", "--nworkers", "1",
                            "--host", "127.0.0.1", "--no-dashboard", "--local-directory", str(directory),
                            "--death-timeout", "60"], f"worker-{number}")

    def client(self):
        from distributed import Client

        return Client(self.address, timeout=START_TIMEOUT, set_as_default=False)

    def wait_for_workers(self, count: int) -> None:
        with self.client() as client:
            client.wait_for_workers(count, timeout=START_TIMEOUT)

    def kill(self, process: subprocess.Popen) -> None:
        """SIGKILL a process group (a worker and its nanny: a machine lost, not a clean shutdown)."""
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait(timeout=30)

    def close(self) -> None:
        for process in reversed(self.processes):
            self.kill(process)


@contextmanager
def loopback_cluster(scratch: Path, workers: int = 2):
    scratch.mkdir(parents=True, exist_ok=True)
    cluster = LoopbackCluster(workers, scratch)
    try:
        cluster.start()
        yield cluster
    finally:
        cluster.close()


def wait_until(condition, timeout: float, step: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(step)
    return False
