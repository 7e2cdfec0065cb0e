"""RecordTable.evaluate finds each (group, s)'s record by a binary search inside its group: the record a
lexicographic search of (group, s0) keys finds, for exact starts, non-finite s and groups without records."""

from __future__ import annotations

import numpy as np

from tavf_mapkit.opendrive import load_opendrive
from tavf_mapkit.opendrive.arrays import RecordTable
from tavf_mapkit.opendrive.sampling import lane_pairs
from tests.conftest import shared_path


def _by_keys(table: RecordTable, group, s, derivative=False, from_left=None):
    """The search the table made before: complex keys group + i*s0 (numpy orders them lexicographically)."""
    if not len(table.s0):
        return np.zeros(len(s))
    keys = np.empty(len(table.s0), dtype=complex)
    keys.real, keys.imag = table.group, table.s0
    key = group + 1j * s
    index = np.searchsorted(keys, key, side="right") - 1
    if from_left is not None:
        before = np.searchsorted(keys, key, side="left") - 1
        same = (before >= 0) & (table.group[np.maximum(before, 0)] == group)
        index = np.where(from_left & same, before, index)
    if table.extend_first:
        first = np.searchsorted(table.group, group, side="left")
        index = np.where((index < first) & (first < len(table.group)), first, index)
    i = np.clip(index, 0, len(table.s0) - 1)
    valid = (index >= 0) & (table.group[i] == group)
    ds = s - table.s0[i]
    a, b, c, d = table.coefficients[i].T
    value = b + ds * (2.0 * c + 3.0 * d * ds) if derivative else a + ds * (b + ds * (c + ds * d))
    return np.where(valid, value, 0.0)


def test_evaluate_finds_the_records_a_key_search_finds():
    rng = np.random.default_rng(11)
    for trial in range(300):
        groups = int(rng.integers(1, 12))
        counts = rng.integers(0, 5, groups)
        group = np.repeat(np.arange(groups), counts)
        s0 = np.concatenate([np.sort(rng.choice(np.arange(0.0, 20.0, 0.5), c, replace=False)) for c in counts])
        table = RecordTable(group, s0, rng.normal(size=(len(s0), 4)), 50.0, bool(trial % 2))
        n = 200
        q_group = rng.integers(-1, groups + 2, n)
        q_s = np.where(rng.random(n) < 0.3, rng.choice(np.r_[s0, 0.0], n), rng.uniform(-3, 25, n))
        q_s[rng.random(n) < 0.05] = np.inf
        q_s[rng.random(n) < 0.05] = -np.inf
        q_s[rng.random(n) < 0.05] = np.nan
        left = rng.random(n) < 0.5
        with np.errstate(invalid="ignore"):
            for options in ({}, {"derivative": True}, {"from_left": left}):
                assert np.array_equal(table.evaluate(q_group, q_s, **options),
                                      _by_keys(table, q_group, q_s, **options), equal_nan=True), (trial, options)
            value, slope = table.evaluate_with_derivative(q_group, q_s)
            assert np.array_equal(value, _by_keys(table, q_group, q_s), equal_nan=True)
            assert np.array_equal(slope, _by_keys(table, q_group, q_s, derivative=True), equal_nan=True)


def test_lane_pairs_of_some_sections_are_the_whole_maps_pairs_of_them():
    """Pairs of a few sections' samples: the (lane, sample) pairs every section's samples give, for those."""
    odr = load_opendrive(shared_path("xodr", "esmini", "multi_intersections.xodr"))
    arrays = odr.arrays
    sections = np.arange(len(arrays.section_s0))
    every = np.repeat(sections, 2)
    all_lane, all_sample, _ = lane_pairs(arrays, every)
    rng = np.random.default_rng(2)
    for _ in range(20):
        some = np.sort(rng.choice(sections, int(rng.integers(1, len(sections))), replace=False))
        lane, sample, inner = lane_pairs(arrays, np.repeat(some, 2))
        mine = np.isin(arrays.lane_section[all_lane], some)
        assert np.array_equal(lane, all_lane[mine])
        # samples renumbered: the k-th sampled section's samples are 2k and 2k + 1
        position = np.searchsorted(some, arrays.lane_section[lane])
        assert np.array_equal(sample, 2 * position + (all_sample[mine] % 2))
        rank = arrays.lane_rank[lane]
        inner_ok = inner[rank > 0]
        assert np.array_equal(lane[inner_ok], lane[rank > 0] - 1)
        assert np.array_equal(sample[inner_ok], sample[rank > 0])
