"""Hand freed memory back to the operating system.

lxml's document trees and numpy's large arrays live on the C heap, Python's small objects in pymalloc's own
arenas: memory a big tree or a stage freed is not reused by the map objects loaded next, and glibc keeps it
resident. A peak is then the sum of what was freed and what comes next; ``return_freed_memory`` between the
two makes it the larger of them (glibc ``malloc_trim``; elsewhere only a garbage collection).
"""

from __future__ import annotations

import ctypes
import gc


def return_freed_memory() -> None:
    gc.collect()
    trim_heap()


def trim_heap() -> None:
    """Only the glibc ``malloc_trim``, no garbage collection (which walks every object: seconds on a city's map):
    for a loop that frees large arrays as it fills new ones, so the freed and the new are never resident together."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
