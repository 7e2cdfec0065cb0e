"""Helper processes of the twin (the UDM query client, the traffic publisher): one worker abstraction for both.

A fresh interpreter, not a fork, because the parent runs pybullet, libsumo and threads that a forked child must
not inherit, and multiprocessing's spawn would re-import the caller's __main__ script. A socket pair carries
pickled messages: the parent sends tuples whose first item is their kind; the child answers with
(kind, payload, stats), ``stats`` being its counters when it sent the message.

Parent side, ``ChildProcess(module, what, settings[, pass_fds])``: starts ``python -m MODULE FD`` (inheriting
``pass_fds`` too), hands it ``settings`` and
waits until it is ready, or raises ``RuntimeError("WHAT did not start: why")`` (one line). ``ask`` sends a
request and reads until its answer, ``close`` asks the child to finish and reads until it says "closed"; both
have a deadline, and a child that does not end in time is killed: nothing here waits for ever.

Child side, ``serve(start)`` is the module's ``__main__``: it reads the settings and calls
``start(settings, parent)``, which builds its worker, calls ``parent.ready()`` and loops on
``parent.waiting(...)`` until it is asked to close (or the parent is gone); "closed" is sent when it returns.
An exception before ``ready()`` goes back to the parent as the reason the child did not start.
"""

from __future__ import annotations

import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

START_TIMEOUT_S = 30.0

OnMessage = Callable[[str, Any], None]


class ChildProcess:
    """The parent's end of a helper process. ``lock`` guards the pipe and ``closed`` (callers guard their own
    state with it too); ``stats`` are the child's counters as of its last message."""

    def __init__(self, module: str, what: str, settings: Any, start_timeout_s: float = START_TIMEOUT_S,
                 pass_fds: tuple[int, ...] = ()) -> None:
        self.what = what
        self.lock = threading.Lock()
        self.closed = False
        self.stats: Any = None
        self.process, self._conn = _spawn(module, pass_fds)
        try:
            self._conn.send(settings)
            answered, reason = self.wait_for("ready", start_timeout_s, errors=("error",))
            if not answered:
                raise RuntimeError(reason or self._silence(start_timeout_s))
        except (OSError, EOFError, RuntimeError) as error:
            self.closed = True
            self._conn.close()
            self.process.kill()
            self.process.wait()
            raise RuntimeError(f"{what} did not start: {error or type(error).__name__}") from None

    def send(self, *message: Any) -> None:
        """Hand a message to the child; OSError or ValueError when it is gone."""
        self._conn.send(message)

    def has_room(self) -> bool:
        """Whether a message of up to ~100 kB goes out without waiting: Linux reports a Unix socket writable
        while at most a quarter of its send buffer (~200 kB) is in use. False when the child is gone."""
        try:
            return bool(select.select((), (self._conn,), (), 0)[1])
        except (OSError, ValueError):
            return False

    def wait_for(self, wanted: str, timeout_s: float, on_message: OnMessage | None = None,
                 errors: tuple[str, ...] = ()) -> tuple[bool, Any]:
        """Read messages until one of kind ``wanted``: (True, its payload). Other kinds go to ``on_message``;
        a kind in ``errors`` ends the wait with (False, its payload); (False, None) when ``timeout_s`` passes or
        the child is gone."""
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self._conn.poll(remaining):
                    return False, None
                kind, payload = self._receive()
                if kind == wanted:
                    return True, payload
                if kind in errors:
                    return False, payload
                if on_message is not None:
                    on_message(kind, payload)
        except (OSError, EOFError, ValueError):
            return False, None

    def read_waiting(self, on_message: OnMessage) -> None:
        """Every message that is already there, to ``on_message``; never blocks, never raises."""
        try:
            while self._conn.poll(0):
                on_message(*self._receive())
        except (OSError, EOFError, ValueError):
            pass

    def ask(self, request: str, timeout_s: float, answer: str, on_message: OnMessage | None = None) -> bool:
        """Send (request, timeout_s) and wait for ``answer`` (the child's own deadline first, then one second
        more); its payload as a bool, False on timeout or when the child is gone or closed. Hold ``lock``."""
        if self.closed:
            return False
        try:
            self.send(request, timeout_s)
        except (OSError, ValueError):
            return False
        answered, payload = self.wait_for(answer, timeout_s + 1.0, on_message)
        return answered and bool(payload)

    def close(self, timeout_s: float = 5.0, on_message: OnMessage | None = None,
              before: Callable[[], Any] | None = None) -> None:
        """Ask the child to finish within ``timeout_s`` and read what it still sends (to ``on_message``) until it
        says "closed"; then wait for it to end, killing it if it does not in time. ``before`` runs first, under
        ``lock`` (e.g. to send what is held back). Closing twice does nothing."""
        with self.lock:
            if self.closed:
                return
            self.closed = True
            try:
                if before is not None:
                    before()
                self.send("close", timeout_s)
                self.wait_for("closed", timeout_s + 1.0, on_message)
            except (OSError, ValueError):
                pass
            self._conn.close()
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()

    def _receive(self) -> tuple[str, Any]:
        kind, payload, stats = self._conn.recv()
        self.stats = stats
        return kind, payload

    def _silence(self, timeout_s: float) -> str:
        code = self.process.poll()
        return f"it ended with exit code {code}" if code is not None else f"no answer in {timeout_s:g} s"


