"""Atomic outputs: a file or a folder is written under a temporary name beside its target (same filesystem) and
renamed into place whole, so a failure, Ctrl-C or SIGTERM never leaves half an output, and an existing output
stays exactly as it was until the new one is complete.

- ``write_bytes_atomic`` / ``write_text_atomic``: a file from bytes or text;
- ``staged_file``: a temporary file name for writers that want a path (osmium), renamed over the target;
- ``StagedFolder`` / ``staged_folder``: a folder (a build, a mesh folder, the collision world, a twin run).

A folder is put in place in one step where the kernel can (renameat2 RENAME_EXCHANGE: the old folder and the
new one trade names), otherwise the old one is renamed aside first; SIGINT and SIGTERM wait until the names are
settled. The previous folder is removed afterwards. While a folder is staged, SIGTERM is raised as ``Terminated``
(a KeyboardInterrupt, in the main thread), so that a killed command cleans up as after Ctrl-C instead of leaving
its staging folder behind. Staging folders are named ``.NAME.staging-XXXX`` beside the target, so a writer that
holds a lock on the target can find and clear what a SIGKILLed one left (``StagedFolder.recover``).
"""

from __future__ import annotations

import ctypes
import errno
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Self

from tavf_mapkit.errors import InputError, StageError

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_ASIDE = "-old"  # suffix of the previous folder while two renames swap folders (no RENAME_EXCHANGE)


# -- files ------------------------------------------------------------------------------------------------------

def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    with staged_file(path) as temporary:
        temporary.write_bytes(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


@contextmanager
def staged_file(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """A new, empty file beside ``path`` (``suffix``: its ending, for writers that choose a format by name), with
    the mode a plain open() would give; renamed over ``path`` when the block ends normally, removed otherwise."""
    path = Path(path)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix,
                                    dir=path.parent if str(path.parent) else ".")
    except FileNotFoundError:
        raise InputError("output folder does not exist", file=str(path)) from None
    except PermissionError:
        raise InputError("output folder is not writable", file=str(path)) from None
    temporary = Path(name)
    try:
        # mkstemp creates 0600; give the file the mode a plain open() would (0666 minus the umask)
        os.fchmod(fd, 0o666 & ~_umask())
        os.close(fd)
        yield temporary
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


# -- folders ----------------------------------------------------------------------------------------------------

class Terminated(KeyboardInterrupt):
    """SIGTERM while a folder is staged, raised like Ctrl-C so the same cleanup runs."""



class StagedFolder:
    """``with StagedFolder(target) as staged: ...write into staged.staging...; staged.commit()``.

    Leaving the block without ``commit()`` (an error, an interrupt) removes the staging folder and leaves the
    target as it was. ``marker``: a target that exists must be an empty folder or hold this file (an earlier
    output of the same kind), so nothing else is ever replaced; ``refusal`` is the one-line error otherwise.
    ``what`` names the folder in errors ("the build folder").
    """

    def __init__(self, target: str | Path, *, marker: str | None = None, refusal: str | None = None,
                 what: str = "the folder") -> None:
        self.target = Path(target).absolute()
        self.marker = marker
        self.refusal = refusal or f"exists and holds no {marker}: refusing to replace it"
        self.what = what
        self.staging: Path | None = None
        self.committed = False
        self._previous_sigterm = None

    def check(self) -> None:
        """Refuse a target that must not be replaced, or that cannot be a folder (a file on its path)."""
        target = self.target
        if target.exists() and not target.is_dir():
            raise InputError("exists and is not a folder", file=str(target))
        if (self.marker is not None and target.is_dir() and any(target.iterdir())
                and not (target / self.marker).is_file()):
            raise InputError(self.refusal, file=str(target))
        for ancestor in target.parents:
            if ancestor.exists():
                if not ancestor.is_dir():
                    raise InputError("is not a folder", file=str(ancestor))
                break

    def open(self) -> Self:
        """Check the target and make the staging folder (and the target's parents)."""
        self.check()
        try:
            self.target.parent.mkdir(parents=True, exist_ok=True)
            self.staging = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.staging-", dir=self.target.parent))
            self.staging.chmod(0o777 & ~_umask())  # mkdtemp makes it private; an output folder is not
        except OSError as error:
            raise InputError(f"cannot write {self.what}: {error.strerror}", file=str(self.target)) from None
        self._catch_sigterm()
        return self

    def commit(self) -> Path:
        """Put the staging folder in place of the target; the previous folder is removed afterwards."""
        assert self.staging is not None and not self.committed
        blocked = {signal.SIGINT, signal.SIGTERM}
        previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
        try:
            if self.target.exists():
                _exchange(self.staging, self.target)
                old = self.staging  # after the exchange the staging name holds the previous folder
            else:
                os.rename(self.staging, self.target)
                old = None
            self.committed = True
        except OSError as error:
            raise StageError(f"cannot move {self.what} into place: {error.strerror}", file=str(self.target)) from None
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)
        self._restore_sigterm()
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.target

    def discard(self) -> None:
        try:
            if not self.committed and self.staging is not None:
                shutil.rmtree(self.staging, ignore_errors=True)
        finally:
            self._restore_sigterm()

    def _catch_sigterm(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return  # only the main thread may set handlers (and only it would receive the exception)

        def terminate(signum, frame):
            raise Terminated(f"signal {signum}")

        self._previous_sigterm = signal.signal(signal.SIGTERM, terminate)

    def _restore_sigterm(self) -> None:
        if self._previous_sigterm is not None:
            signal.signal(signal.SIGTERM, self._previous_sigterm)
            self._previous_sigterm = None

    def recover(self) -> list[str]:
        """Clear what writers killed outright (SIGKILL, out of memory) left beside the target: a previous folder
        they had renamed aside goes back in place, staging folders are removed. Returns what was done, one phrase
        each. Only for a caller that holds a lock on the target: a live writer's staging folder looks the same."""
        done = []
        leftovers = sorted(self.target.parent.glob(f".{self.target.name}.staging-*"))
        for leftover in leftovers:
            # killed between the two renames of _exchange's fallback: the previous folder waits beside the target
            previous = leftover.name.endswith(_ASIDE) and (self.marker is None or (leftover / self.marker).is_file())
            if previous and not self.target.exists():
                os.rename(leftover, self.target)
                done.append(f"put the previous {self.what.removeprefix('the ')} back from {leftover.name}")
        for leftover in leftovers:
            if leftover.exists():
                shutil.rmtree(leftover, ignore_errors=True)
                done.append(f"removed its unfinished staging folder {leftover.name}")
        return done

    def __enter__(self) -> Self:
        return self.open() if self.staging is None else self

    def __exit__(self, *exc_info: object) -> None:
        self.discard()


@contextmanager
def staged_folder(target: str | Path, **options) -> Iterator[Path]:
    """The staging folder of ``StagedFolder(target, **options)``, put in place when the block ends normally."""
    with StagedFolder(target, **options) as staged:
        yield staged.staging
        staged.commit()


def _exchange(new: Path, target: Path) -> None:
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
    aside = new.with_name(new.name + _ASIDE)
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except OSError:
        os.rename(aside, target)
        raise
    os.rename(aside, new)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
