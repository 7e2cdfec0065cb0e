"""Points into OSM nodes: one node where the map's links join lane ends, and one where points of a lane section
coincide.

Lanelet2 finds a lanelet's successor by node identity (the end points of its bounds are the start points of
the next one's), and neighbours by way identity. So the corners of lane ends that the map links are made one
node (``joins``: they lie within micrometres of each other on a repaired build), and otherwise points closer
than ``radius`` become one node only within a group (the exporter's groups are lane sections): position alone
never joins a lane end to another section -- else two lanes whose ends merely touch (Columbus: the two roads
leaving a motorway split overlap where they start) would be successors in Lanelet2 that our lane graph does not
have. Nodes without a lane end (``shared`` points only: the middle of the shared centre line of the two roads
of a two-way street) are then merged across groups too: such a node makes no successor. A node sits at the mean
of its points.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: points closer than this are one node (m)
NODE_RADIUS = 2e-3
#: group of a point that belongs to no lane section (signal geometry): it takes the nearest node
FREE = -1
# a node's key for merging across nodes: its group, or one of these
_SHARED, _MIXED = -2, -3


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    if not len(pairs):
        return np.arange(n)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _means(points: np.ndarray, label: np.ndarray, n: int) -> np.ndarray:
    counts = np.bincount(label, minlength=n).astype(float)
    return np.column_stack([np.bincount(label, weights=points[:, k], minlength=n) / counts for k in range(3)])


def _node_keys(label: np.ndarray, group: np.ndarray, shared: np.ndarray, m: int) -> np.ndarray:
    """Per node: ``_SHARED`` if all its points are shared ones, else its group if it has one group, else
    ``_MIXED`` (lane ends of several sections joined by links). Nodes with one key may merge."""
    low = np.full(m, np.iinfo(np.int32).max, dtype=np.int32)
    high = np.full(m, np.iinfo(np.int32).min, dtype=np.int32)
    np.minimum.at(low, label, group)
    np.maximum.at(high, label, group)
    key = np.where(low == high, low, _MIXED)
    del high
    key[np.bincount(label[~shared], minlength=m) == 0] = _SHARED
    return key


def merge_points(
    points: np.ndarray,
    joins: np.ndarray,
    group: np.ndarray | None = None,
    shared: np.ndarray | None = None,
    radius: float = NODE_RADIUS,
    max_rounds: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """(node index of every point, (m, 3) node positions).

    ``joins``: (k, 2) point indices that must become one node. ``group``: per point, the lane section it
    belongs to (one group when not given): points closer than ``radius`` become one node within a group;
    ``FREE`` points (signal geometry) take the nearest node within ``radius`` and otherwise merge with the
    free points near them. ``shared``: per point, whether a node made of such points only may merge with
    nodes of other groups that are made of them too (none when not given). Nodes are numbered in the order
    of their first point, so the output does not depend on scipy's component numbering.
    """
    n = len(points)
    if not n:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    group = np.zeros(n, dtype=np.int32) if group is None else np.asarray(group)
    shared = np.zeros(n, dtype=bool) if shared is None else np.asarray(shared, dtype=bool)
    joins = np.asarray(joins, dtype=np.int64).reshape(-1, 2)
    free = np.flatnonzero(group == FREE)
    # the others, as a view where the free points come last (the exporter's signal points): a region has
    # ten million points
    tail = len(free) == 0 or free[0] == n - len(free)
    fixed = slice(0, n - len(free)) if tail else np.flatnonzero(group != FREE)
    fixed_points, fixed_group, fixed_shared = points[fixed], group[fixed], shared[fixed]

    close = cKDTree(fixed_points).query_pairs(radius, output_type="ndarray")
    close = close[fixed_group[close[:, 0]] == fixed_group[close[:, 1]]]
    if not tail:
        joins = np.searchsorted(fixed, joins)  # joins are between fixed points: their numbers among them
    label = _first_order(_components(len(fixed_points), np.concatenate([joins, close])))
    del close
    m = int(label.max()) + 1 if len(label) else 0
    positions = _means(fixed_points, label, m)
    # nodes of shared points merge across groups; and a node at the mean of its points may come close to
    # another one of its kind: merge again until none do. A node holding a lane end never merges with
    # another section's by position, so none can bridge two sections' lane ends.
    for _ in range(max_rounds):
        close = cKDTree(positions).query_pairs(radius, output_type="ndarray")
        key = _node_keys(label, fixed_group, fixed_shared, m)
        close = close[(key[close[:, 0]] == key[close[:, 1]]) & (key[close[:, 0]] != _MIXED)]
        del key
        if not len(close):
            break
        del positions  # a region's nodes: free what the next ones replace before making them
        merged = _first_order(_components(m, close))
        del close
        np.take(merged, label, out=label, mode="clip")  # in place: a region's labels are 100 MB
        m = int(merged.max()) + 1
        del merged
        positions = _means(fixed_points, label, m)

    if not len(free):
        return label, positions
    # free points: one nearest node each (which they do not move), never a bridge between sections; the rest
    # are nodes of their own, numbered on
    node_of = np.empty(n, dtype=np.int64)
    node_of[fixed] = label
    del label
    taken = np.zeros(len(free), dtype=bool)
    if m:
        distance, nearest = cKDTree(positions).query(points[free])
        taken = distance <= radius
        node_of[free[taken]] = nearest[taken]
    alone = free[~taken]
    among = _components(len(alone), cKDTree(points[alone]).query_pairs(radius, output_type="ndarray"))
    node_of[alone] = m + among  # scipy numbers components in the order of their first member
    positions = np.concatenate([positions, _means(points[alone], among, int(among.max(initial=-1)) + 1)])
    if not tail:  # free points among the others: number the nodes in the order of their first point again
        first = np.full(len(positions), n, dtype=np.int64)
        np.minimum.at(first, node_of, np.arange(n))
        rank = np.argsort(np.argsort(first))
        node_of = rank[node_of]
        positions = positions[np.argsort(rank)]
    return node_of, positions


def _first_order(label: np.ndarray) -> np.ndarray:
    """Relabel components 0, 1, ... in the order of their first member (``label`` holds 0 .. k-1; one pass
    instead of a sort: a region has ten million points)."""
    k = int(label.max()) + 1 if len(label) else 0
    first = np.full(k, len(label), dtype=np.int64)
    np.minimum.at(first, label, np.arange(len(label)))
    rank = np.empty(k, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(k)
    return rank[label]
