"""The map's lane samples in parts, so a region's export stays within the map's budget of one allocation.

Sampling every lane at once costs ~400 bytes per (lane, sample) pair through the reference frame and the
border offsets; Columbus has 4.25 million pairs at the export's 1 cm, more than ``budget.MAX_POINTS``
allows in one go. The export samples runs of consecutive lane sections of about ``PART_PAIRS`` pairs
instead and keeps from each only what it writes (border and centre points, tangents, a few numbers per
lane). Every number is evaluated per sample, so the parts' results one after the other are the whole
map's, bit for bit.
"""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive.sampling import sample_lanes_at

#: (lane, sample) pairs sampled at once (~200 MB through the sampling)
PART_PAIRS = 500_000


def section_runs(arrays, sample_section: np.ndarray, part_pairs: int = PART_PAIRS) -> list[slice]:
    """Slices of the samples (grouped by section, sections ascending) in runs of whole lane sections: a run
    starts with the first section that starts past a multiple of ``part_pairs`` pairs, so it holds fewer than
    ``part_pairs`` pairs plus its last section."""
    sample_section = np.asarray(sample_section, dtype=np.int64)
    if not len(sample_section):
        return [slice(0, 0)]  # one empty part: a map without samples exports as before, with nothing in it
    if np.any(np.diff(sample_section) < 0):
        raise ValueError("samples must come grouped by lane section in ascending section order")
    first = np.flatnonzero(np.concatenate([[True], sample_section[1:] != sample_section[:-1]]))
    ends = np.append(first[1:], len(sample_section))
    lanes = np.bincount(arrays.lane_section, minlength=len(arrays.section_s0))[sample_section[first]]
    pairs = (ends - first) * lanes
    # a run ends where the running total crosses a multiple of part_pairs
    run = (np.cumsum(pairs) - pairs) // max(int(part_pairs), 1)
    starts = first[np.flatnonzero(np.concatenate([[True], run[1:] != run[:-1]]))]
    return [slice(int(a), int(b)) for a, b in zip(starts, np.append(starts[1:], len(sample_section)))]


def sample_in_parts(odr, sample_section: np.ndarray, sample_s: np.ndarray, part_pairs: int = PART_PAIRS):
    """``sample_lanes_at(odr, sample_section, sample_s)`` run by run of ``section_runs``: one LaneSampling
    per part, in map order."""
    for run in section_runs(odr.arrays, sample_section, part_pairs):
        yield sample_lanes_at(odr, sample_section[run], sample_s[run])
