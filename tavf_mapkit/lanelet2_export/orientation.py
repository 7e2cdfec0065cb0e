"""Which lanelets Lanelet2's loader will turn around: a replica of ``lanelet::geometry::align``.

Lanelet2 does not take a lanelet's bounds as written: the loader inverts the left bound unless the right
bound's middle point lies right of it, then the right bound unless the left bound's middle point lies left of
it (``signedDistance`` to the nearest segment in 3D, with its rule for points nearest a vertex). Our bounds run
in the driving direction, so on sane geometry nothing is inverted. A lane whose border runs backwards between its
two corners (inside out: netconvert's wide lane groups through tight junction turns) cannot pass that test
with any polyline from corner to corner; the export counts those lanelets instead of hiding them.

Where the middle point is nearest a vertex at which the bound turns back (the curl a folded inner border leaves
on a tight ramp), the two segments meeting there disagree on the side and the loader's answer depends on which
of the two equally near segments its distance search keeps: Columbus, road 151076, reads either way depending on
how many points the bound has. Such a lanelet is *uncertain* and handled as a turned one.
"""

from __future__ import annotations

import itertools

import numpy as np

#: a side decided by less than this may be noise to the loader: ten times the file's lat/lon rounding
#: (1e-10 deg, 0.01 mm). Columbus's U-turn 251407 with bounds cut to their corners had the right chord's middle
#: 2 nm off the 79 mm inner bound's line; at 1 mm tiny turnaround loops whose side is clear would count too
SIDE_MARGIN = 1e-4