class Parent:
    """The child's end: messages from the parent, answers to it. ``stats`` is called for every answer."""

    def __init__(self, conn: Connection) -> None:
        self._conn = conn
        self.stats: Callable[[], Any] = lambda: None
        self.is_ready = False
        self.gone = False  # the parent closed the pipe (or died)

    def ready(self) -> None:
        self.send("ready", None)
        self.is_ready = True

    def send(self, kind: str, payload: Any) -> None:
        self._conn.send((kind, payload, self.stats()))

    def waiting(self, block: bool) -> list[tuple]:
        """The parent's messages: with ``block``, wait for one first; then every one already there. Sets
        ``gone`` (and returns what came before) when the parent is gone."""
        messages = []
        try:
            if block:
                messages.append(self._conn.recv())
            while self._conn.poll(0):
                messages.append(self._conn.recv())
        except (EOFError, OSError):
            self.gone = True
        return messages


def serve(start: Callable[[Any, Parent], None], what: str) -> None:
    """Run a child module's worker: ``python -m MODULE FD``, FD being the child's end of the socket pair.
    ``what`` names the child in the one line it writes should the worker fail after it was ready."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it closes us
    conn = Connection(int(sys.argv[1]))
    parent = Parent(conn)
    try:
        settings = conn.recv()
        try:
            start(settings, parent)
        except Exception as error:  # noqa: BLE001 -- reported in one line; the parent sees the pipe close
            line = f"{type(error).__name__}: {error}"
            if not parent.is_ready:
                parent.send("error", line)  # the parent raises it as the reason the child did not start
                return
            if isinstance(error, (EOFError, BrokenPipeError, ConnectionResetError)):
                return  # the parent is gone: nobody to tell
            print(f"error: {what} failed: {line}", file=sys.stderr)
            sys.exit(1)
        parent.send("closed", None)
    except (EOFError, OSError, ValueError):
        pass  # the parent is gone: nobody to tell
    finally:
        conn.close()


def _spawn(module: str, pass_fds: tuple[int, ...] = ()) -> tuple[subprocess.Popen, Connection]:
    """Start ``python -m MODULE FD``; return the process and the parent's end of the socket pair. ``pass_fds``:
    more descriptors the child inherits under the same numbers (e.g. a listening socket bound by the parent)."""
    parent_socket, child_socket = socket.socketpair()
    try:
        process = subprocess.Popen([sys.executable, "-m", module, str(child_socket.fileno())],
                                   pass_fds=[child_socket.fileno(), *pass_fds], stdin=subprocess.DEVNULL)
    except BaseException:
        parent_socket.close()
        raise
    finally:
        child_socket.close()
    return process, Connection(parent_socket.detach())
