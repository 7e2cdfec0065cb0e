"""The exact numpy helpers of the tiled mesher (also the twin's bend measure): answers against plain
definitions, for any input order and ties."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tavf_mapkit.mesh.exact import search_pairs

pairs = st.lists(st.tuples(st.integers(-3, 6), st.sampled_from([-2.5, -1.0, -0.0, 0.0, 0.5, 1.0, 3.0, 1e-300])),
                 max_size=60)


def _count_before(samples, query, side):
    """Samples before a query pair in lexicographic order (on ties: after them for "right")."""
    if side == "right":
        return sum(1 for s in samples if s <= query)
    return sum(1 for s in samples if s < query)


@settings(max_examples=300, deadline=None)
@given(samples=pairs, queries=pairs, side=st.sampled_from(["left", "right"]), sort_queries=st.booleans())
def test_search_pairs_is_searchsorted_on_pairs(samples, queries, side, sort_queries):
    """Sorted or not, queries get the lexicographic insertion point of their (major, minor) pair (-0.0
    equals 0.0, as in a float comparison)."""
    samples = sorted(samples)
    if sort_queries:
        queries = sorted(queries)
    major = np.array([s[0] for s in samples], dtype=np.int64)
    minor = np.array([s[1] for s in samples], dtype=float)
    q_major = np.array([q[0] for q in queries], dtype=np.int64)
    q_minor = np.array([q[1] for q in queries], dtype=float)
    found = search_pairs(major, minor, q_major, q_minor, side)
    assert found.tolist() == [_count_before(samples, q, side) for q in queries]
