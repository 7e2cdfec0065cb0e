"""Atomic build folders: build in a staging folder next to the target, then swap it into place.

The staging folder is a sibling of the target (same filesystem, so the final rename is atomic). On success
the new folder replaces the old one in one step (renameat2 RENAME_EXCHANGE where the kernel has it,
otherwise two renames with signals blocked in between) and the old one is removed. On any failure --
a stage error, KeyboardInterrupt, SIGTERM -- the staging folder is removed and the existing build is
left exactly as it was. A lock file keeps two builds from writing the same target at once.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import shutil
import signal
import tempfile
import threading
from pathlib import Path
from typing import Self

from tavf_mapkit.errors import InputError, StageError
from tavf_mapkit.pipeline.manifest import MANIFEST_NAME

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


class BuildInterrupted(KeyboardInterrupt):
    """SIGTERM during a build, raised like Ctrl-C so the same cleanup runs."""


class BuildFolder:
    """``with BuildFolder(target) as folder: ...write into folder.staging...; folder.commit()``."""

    def __init__(self, target: str | Path) -> None:
        self.target = Path(target).absolute()
        self.parent = self.target.parent
        self.staging: Path | None = None
        self.committed = False
        self._lock_handle = None
        self._previous_sigterm = None

    @property
    def existing(self) -> Path | None:
        """The current build at the target, if there is one."""
        return self.target if (self.target / MANIFEST_NAME).is_file() else None

    def __enter__(self) -> Self:
        self._check_target()
        try:
            self.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise InputError(f"cannot create the build folder's parent: {error.strerror}",
                             file=str(self.parent)) from None
        self._lock()
        try:
            self._remove_leftovers()
            self.staging = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.staging-", dir=self.parent))
            self.staging.chmod(0o777 & ~_umask())  # mkdtemp makes it private; a build folder is not
        except OSError as error:
            self._unlock()
            raise InputError(f"cannot write the build folder: {error.strerror}",
                             file=str(self.parent)) from None
        self._catch_sigterm()
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        try:
            if not self.committed and self.staging is not None:
                shutil.rmtree(self.staging, ignore_errors=True)
        finally:
            self._restore_sigterm()
            self._unlock()

    def commit(self) -> None:
        """Put the staging folder in place of the target; the old build is removed afterwards."""
        assert self.staging is not None
        blocked = {signal.SIGINT, signal.SIGTERM}
        previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
        try:
            if self.target.exists():
                _swap(self.staging, self.target)
                old = self.staging  # after the swap the staging name holds the previous build
            else:
                os.rename(self.staging, self.target)
                old = None
            self.committed = True
        except OSError as error:
            raise StageError(f"cannot move the new build into place: {error.strerror}",
                             file=str(self.target)) from None
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    # ------------------------------------------------------------------------------------------- private

    def _check_target(self) -> None:
        target = self.target
        if target.exists() and not target.is_dir():
            raise InputError("exists and is not a folder", file=str(target))
        if target.is_dir() and any(target.iterdir()) and not (target / MANIFEST_NAME).is_file():
            # the swap would delete it: refuse to treat somebody's folder as an old build
            raise InputError("exists and is not a mapkit build folder (no manifest.json); "
                             "choose another -o or remove it", file=str(target))
        for ancestor in [target.parent, *target.parent.parents]:
            if ancestor.exists():
                if not ancestor.is_dir():
                    raise InputError("is not a folder", file=str(ancestor))
                break

    def _lock(self) -> None:
        lock_path = self.parent / f".{self.target.name}.lock"
        try:
            self._lock_handle = open(lock_path, "a+")  # noqa: SIM115 -- held open until _unlock
        except OSError as error:
            raise InputError(f"cannot write the build folder: {error.strerror}",
                             file=str(self.parent)) from None
        try:
            fcntl.flock(self._lock_handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock_handle.close()
            self._lock_handle = None
            raise StageError("another mapkit build is writing this build folder",
                             file=str(self.target)) from None

    def _unlock(self) -> None:
        if self._lock_handle is not None:
            fcntl.flock(self._lock_handle, fcntl.LOCK_UN)
            self._lock_handle.close()
            self._lock_handle = None
            # the lock file stays: unlinking it would let a waiting build lock a file nobody else sees

    def _remove_leftovers(self) -> None:
        """Staging folders of killed builds (SIGKILL, power loss); we hold the lock, so none is live."""
        for leftover in self.parent.glob(f".{self.target.name}.staging-*"):
            shutil.rmtree(leftover, ignore_errors=True)

    def _catch_sigterm(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def interrupt(signum, frame):
            raise BuildInterrupted(f"signal {signum}")

        self._previous_sigterm = signal.signal(signal.SIGTERM, interrupt)

    def _restore_sigterm(self) -> None:
        if self._previous_sigterm is not None:
            signal.signal(signal.SIGTERM, self._previous_sigterm)
            self._previous_sigterm = None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _swap(new: Path, target: Path) -> None:
    """Exchange two folders atomically if the kernel can; otherwise rename the old one aside first."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        renameat2 = None
    if renameat2 is not None:
        result = renameat2(_AT_FDCWD, os.fsencode(new), _AT_FDCWD, os.fsencode(target), _RENAME_EXCHANGE)
        if result == 0:
            return
        code = ctypes.get_errno()
        if code not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
            raise OSError(code, os.strerror(code), str(target))
    aside = new.with_name(new.name + "-old")
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except OSError:
        os.rename(aside, target)
        raise
    os.rename(aside, new)
