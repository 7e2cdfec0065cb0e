"""Whether this kernel keeps a requested time slice (EEVDF custom slices, Linux 6.12+), for tests of twin/sched.py's
users; asked in a process of its own, so the test process's scheduling stays as it was."""

from __future__ import annotations

import functools
import subprocess
import sys


@functools.cache
def kernel_takes_short_slices() -> bool:
    code = "from twin.sched import *; print(request_short_slices() and slice_s() == SHORT_SLICE_S)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return done.stdout.strip() == "True"