def _middle(points: np.ndarray) -> np.ndarray:
    """lanelet2's getMiddlePoint: the point at half the count, or the mean of the ends for two points."""
    return points[len(points) // 2] if len(points) > 2 else 0.5 * (points[0] + points[-1])


def inverted_bounds(left: np.ndarray, right: np.ndarray) -> tuple[bool, bool] | None:
    """(left inverted, right inverted) as Lanelet2's loader decides for (n, 2) or (n, 3) bounds as the file has
    them, or None where its decision hangs on a tie (see the module's doc)."""
    left_inverted, right_inverted, uncertain = _inversions([left], [right])
    return None if uncertain[0] else (bool(left_inverted[0]), bool(right_inverted[0]))


def _sides(lines: list[np.ndarray], queries: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every (polyline, point) pair: is the point left of the polyline, is it off it, and is that side
    uncertain. lanelet2's signedDistance: the nearest segment decides (distances over all the coordinates
    given, the side in x-y); a point nearest a segment's end vertex is nearest there exactly, and the next
    segment may turn the answer. Uncertain: where that vertex is also the next segment's start and the next
    segment alone says the other side (the answer depends on which of the two the loader keeps), where the
    point lies within ``SIDE_MARGIN`` of the deciding segment's line, or where another segment within
    ``SIDE_MARGIN`` as near says the other side."""
    n = len(lines)
    sizes = np.array([len(line) for line in lines], dtype=np.int64)
    left = np.zeros(n, dtype=bool)
    positive = np.zeros(n, dtype=bool)
    uncertain = np.zeros(n, dtype=bool)
    single = sizes < 2
    if single.any():  # a one-point line: the distance to the point, never left
        idx = np.flatnonzero(single)
        points = np.array([lines[i][0] for i in idx]).reshape(len(idx), -1)
        positive[idx] = np.linalg.norm(queries[idx] - points, axis=1) > 0
    many = np.flatnonzero(~single)
    if not len(many):
        return left, positive, uncertain
    count = sizes[many] - 1
    owner = np.repeat(np.arange(len(many)), count)
    stacked = np.concatenate([lines[i] for i in many])
    first = np.cumsum(sizes[many]) - sizes[many]
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    a = stacked[np.repeat(first, count) + k]
    b = stacked[np.repeat(first, count) + k + 1]
    p = queries[many][owner]
    d = b - a
    # lanelet2's projection: the start vertex itself where c1 <= 0, the end vertex itself where c2 <= c1, so a
    # point nearest a vertex is exactly as near the two segments meeting there (the first of them is kept)
    c1 = np.einsum("ij,ij->i", p - a, d)
    c2 = np.einsum("ij,ij->i", d, d)
    at_start = c1 <= 0
    at_end = ~at_start & (c2 <= c1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = a + (c1 / c2)[:, None] * d
    foot = np.where(at_start[:, None], a, np.where(at_end[:, None], b, inside))
    distance2 = np.einsum("ij,ij->i", p - foot, p - foot)
    # first nearest segment of each line
    order = np.lexsort((np.arange(len(owner)), distance2, owner))
    best = order[np.searchsorted(owner[order], np.arange(len(many)), side="left")]

    side = _cross(d, p - a)  # lanelet2's pointIsLeftOf: the z of (b - a) x (p - a), left where > 0
    raw = side > 0
    result = raw[best].copy()
    span = np.sqrt(c2)
    with np.errstate(divide="ignore", invalid="ignore"):
        off_line = np.abs(side) / span
    # near-collinear: the side is the sign of a cross product the loader's coordinates may turn
    close_call = off_line[best] < SIDE_MARGIN
    vertex = np.flatnonzero(at_end[best] & (k[best] != count - 1))
    if len(vertex):
        j = best[vertex]
        next_side = raw[j + 1]
        disagree = result[vertex] != next_side
        turn = _cross(d[j], b[j + 1] - a[j])
        flip = disagree & (result[vertex] == (turn > 0))
        result[vertex[flip]] = ~result[vertex[flip]]
        # had the loader kept the next segment (it starts on the vertex), it would read next_side; where the
        # line doubles straight back the rule's test of the turn is a close call too
        uncertain[many[vertex[result[vertex] != next_side]]] = True
        close_call[vertex] |= (off_line[j + 1] < SIDE_MARGIN) | (disagree & (np.abs(turn) / span[j] < SIDE_MARGIN))
    # another segment about as near that says the other side (the one after a vertex is the rule's)
    near = distance2 <= (np.sqrt(distance2[best])[owner] + SIDE_MARGIN) ** 2
    others = near & (raw != result[owner])
    others[best] = False
    others[best[vertex] + 1] = False
    uncertain[many] |= close_call | (np.bincount(owner[others], minlength=len(many)) > 0)
    left[many] = result
    positive[many] = distance2[best] > 0
    return left, positive, uncertain


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """z of the cross products of the x-y parts of rows of ``u`` and ``v``."""
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def _inversions(lefts: list[np.ndarray], rights: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``inverted_bounds`` of many lanelets at once: (left inverted, right inverted, uncertain)."""
    left_size = np.array([len(v) for v in lefts])
    right_size = np.array([len(v) for v in rights])
    trivial = ((left_size <= 1) & (right_size <= 1)) | (left_size == 0) | (right_size == 0)
    dim = next((np.shape(v)[1] for v in lefts + rights if len(v)), 2)
    side, positive, left_uncertain = _sides(lefts, np.array([_middle(r) for r in rights]).reshape(-1, dim))
    left_inverted = ~(~side & positive) & (left_size > 1) & ~trivial
    middles = np.array([_middle(l[::-1] if inv else l) for l, inv in zip(lefts, left_inverted)]).reshape(
        -1, dim
    )
    side, positive, right_uncertain = _sides(rights, middles)
    right_inverted = ~(side & positive) & (right_size > 1) & ~trivial
    return left_inverted, right_inverted, (left_uncertain | right_uncertain) & ~trivial


def turned_lanelets(laneletmap) -> list[int]:
    """Indices of the lanelets Lanelet2 will not read, or may not read, in their lane's driving direction. Our
    ways run with s, so a lanelet against s is right when both bounds get inverted, one with s when neither
    does."""
    if not laneletmap.lanelets:
        return []
    nodes = laneletmap.nodes
    lefts = [nodes[laneletmap.way_nodes[lanelet["left"]]] for lanelet in laneletmap.lanelets]
    rights = [nodes[laneletmap.way_nodes[lanelet["right"]]] for lanelet in laneletmap.lanelets]
    against = np.array([not lanelet["forward"] for lanelet in laneletmap.lanelets])
    left_inverted, right_inverted, uncertain = _inversions(lefts, rights)
    return np.flatnonzero((left_inverted != against) | (right_inverted != against) | uncertain).tolist()


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
    """(n, 3) of node ids that are nodes of ``original`` or, from ``first_fresh`` on, points of ``fresh``."""
    is_fresh = ids >= first_fresh
    xyz = original[np.where(is_fresh, 0, ids)]
    xyz[is_fresh] = fresh[ids[is_fresh] - first_fresh]
    return xyz


def _cross_section(middle: np.ndarray, u: np.ndarray, n: np.ndarray, offset: float) -> np.ndarray:
    """Three points across ``middle`` at ``offset`` along ``n``, ``offset / 4`` apart along ``u``."""
    step = 0.25 * abs(offset)
    xy = middle[:2] + offset * n + np.array([-step, 0.0, step])[:, None] * u
    return np.column_stack([xy, np.full(3, middle[2])])
