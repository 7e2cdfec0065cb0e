"""Atomic build folders: build in a staging folder next to the target, then swap it into place
(``fileutil.StagedFolder``: one step where the kernel can, the old build removed afterwards). On any failure --
a stage error, KeyboardInterrupt, SIGTERM -- the staging folder is removed and the existing build is left
exactly as it was. A lock file keeps two builds from writing the same target at once.

A build killed outright (SIGKILL, the kernel's out-of-memory killer, power loss) runs no cleanup: it leaves
its staging folder, and its record in the lock file. The lock itself is an flock, which the kernel releases
when the holder dies, so a dead build never blocks the next one; the record (pid, host, start time) written
into the lock file while it is held, and cleared on a normal exit, is how the next build knows that the
previous one was killed. That build removes the leftovers and says so in one line; a live build still holds
the flock, so a concurrent build is refused, naming the holder.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Self

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.fileutil import StagedFolder
from tavf_mapkit.pipeline.manifest import MANIFEST_NAME


class BuildFolder:
    """``with BuildFolder(target) as folder: ...write into folder.staging...; folder.commit()``."""

    def __init__(self, target: str | Path, notify: Callable[[str], None] | None = None) -> None:
        self._staged = StagedFolder(target, marker=MANIFEST_NAME, what="the build folder",
                                    # the swap would delete it: refuse to treat somebody's folder as an old build
                                    refusal="exists and is not a mapkit build folder (no manifest.json); "
                                            "choose another -o or remove it")
        self.target = self._staged.target
        self.parent = self.target.parent
        self._notify = notify or (lambda line: None)  # one line for the user (recovery from a killed build)
        self._lock_handle = None

    @property
    def staging(self) -> Path | None:
        return self._staged.staging

    @property
    def committed(self) -> bool:
        return self._staged.committed

    @property
    def existing(self) -> Path | None:
        """The current build at the target, if there is one."""
        return self.target if (self.target / MANIFEST_NAME).is_file() else None

    def __enter__(self) -> Self:
        self._staged.check()
        try:
            self.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise InputError(f"cannot create the build folder's parent: {error.strerror}",
                             file=str(self.parent)) from None
        killed = self._lock()
        try:
            self._recover(killed)
            self._staged.open()
        except OSError as error:
            self._unlock()
            raise InputError(f"cannot write the build folder: {error.strerror}",
                             file=str(self.parent)) from None
        except BaseException:
            self._unlock()
            raise
        return self  # SIGTERM is now raised like Ctrl-C (StagedFolder), so __exit__ cleans up

    def __exit__(self, exc_type, exc, traceback) -> None:
        try:
            self._staged.discard()
        finally:
            self._unlock()

    def commit(self) -> None:
        """Put the staging folder in place of the target; the old build is removed afterwards."""
        self._staged.commit()

    # ------------------------------------------------------------------------------------------- private

    @property
    def lock_path(self) -> Path:
        return self.parent / f".{self.target.name}.lock"

    def _lock(self) -> dict | None:
        """Take the lock and write our record into it; return the record a killed build left, if any."""
        try:
            self._lock_handle = open(self.lock_path, "a+")  # noqa: SIM115 -- held open until _unlock
        except OSError as error:
            raise InputError(f"cannot write the build folder: {error.strerror}",
                             file=str(self.parent)) from None
        try:
            fcntl.flock(self._lock_handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_record(self._lock_handle)
            self._lock_handle.close()
            self._lock_handle = None
            raise StageError(f"another mapkit build{_describe(holder)} is writing this build folder",
                             file=str(self.target)) from None
        # we hold the flock, so whoever wrote a record here is dead: a normal exit clears it
        killed = _read_record(self._lock_handle)
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        try:
            self._lock_handle.truncate(0)
            self._lock_handle.write(json.dumps(record) + "\n")
            self._lock_handle.flush()
        except OSError as error:
            self._unlock()
            raise InputError(f"cannot write the build folder: {error.strerror}",
                             file=str(self.parent)) from None
        return killed

    def _unlock(self) -> None:
        if self._lock_handle is not None:
            try:
                self._lock_handle.truncate(0)  # no record: this build ended, it was not killed
            except OSError:
                pass
            fcntl.flock(self._lock_handle, fcntl.LOCK_UN)
            self._lock_handle.close()
            self._lock_handle = None
            # the lock file stays: unlinking it would let a waiting build lock a file nobody else sees

    def _recover(self, killed: dict | None) -> None:
        """Remove the staging folders of killed builds (we hold the lock, so none is live) and say so."""
        done = self._staged.recover()
        if killed is None and not done:
            return
        self._notify(f"note: recovered from an earlier build of {self.target} that was killed"
                     f"{_describe(killed)}: {'; '.join(done) or 'nothing was left to clean up'}")


def _read_record(handle) -> dict | None:
    """The record in a lock file (None if empty or unreadable: a build of an older mapkit wrote none)."""
    try:
        handle.seek(0)
        record = json.loads(handle.read() or "null")
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _describe(record: dict | None) -> str:
    if not record:
        return ""
    return f" (pid {record.get('pid')} on {record.get('host')}, started {record.get('started')})"
