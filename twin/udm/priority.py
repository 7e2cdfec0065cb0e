"""Scheduling policies of the UDM request path: the UDM server's event loop and a twin's UDM client process.

On a machine whose cores are all busy (other jobs, a fleet of twins), a UDM request's latency is mostly time
spent waiting for a core: the server and the client each use about 1 ms of CPU per request, but wait behind
whatever runs when the answer or the request arrives. Two policies, for the two ends:

- ``normal_policy()``: leave SCHED_BATCH (``twin sweep`` starts its drives under it, so their simulations never
  preempt anything on waking); the client process wakes for every answer and must not queue behind them.
- ``realtime_policy(what)``: SCHED_FIFO at ``REALTIME_PRIORITY``, so a woken server or client preempts every
  normal task at once (``twin udm serve --realtime``, ``twin drive/sweep --udm-realtime``; docs/distributed.md,
  "Session 12: the UDM path at real-time priority").

Why FIFO is safe here: these threads only wait on sockets and use ~1 ms per request (40 requests/s with 20
twins: a few % of a core), so they never hold a core for long; and should one spin, Linux's RT throttling
(/proc/sys/kernel/sched_rt_runtime_us, 950000 of every 1000000 us by default) leaves 5 % of each core to the
normal tasks anyway. The simulations never get it: they are the load the requests must pass.
"""

from __future__ import annotations

import os
import sys

REALTIME_PRIORITY = 10  # low among the 1-99 FIFO priorities: above every normal task, below the kernel's own


def realtime_policy(what: str) -> str | None:
    """Put the calling thread under SCHED_FIFO at ``REALTIME_PRIORITY``; threads it starts later inherit it.

    Returns None on success, else one line saying why ``what`` stays at its present policy (not Linux, or not
    permitted). Callers warn with it once and go on: a drive never fails for its priority."""
    if not sys.platform.startswith("linux") or not hasattr(os, "SCHED_FIFO"):
        return f"{what} stays at normal priority: real-time scheduling (SCHED_FIFO) is only used on Linux"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except PermissionError:
        return (f"{what} stays at normal priority: SCHED_FIFO is not permitted (needs root, CAP_SYS_NICE or an "
                f"rtprio limit of at least {REALTIME_PRIORITY}, e.g. `ulimit -r {REALTIME_PRIORITY}`)")
    except OSError as error:  # e.g. a cgroup without real-time budget (cpu.rt_runtime_us 0)
        return f"{what} stays at normal priority: SCHED_FIFO refused: {error.strerror or error}"
    return None


def normal_policy() -> None:
    """Leave SCHED_BATCH if the drive was started under it (``twin sweep`` does, twin.sweep.runs.batch_policy):
    the simulation may wait for a core, the UDM request must not. A batch thread that wakes never preempts the
    running one, it waits for that one's slice to end -- and the UDM client process wakes for every answer."""
    try:
        if os.sched_getscheduler(0) == os.SCHED_BATCH:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux, or not allowed: keep the inherited policy
        pass


def policy_name(pid: int = 0) -> str | None:
    """The scheduling policy of a process's main thread (0: the calling thread) as ``fifo``, ``other``,
    ``batch``, ...; None when it cannot be read (not Linux, the process is gone)."""
    try:
        policy = os.sched_getscheduler(pid)
    except (AttributeError, OSError):
        return None
    names = {getattr(os, name): name.removeprefix("SCHED_").lower()
             for name in ("SCHED_OTHER", "SCHED_BATCH", "SCHED_IDLE", "SCHED_FIFO", "SCHED_RR") if hasattr(os, name)}
    return names.get(policy, str(policy))
