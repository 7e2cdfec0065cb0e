"""Which lanelets Lanelet2's loader will turn around: a replica of ``lanelet::geometry::align``.

Lanelet2 does not take a lanelet's bounds as written: the loader inverts the left bound unless the right
bound's middle point lies right of it, then the right bound unless the left bound's middle point lies left of
it (``signedDistance`` to the nearest segment, with its rule for points nearest a vertex). Our bounds run in
the driving direction, so on sane geometry nothing is inverted. A lane whose border runs backwards between its
two corners (inside out: netconvert's wide lane groups through tight junction turns) cannot pass that test
with any polyline from corner to corner; the export counts those lanelets instead of hiding them.
"""

from __future__ import annotations

import itertools

import numpy as np


def _middle(points: np.ndarray) -> np.ndarray:
    """lanelet2's getMiddlePoint: the point at half the count, or the mean of the ends for two points."""
    return points[len(points) // 2] if len(points) > 2 else 0.5 * (points[0] + points[-1])


def inverted_bounds(left: np.ndarray, right: np.ndarray) -> tuple[bool, bool]:
    """(left inverted, right inverted) as Lanelet2's loader decides for (n, 2) bounds as the file has them."""
    left_inverted, right_inverted = _inversions([left], [right])
    return bool(left_inverted[0]), bool(right_inverted[0])


def _sides(lines: list[np.ndarray], queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every (polyline, point) pair: is the point left of the polyline, and is it off it (lanelet2's
    signedDistance: the first nearest segment decides, and where the point is nearest that segment's end
    vertex the
    next segment may turn the answer)."""
    n = len(lines)
    sizes = np.array([len(line) for line in lines], dtype=np.int64)
    left = np.zeros(n, dtype=bool)
    positive = np.zeros(n, dtype=bool)
    single = sizes < 2
    if single.any():  # a one-point line: the distance to the point, never left
        idx = np.flatnonzero(single)
        points = np.array([lines[i][0] for i in idx]).reshape(-1, 2)
        positive[idx] = np.hypot(*(queries[idx] - points).T) > 0
    many = np.flatnonzero(~single)
    if not len(many):
        return left, positive
    count = sizes[many] - 1
    owner = np.repeat(np.arange(len(many)), count)
    stacked = np.concatenate([lines[i] for i in many])
    first = np.cumsum(sizes[many]) - sizes[many]
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    a = stacked[np.repeat(first, count) + k]
    b = stacked[np.repeat(first, count) + k + 1]
    p = queries[many][owner]
    d = b - a
    length2 = np.einsum("ij,ij->i", d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.clip(np.einsum("ij,ij->i", p - a, d) / length2, 0.0, 1.0)
    u = np.where(length2 > 0, u, 0.0)
    foot = a + u[:, None] * d
    distance2 = np.einsum("ij,ij->i", p - foot, p - foot)
    # first nearest segment of each line (lanelet2 keeps the first on ties)
    order = np.lexsort((np.arange(len(owner)), distance2, owner))
    best = order[np.searchsorted(owner[order], np.arange(len(many)), side="left")]

    def is_left(a_, b_, p_):
        return (b_[:, 0] - a_[:, 0]) * (p_[:, 1] - a_[:, 1]) - (b_[:, 1] - a_[:, 1]) * (
            p_[:, 0] - a_[:, 0]
        ) > 0

    result = is_left(a[best], b[best], p[best])
    last_segment = k[best] == count - 1
    at_end = (u[best] >= 1.0) & ~last_segment
    if at_end.any():
        j = best[at_end]
        following = b[j + 1]
        flip = (result[at_end] != is_left(b[j], following, p[j])) & (
            result[at_end] == is_left(a[j], b[j], following)
        )
        result[np.flatnonzero(at_end)[flip]] = ~result[np.flatnonzero(at_end)[flip]]
    left[many] = result
    positive[many] = distance2[best] > 0
    return left, positive


def _inversions(lefts: list[np.ndarray], rights: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``inverted_bounds`` of many lanelets at once."""
    left_size = np.array([len(v) for v in lefts])
    right_size = np.array([len(v) for v in rights])
    trivial = ((left_size <= 1) & (right_size <= 1)) | (left_size == 0) | (right_size == 0)
    side, positive = _sides(lefts, np.array([_middle(r) for r in rights]).reshape(-1, 2))
    left_inverted = ~(~side & positive) & (left_size > 1) & ~trivial
    middles = np.array([_middle(l[::-1] if inv else l) for l, inv in zip(lefts, left_inverted)]).reshape(
        -1, 2
    )
    side, positive = _sides(rights, middles)
    right_inverted = ~(side & positive) & (right_size > 1) & ~trivial
    return left_inverted, right_inverted


def turned_lanelets(laneletmap) -> list[int]:
    """Indices of the lanelets Lanelet2 will not read in their lane's driving direction. Our ways run with s,
    so a lanelet against s is right when both bounds get inverted, one with s when neither does."""
    if not laneletmap.lanelets:
        return []
    nodes = laneletmap.nodes[:, :2]
    lefts = [nodes[laneletmap.way_nodes[lanelet["left"]]] for lanelet in laneletmap.lanelets]
    rights = [nodes[laneletmap.way_nodes[lanelet["right"]]] for lanelet in laneletmap.lanelets]
    against = np.array([not lanelet["forward"] for lanelet in laneletmap.lanelets])
    left_inverted, right_inverted = _inversions(lefts, rights)
    return np.flatnonzero((left_inverted != against) | (right_inverted != against)).tolist()


def give_private_bounds(laneletmap) -> tuple[int, int]:
    """Give each lanelet the loader would turn bounds of its own that it reads the right way round.

    Such a lane runs inside out between its corners, so no polyline along its borders can pass the loader's
    test. Its new bounds keep the corner nodes (so successors still follow it) and pass through a short
    cross-section at the middle of the lanelet, square to its driving direction there (the reference line's,
    which stays sane where the lane does not): ``[start, m - e*u, m, m + e*u, end]`` on each side, the
    loader's middle points m straight across from each other. The first cross-section the loader reads right
    is taken (``_cross_sections``): at our lane centre in the middle of the section, at the middle of the
    corners, a quarter of the length ahead or behind; from the lane's own width down to 5 cm; square to the
    lane's direction, then to the chord between its ends. The lanelet loses only the shared way to
    its neighbours, i.e. lane changes there. Returns (lanelets given private bounds, lanelets still turned).
    """
    turned = turned_lanelets(laneletmap)
    if not turned:
        return 0, 0
    from scipy.spatial import cKDTree

    from tavf_mapkit.lanelet2_export.nodes import NODE_RADIUS

    # the corners and the nodes new points fall on are nodes of the map as built; points the lanelets before
    # added are numbered on from it, and the nodes are joined once at the end (not a copy of every node per
    # candidate: millions of nodes on a region)
    original = laneletmap.nodes
    tree = cKDTree(original)
    added: list[np.ndarray] = []
    n_total = len(original)
    fixed = 0
    for i in turned:
        lanelet = laneletmap.lanelets[i]
        left = laneletmap.way_nodes[lanelet["left"]]
        right = laneletmap.way_nodes[lanelet["right"]]
        forward = lanelet["forward"]
        # corners in driving direction (ways run with s)
        a, b = (left[0], left[-1]) if forward else (left[-1], left[0])
        c, d = (right[0], right[-1]) if forward else (right[-1], right[0])
        nodes = original
        width = 0.5 * (np.hypot(*(nodes[a] - nodes[c])[:2]) + np.hypot(*(nodes[b] - nodes[d])[:2]))
        length = 0.5 * (np.hypot(*(nodes[b] - nodes[a])[:2]) + np.hypot(*(nodes[d] - nodes[c])[:2]))
        for u, middle, half in _cross_sections(lanelet, nodes[a], nodes[b], nodes[c], nodes[d], length):
            n = np.array([-u[1], u[0]])
            half = max(half * width, 0.05)
            points = np.concatenate(
                [_cross_section(middle, u, n, +half), _cross_section(middle, u, n, -half)]
            )
            # a new point on an existing node is that node (no new node on an old one)
            distance, nearest = tree.query(points)
            new = distance > NODE_RADIUS
            ids = np.where(new, n_total + np.cumsum(new) - 1, nearest)
            left_ids = np.array([a, *ids[:3], b])
            right_ids = np.array([c, *ids[3:], d])
            if not forward:  # as written the ways run with s: a lanelet against s lists them from its end
                left_ids, right_ids = left_ids[::-1], right_ids[::-1]
            fresh = points[new]
            if inverted_bounds(_positions(original, fresh, n_total, left_ids),
                               _positions(original, fresh, n_total, right_ids)) == (not forward, not forward):
                break
        else:
            continue
        added.append(fresh)
        n_total += len(fresh)
        # say so in the file: the lane's own geometry is inside out here, and its lane changes are gone
        lanelet["tags"]["opendrive:inside_out"] = "yes"
        for key, line in (("left", left_ids), ("right", right_ids)):
            line = line[np.concatenate([[True], line[1:] != line[:-1]])]
            laneletmap.way_tags.append(dict(laneletmap.way_tags[lanelet[key]]))
            laneletmap.way_nodes.append(line)
            lanelet[key] = len(laneletmap.way_nodes) - 1
        fixed += 1
    laneletmap.nodes = np.concatenate([original, *added])
    return fixed, len(turned) - fixed


def _cross_sections(lanelet: dict, a, b, c, d, length: float):
    """(driving direction u, middle point, half width as a share of the lane's) of the cross-sections to try,
    best first: square to the lane's direction in its middle, then square to the chord from the middle of its
    start to the middle of its end (a lane of a U-turn that is wider than the turn's radius runs inside out
    in its middle, so its own direction there points back: Columbus, road 187692)."""
    centre = 0.25 * (a + b + c + d)
    chord = 0.5 * (b + d - a - c)[:2]
    directions = [np.array([np.cos(lanelet["heading"]), np.sin(lanelet["heading"])])]
    if np.hypot(*chord) > 0:
        directions.append(chord / np.hypot(*chord))
    for u in directions:
        middles = [np.asarray(lanelet["middle"], dtype=float)]
        middles += [centre + np.append(shift * length * u, 0.0) for shift in (0.0, 0.25, -0.25)]
        for middle, half in itertools.product(middles, (0.5, 0.25, 0.1, 0.02)):
            yield u, middle, half


def _positions(original: np.ndarray, fresh: np.ndarray, first_fresh: int, ids: np.ndarray) -> np.ndarray:
    """(n, 2) of node ids that are nodes of ``original`` or, from ``first_fresh`` on, points of ``fresh``."""
    is_fresh = ids >= first_fresh
    xy = original[np.where(is_fresh, 0, ids), :2]
    xy[is_fresh] = fresh[ids[is_fresh] - first_fresh, :2]
    return xy


def _cross_section(middle: np.ndarray, u: np.ndarray, n: np.ndarray, offset: float) -> np.ndarray:
    """Three points across ``middle`` at ``offset`` along ``n``, ``offset / 4`` apart along ``u``."""
    step = 0.25 * abs(offset)
    xy = middle[:2] + offset * n + np.array([-step, 0.0, step])[:, None] * u
    return np.column_stack([xy, np.full(3, middle[2])])
