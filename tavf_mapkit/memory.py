"""Hand freed memory back to the operating system, and keep the garbage collector off a loaded map.

lxml's document trees and numpy's large arrays live on the C heap, Python's small objects in pymalloc's own
arenas: memory a big tree or a stage freed is not reused by the map objects loaded next, and glibc keeps it
resident. A peak is then the sum of what was freed and what comes next; ``return_freed_memory`` between the
two makes it the larger of them (glibc ``malloc_trim``; elsewhere only a garbage collection).
"""

from __future__ import annotations

import ctypes
import gc
from collections.abc import Iterator
from contextlib import contextmanager


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


@contextmanager
def collector_paused() -> Iterator[None]:
    """No cyclic garbage collection while a map is made (reader, snapshot): millions of new objects and next to
    no cycles, so each collection would only walk the growing map again (region-32: 565 collections, 289
    objects freed, ~6 % of the load). The collector is enabled again after, if it was."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if collecting:
            gc.enable()


@contextmanager
def frozen_heap() -> Iterator[None]:
    """Exempt every object alive now (a loaded map: millions of them) from the collector's scans while the block
    runs (``gc.freeze``), given back after it: a region's rules and page allocate much, and each full collection
    would walk the whole map again (seconds each on a region), though none of it can be garbage meanwhile."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
