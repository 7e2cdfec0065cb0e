"""Helper processes of the twin (the UDM query client, the traffic publisher): a fresh interpreter, not a fork,
because the parent runs pybullet, libsumo and threads that a forked child must not inherit, and
multiprocessing's spawn would re-import the caller's __main__ script. A socket pair carries pickled messages."""

from __future__ import annotations

import socket
import subprocess
import sys
from multiprocessing.connection import Connection


def spawn_child(module: str, *arguments: str) -> tuple[subprocess.Popen, Connection]:
    """Start ``python -m MODULE FD ARGUMENTS...``, FD being the child's end of a socket pair; return the
    process and the parent's end."""
    parent_socket, child_socket = socket.socketpair()
    try:
        process = subprocess.Popen([sys.executable, "-m", module, str(child_socket.fileno()), *arguments],
                                   pass_fds=[child_socket.fileno()], stdin=subprocess.DEVNULL)
    except BaseException:
        parent_socket.close()
        raise
    finally:
        child_socket.close()
    return process, Connection(parent_socket.detach())


def stop_child(process: subprocess.Popen, timeout_s: float) -> None:
    """Wait for a child that was asked to close; kill it if it does not end in time."""
    try:
        process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
