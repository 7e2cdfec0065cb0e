"""Points into OSM nodes: one node wherever points coincide, and one where the map's links join lane ends.

Lanelet2 finds a lanelet's successor by node identity (the end points of its bounds are the start points of
the next one's), and neighbours by way identity. So the corners of lane ends that the map links are made one
node (they lie within micrometres of each other on a repaired build), and then any points closer than
``radius`` become one node too, so no two nodes of the file coincide. A node sits at the mean of its points.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: points closer than this are one node (m)
NODE_RADIUS = 2e-3


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    if not len(pairs):
        return np.arange(n)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _means(points: np.ndarray, label: np.ndarray, n: int) -> np.ndarray:
    counts = np.bincount(label, minlength=n).astype(float)
    return np.column_stack([np.bincount(label, weights=points[:, k], minlength=n) / counts for k in range(3)])


def merge_points(
    points: np.ndarray, joins: np.ndarray, radius: float = NODE_RADIUS, max_rounds: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """(node index of every point, (m, 3) node positions).

    ``joins``: (k, 2) point indices that must become one node. Nodes are numbered in the order of their first
    point, so the output does not depend on scipy's component numbering.
    """
    n = len(points)
    if not n:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    joins = np.asarray(joins, dtype=np.int64).reshape(-1, 2)
    close = cKDTree(points).query_pairs(radius, output_type="ndarray")
    label = _components(n, np.concatenate([joins, close]))
    label = _first_order(label)
    m = int(label.max()) + 1
    positions = _means(points, label, m)
    # a node at the mean of its points may come close to another one: merge again until none do
    for _ in range(max_rounds):
        close = cKDTree(positions).query_pairs(radius, output_type="ndarray")
        if not len(close):
            break
        merged = _first_order(_components(m, close))
        label = merged[label]
        m = int(merged.max()) + 1
        positions = _means(points, label, m)
    return label, positions


def _first_order(label: np.ndarray) -> np.ndarray:
    """Relabel components 0, 1, ... in the order of their first member."""
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)  # one sort of the labels
    order = np.argsort(first)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank[inverse]
