"""A directed graph of numbered nodes as arrays: each node's out-edges in one compressed row (CSR), with
their kind and weight; strongly connected components and exact shortest paths over them.

A region's lane graph has hundreds of thousands of lanes and edges: as a networkx graph that is a dict per
node and per edge (some 600 MB on Columbus's 161,781 lanes), here it is four arrays (a few MB).

Routes must not change with the representation: where several routes cost the same, networkx returns the
one its search meets first, and that depends on the order of each node's out-edges (the order they were
added) and on its heap's tie-break (a running counter). ``EdgeArrays`` keeps each node's out-edges in the
order they were added, and ``distances``/``astar`` are networkx's ``_dijkstra_multisource`` and
``astar_path`` step for step (networkx 3.x), on integers and Python floats, so they return the same routes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cached_property
from heapq import heappop, heappush
from itertools import count

import numpy as np

FOLLOW, LEFT, RIGHT = 0, 1, 2
KIND_NAMES = ("follow", "left", "right")
KIND_CODES = {name: code for code, name in enumerate(KIND_NAMES)}


class EdgeArrays:
    """Edges ``source[e] -> target[e]`` of a graph of ``n`` nodes, each node's edges in one row:
    ``target[indptr[i]:indptr[i + 1]]`` are node i's successors in the order they were first added.

    Build with :meth:`from_edges`: an edge added twice keeps its first place and its last kind and weight
    (as ``networkx.DiGraph.add_edge`` does)."""

    def __init__(self, n: int, indptr: np.ndarray, target: np.ndarray, kind: np.ndarray, weight: np.ndarray):
        self.n = int(n)
        self.indptr = indptr
        self.target = target
        self.kind = kind
        self.weight = weight

    @classmethod
    def from_edges(cls, n: int, source, target, kind=None, weight=None) -> EdgeArrays:
        source = np.asarray(source, dtype=np.int64).reshape(-1)
        target = np.asarray(target, dtype=np.int64).reshape(-1)
        kind = np.zeros(len(source), dtype=np.int8) if kind is None else np.asarray(kind, dtype=np.int8)
        weight = np.ones(len(source)) if weight is None else np.asarray(weight, dtype=np.float64)
        if len(source):
            code = source * max(n, 1) + target
            # first place of each distinct edge, and its last occurrence for kind and weight
            _, first = np.unique(code, return_index=True)
            _, from_end = np.unique(code[::-1], return_index=True)
            last = len(code) - 1 - from_end  # both in the order of the sorted distinct codes
            order = np.argsort(first, kind="stable")
            first, last = first[order], last[order]
            # rows by source, each row in the order its edges were first added
            by_source = np.argsort(source[first], kind="stable")
            first, last = first[by_source], last[by_source]
            source, target, kind, weight = source[first], target[first], kind[last], weight[last]
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(source, minlength=n), out=indptr[1:])
        return cls(n, indptr, target.astype(np.int32), kind.astype(np.int8), weight.astype(np.float64))

    def __len__(self) -> int:
        return len(self.target)

    @cached_property
    def source(self) -> np.ndarray:
        """The source node of every edge (row order)."""
        return np.repeat(np.arange(self.n, dtype=np.int32), np.diff(self.indptr))

    def row(self, i: int) -> range:
        """Indices of node ``i``'s out-edges."""
        return range(int(self.indptr[i]), int(self.indptr[i + 1]))

    def find(self, i: int, j: int) -> int:
        """Index of the edge ``i -> j``, -1 without one (rows are short: a lane has a handful of edges)."""
        start, stop = int(self.indptr[i]), int(self.indptr[i + 1])
        hits = np.flatnonzero(self.target[start:stop] == j)
        return start + int(hits[0]) if len(hits) else -1

    @cached_property
    def incoming(self) -> tuple[np.ndarray, np.ndarray]:
        """(indptr, edge): node j's incoming edges are ``edge[indptr[j]:indptr[j + 1]]`` (indices into the
        forward arrays), in row order of their sources."""
        indptr = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(np.bincount(self.target, minlength=self.n), out=indptr[1:])
        return indptr, np.argsort(self.target, kind="stable")

    # ------------------------------------------------------------------ components
    def strong_labels(self) -> tuple[int, np.ndarray]:
        """(number of strongly connected components, component label of every node)."""
        return strong_components(self.n, self.source, self.target)

    # ------------------------------------------------------------------ shortest paths (networkx's searches)
    @cached_property
    def lists(self) -> tuple[list[int], list[int], list[int], list[float]]:
        """(indptr, target, kind, weight) as Python lists: searches and walks step edge by edge, and numpy
        scalars would make them several times slower (a region's edges: some 20 MB as lists)."""
        return self.indptr.tolist(), self.target.tolist(), self.kind.tolist(), self.weight.tolist()

    def distances(self, source: int, cutoff: float | None = None) -> tuple[dict[int, float], dict[int, int]]:
        """(cost of the cheapest route to every node reached within ``cutoff``, in the order the search settles
        them; the node before each on its route). networkx's ``single_source_dijkstra``: the route kept to a
        node is the first found at its final cost."""
        indptr, target, _kind, weight = self.lists
        dist: dict[int, float] = {}
        seen = {source: 0}
        before: dict[int, int] = {}
        c = count()
        fringe = [(0, next(c), source)]
        while fringe:
            d, _, v = heappop(fringe)
            if v in dist:
                continue
            dist[v] = d
            for e in range(indptr[v], indptr[v + 1]):
                u = target[e]
                vu = d + weight[e]
                if cutoff is not None and vu > cutoff:
                    continue
                if u in dist:
                    continue
                if u not in seen or vu < seen[u]:
                    seen[u] = vu
                    heappush(fringe, (vu, next(c), u))
                    before[u] = v
        return dist, before

    def astar(self, source: int, goal: int, heuristic: Callable[[int], float]) -> list[int] | None:
        """Nodes of the cheapest route from ``source`` to ``goal`` (both included), None without one:
        networkx's ``astar_path`` step for step (``heuristic(node)`` estimates the cost on to ``goal``)."""
        indptr, target, _kind, weight = self.lists
        c = count()
        queue = [(0, next(c), source, 0, None)]
        enqueued: dict[int, tuple[float, float]] = {}
        explored: dict[int, int | None] = {}
        while queue:
            _, __, node, dist, parent = heappop(queue)
            if node == goal:
                path = [node]
                step = parent
                while step is not None:
                    path.append(step)
                    step = explored[step]
                path.reverse()
                return path
            if node in explored:
                if explored[node] is None:
                    continue
                queued_cost, _h = enqueued[node]
                if queued_cost < dist:
                    continue
            explored[node] = parent
            for e in range(indptr[node], indptr[node + 1]):
                neighbour = target[e]
                cost = dist + weight[e]
                if neighbour in enqueued:
                    queued_cost, h = enqueued[neighbour]
                    if queued_cost <= cost:
                        continue
                else:
                    h = heuristic(neighbour)
                enqueued[neighbour] = cost, h
                heappush(queue, (cost + h, next(c), neighbour, cost, node))
        return None


def route_to(before: dict[int, int], source: int, node: int) -> list[int]:
    """The nodes from ``source`` to ``node`` along ``before`` (from ``EdgeArrays.distances``)."""
    path = [node]
    while path[-1] != source:
        path.append(before[path[-1]])
    path.reverse()
    return path


def strong_components(n: int, source, target) -> tuple[int, np.ndarray]:
    """(number of strongly connected components, label of every node 0..n-1) of the edges source -> target."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    source = np.asarray(source, dtype=np.int64)
    target = np.asarray(target, dtype=np.int64)
    if n == 0:
        return 0, np.zeros(0, dtype=np.int32)
    matrix = csr_matrix((np.ones(len(source), dtype=np.int8), (source, target)), shape=(n, n))
    count_, labels = connected_components(matrix, directed=True, connection="strong")
    return int(count_), labels


def euclidean(xy: list, goal: int) -> Callable[[int], float]:
    """A* heuristic: straight-line distance between node ``i``'s point ``xy[i]`` and the goal's (lists of
    Python floats, as the networkx heuristic's ``math.dist`` had)."""
    target = xy[goal]
    return lambda i: math.dist(xy[i], target)
