"""Ask Linux to schedule a latency-sensitive thread in short time slices (EEVDF's custom slice, kernel 6.12+).

A UDM request wakes two processes that mostly sleep: the server when the request arrives and the twin's
client when the answer does. On a machine whose cores are busy (a fleet of twins, other jobs) a woken task
waits until the tasks whose slices end earlier have run -- a default slice is 1.4 ms on this 2-core machine. With a
short slice of its own its deadline comes first, so the kernel runs it at once. It gets no more CPU than
before (the share still follows nice and weight); it only gets it in shorter, earlier pieces, which is what a
thread that wakes, answers in well under a millisecond and sleeps again needs.

``sched_setattr`` with SCHED_OTHER and ``sched_runtime`` as the requested slice needs no privilege. Where the
kernel (older than 6.12: the field is ignored) or the platform (not Linux, an architecture whose system call
number is not known here) cannot take it, nothing changes and ``request_short_slices`` says False.
"""

from __future__ import annotations

import ctypes
import os
import platform

SHORT_SLICE_S = 0.0005  # about one request's work; the kernel accepts 0.1 ms .. 100 ms

_SCHED_OTHER = 0
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
_SYS_SCHED_GETATTR = {"x86_64": 315, "aarch64": 275}


class _SchedAttr(ctypes.Structure):
    """struct sched_attr, version 0 (48 bytes), as in include/uapi/linux/sched/types.h."""

    _fields_ = [("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32), ("sched_flags", ctypes.c_uint64),
                ("sched_nice", ctypes.c_int32), ("sched_priority", ctypes.c_uint32),
                ("sched_runtime", ctypes.c_uint64), ("sched_deadline", ctypes.c_uint64),
                ("sched_period", ctypes.c_uint64)]


def _syscall(table: dict[str, int]):
    number = table.get(platform.machine())
    if number is None or platform.system() != "Linux":
        return None, None
    libc = ctypes.CDLL(None, use_errno=True)
    return libc.syscall, number


def request_short_slices(slice_s: float = SHORT_SLICE_S) -> bool:
    """Ask for ``slice_s`` slices for the calling thread, keeping its policy (SCHED_OTHER) and nice; True when
    the kernel took the request."""
    syscall, number = _syscall(_SYS_SCHED_SETATTR)
    if syscall is None:
        return False
    try:
        attr = _SchedAttr(size=ctypes.sizeof(_SchedAttr), sched_policy=_SCHED_OTHER,
                          sched_nice=os.getpriority(os.PRIO_PROCESS, 0),
                          sched_runtime=int(slice_s * 1e9))
        return syscall(ctypes.c_long(number), 0, ctypes.byref(attr), 0) == 0
    except (OSError, AttributeError, ValueError):
        return False


def slice_s(tid: int = 0) -> float | None:
    """The slice of thread ``tid`` (0: the calling one; a process's id is its main thread's) from sched_getattr;
    None where it cannot be read."""
    syscall, number = _syscall(_SYS_SCHED_GETATTR)
    if syscall is None:
        return None
    try:
        attr = _SchedAttr()
        if syscall(ctypes.c_long(number), tid, ctypes.byref(attr), ctypes.sizeof(_SchedAttr), 0) != 0:
            return None
        return attr.sched_runtime / 1e9
    except (OSError, AttributeError, ValueError):
        return None
