"""Curbs around junctions: a low solid strip along every open side of a junction surface.

A junction surface (kind "junction" faces of the road surface) meets the incoming roads at its entries; between
them its border is open -- the corners of a crossing, the outer side of a turn. Those open sides get a curb
JUNCTION_CURB_WIDTH wide, standing JUNCTION_CURB_HEIGHT above the junction's edge and reaching
CURB_FOUNDATION below it (as the curbs of raised lanes do), on the outside of the junction.

Which sides are open is read from the surface mesh and the connecting roads' ends: an outer border edge of the
junction is open when it lies along the side of a connecting lane -- not across a connecting road's start or
end (CAP_TOLERANCE), where traffic enters or leaves, even when the road beyond is narrower -- and no other
road-surface face lies in front of it within PROBE_DEPTH (a gap between the junction and a neighbouring road or
junction is not a curb either); holes inside a junction get none. The strips are cut out of every road-surface
face they would overlap, so a curb never covers a lane, and out of the swept path of every driving lane
(``swept_path``), so a car following its lane never meets one where netconvert drew a corner tighter than a
car turns. Pieces smaller than MIN_AREA or cut off from the junction (no corner within TOUCH of its open
border) are dropped.
Heights follow the junction's own border: every curb corner takes the height of the nearest open border point.
One solid per connected curb piece, labelled with the connecting road behind it (source "junction J curb k").
"""

from __future__ import annotations

import manifold3d
import numpy as np
import shapely

from tavf_mapkit.mesh.labelled import KIND_CODE, LabelledMesh
from tavf_mapkit.mesh.solid_curbs import CURB_FOUNDATION
from tavf_mapkit.mesh.solid_kit import Solid, SolidError, to_solid
from tavf_mapkit.mesh.swept_path import CentrePieces, swept_section
from tavf_mapkit.opendrive.sampling import sample_lanes_at

JUNCTION_CURB_HEIGHT = 0.15   # m above the junction's edge (a common kerb upstand)
JUNCTION_CURB_WIDTH = 0.30    # m, outwards from the junction's edge
PROBE_DEPTH = 0.5             # m: a border edge with road surface this close in front of it is not open
SIMPLIFY = 0.001              # m: collinear border vertices are merged within this
HEIGHT_STEP = 0.25            # m: open borders are sampled this densely for the curb heights
MIN_AREA = 0.02               # m^2: smaller curb pieces are dropped
TOUCH = 0.002                 # m: a curb piece with no corner this close to the open border is dropped
CAP_TOLERANCE = 0.05          # m: a border edge this close to a connecting road's start or end is an entry
CONTEXT_REACH = 2.0           # m: surface faces this far from a cluster's junction faces can touch its curbs
ROAD_REACH = 10.0             # m: roads whose coarse box is this close may sweep over (or end at) its curbs


def junction_curb_solids(odr, surface: LabelledMesh, units=None) -> tuple[list[Solid], list[str]]:
    """One curb solid per connected curb piece along the open sides of every junction, ordered by junction
    and position (and "where: why" for pieces that could not be made). Junction clusters (``mesh.units``) are
    curbed one by one, each from its own surroundings (``cluster_curb_solids``)."""
    from tavf_mapkit.mesh.units import mesh_units

    if surface is None or not len(surface.faces):
        return [], []
    junction_face = surface.kind == KIND_CODE["junction"]
    if not np.any(junction_face):
        return [], []
    units = mesh_units(odr) if units is None else units
    face_unit = units.road_unit[surface.road_index]
    made = []
    around = CurbSurroundings(odr)  # every road's lanes, sampled once
    for unit in np.unique(face_unit[junction_face]).tolist():
        made.extend(cluster_curb_solids(odr, surface, junction_face & (face_unit == unit), units, around))
    made.sort(key=lambda item: item[0])
    return [item[1] for item in made if item[1] is not None], [item[2] for item in made if item[2] is not None]


def curb_context(surface: LabelledMesh, cluster_faces: np.ndarray):
    """(plan box of a cluster's junction faces, mask of the faces that may touch its curbs: their plan boxes
    come within CONTEXT_REACH of that box). Faces further away can neither stand in front of an open side
    nor under a curb strip, so the curbs made from this part of the surface are those of the whole."""
    corners = surface.vertices[surface.faces[cluster_faces]][:, :, :2].reshape(-1, 2)
    box = np.concatenate([corners.min(axis=0), corners.max(axis=0)])
    plan = surface.vertices[surface.faces][:, :, :2]
    low, high = plan.min(axis=1), plan.max(axis=1)
    near = np.all(low <= box[2:] + CONTEXT_REACH, axis=1) & np.all(high >= box[:2] - CONTEXT_REACH, axis=1)
    return box, near


class CurbSurroundings:
    """The lanes the curbs of junction clusters must respect -- connecting roads' ends and driving lanes'
    swept paths -- sampled once for the ``roads`` indices (all when not given), asked per cluster. ``before``:
    the surroundings of the group of clusters before, whose swept pieces of the roads both need are reused."""

    def __init__(self, odr, roads: np.ndarray | None = None, before: CurbSurroundings | None = None):
        self.ends, self.end_road = _road_ends(odr, roads)
        self.pieces = CentrePieces.of(odr, roads, None if before is None else before.pieces)

    def ends_of(self, roads: np.ndarray) -> np.ndarray:
        return self.ends[np.isin(self.end_road, roads)]


def cluster_curb_solids(odr, surface: LabelledMesh, cluster_faces: np.ndarray, units,
                        around: CurbSurroundings | None = None) -> list[tuple]:
    """The curbs of one junction cluster (``cluster_faces``: mask of its junction faces in ``surface``), as
    (sort key, solid or None, skipped line or None) with sort key (junction id, x, y). Only the surface near
    the cluster and the roads near it count, so the result is the same from any part of the surface that
    holds that neighbourhood (the tiled mesher passes the tiles around the cluster). ``around``: the
    surroundings of (at least) the roads near the cluster, sampled before."""
    box, near = curb_context(surface, cluster_faces)
    local = surface.select(near)
    junction_face = cluster_faces[near]
    roads = units.roads_near(box, ROAD_REACH)
    around = CurbSurroundings(odr, roads) if around is None else around
    plan = local.vertices[local.faces][:, :, :2]
    triangles = shapely.polygons(np.concatenate([plan, plan[:, :1]], axis=1))
    tree = shapely.STRtree(triangles)
    edges, face = _open_edges(local, junction_face, triangles, tree, around.ends_of(roads))
    if not len(face):
        return []
    order, chain = _chains(edges)
    strips = shapely.buffer(_chain_lines(local.vertices, edges, order, chain), -JUNCTION_CURB_WIDTH,
                            single_sided=True, join_style="mitre", mitre_limit=2.0)
    strips = shapely.orient_polygons(shapely.make_valid(strips))
    # the faces the strips overlap: every face one meets, except those owning its own edges (they only touch)
    strip_of_pair, hit = tree.query(strips, predicate="intersects")
    n_faces = len(local.faces)
    own = np.isin(strip_of_pair * n_faces + hit, chain * n_faces + face[order])
    cuts = triangles[np.unique(hit[~own])]
    # the cluster's strips minus the faces, in one plane (manifold3d / Clipper2)
    anchor = np.round(shapely.get_coordinates(strips).mean(axis=0))
    section = manifold3d.CrossSection(_contours(strips, anchor), manifold3d.FillRule.Positive)
    if len(cuts):
        section = section - manifold3d.CrossSection(_contours(cuts, anchor), manifold3d.FillRule.Positive)
    section = section - swept_section(odr, strips, anchor, roads, around.pieces)
    heights = _BorderHeights(local.vertices, edges[order], face[order])
    labelled = []
    for piece in section.decompose():
        if piece.area() < MIN_AREA:
            continue
        corners = np.concatenate(piece.to_polygons()) + anchor
        _, behind, distance = heights(corners)
        if distance.min() > TOUCH:  # cut off from the junction by another surface: not a curb of it
            continue
        low, high = corners.min(axis=0), corners.max(axis=0)
        road_index = int(local.road_index[behind[np.argmin(distance)]])
        road = odr.roads[road_index]
        labelled.append((road.junction if road.in_junction else "", float(low[0] + high[0]),
                         float(low[1] + high[1]), road_index, piece))

    def place(vertices: np.ndarray) -> np.ndarray:
        z = heights(vertices[:, :2] + anchor)[0]
        out = np.array(vertices, dtype=float)
        out[:, 2] = np.where(vertices[:, 2] > 0.5, z + JUNCTION_CURB_HEIGHT, z - CURB_FOUNDATION)
        return out

    labelled.sort(key=lambda item: item[:3])
    made, count = [], {}
    for junction, x, y, road_index, piece in labelled:
        number = count[junction] = count.get(junction, -1) + 1
        where = f"junction {junction} curb {number}"
        try:
            made.append(((junction, x, y), to_solid(piece.extrude(1.0).warp_batch(place), "curb", where,
                                                    (*anchor, 0.0), road_index=road_index, lane_id=0), None))
        except SolidError as error:
            made.append(((junction, x, y), None, f"{where}: {error}"))
    return made


def _open_edges(surface: LabelledMesh, junction_face: np.ndarray, triangles: np.ndarray, tree: shapely.STRtree,
                road_ends):
    """(vertex ids (E, 2), face) of every outer border edge of the junction faces with no road surface in front
    and not across a connecting road's end (``road_ends``, shapely LineStrings).

    Junction faces are counter-clockwise from above, so a border edge a -> b has its face on the left and
    the outside on the right; outer borders run counter-clockwise, the borders of holes clockwise. Holes are
    left alone: a gap between connecting lanes inside a crossing is no traffic island, and a curb there would
    stand in the way. "In front" is the rectangle PROBE_DEPTH deep on the right of the edge's middle 80 %
    (the ends are left out so that a road beside the edge's end does not count)."""
    faces = surface.faces[junction_face]
    owner = np.flatnonzero(junction_face)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edge_face = np.tile(owner, 3)
    n = len(surface.vertices)
    border = ~np.isin(directed[:, 0] * n + directed[:, 1], directed[:, 1] * n + directed[:, 0])
    directed, edge_face = directed[border], edge_face[border]
    a, b = surface.vertices[directed[:, 0], :2], surface.vertices[directed[:, 1], :2]
    order, ring = _chains(directed)
    twice_area = np.bincount(ring, weights=(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1])[order])
    outer = np.zeros(len(directed), dtype=bool)
    outer[order] = twice_area[ring] > 0
    directed, edge_face, a, b = directed[outer], edge_face[outer], a[outer], b[outer]
    along = b - a
    length = np.hypot(along[:, 0], along[:, 1])
    keep = length > 1e-6
    directed, edge_face, a, b, along, length = (x[keep] for x in (directed, edge_face, a, b, along, length))
    outward = np.column_stack([along[:, 1], -along[:, 0]]) / length[:, None]
    near = a + 0.1 * along + 0.01 * outward
    far = b - 0.1 * along + 0.01 * outward
    depth = PROBE_DEPTH * outward
    probes = shapely.polygons(np.stack([near, far, far + depth, near + depth, near], axis=1))
    edge, triangle = tree.query(probes, predicate="intersects")
    covered = np.zeros(len(directed), dtype=bool)
    covered[edge[triangle != edge_face[edge]]] = True
    if len(road_ends):
        ends = shapely.STRtree(road_ends)
        at_end = np.zeros(2 * len(a), dtype=bool)
        point, _ = ends.query(shapely.points(np.concatenate([a, b])), predicate="dwithin", distance=CAP_TOLERANCE)
        at_end[point] = True
        covered |= at_end[:len(a)] & at_end[len(a):]
    return directed[~covered], edge_face[~covered]


def _road_ends(odr, roads: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The start and end line of every lane of every connecting road (of the ``roads`` indices, when given;
    shapely LineStrings) and the road of each."""
    arrays = odr.arrays
    in_junction = np.zeros(len(odr.roads), dtype=bool)
    for road in (range(len(odr.roads)) if roads is None else np.asarray(roads).tolist()):
        in_junction[road] = odr.roads[road].in_junction
    if not len(arrays.section_s0) or not np.any(in_junction):
        return np.zeros(0, dtype=object), np.zeros(0, dtype=np.int64)
    section_road = arrays.section_road
    first = np.flatnonzero(np.r_[True, section_road[1:] != section_road[:-1]])
    last = np.r_[first[1:] - 1, len(section_road) - 1]
    first, last = first[in_junction[section_road[first]]], last[in_junction[section_road[last]]]
    sections = np.concatenate([first, last])
    s = np.concatenate([arrays.section_s0[first], arrays.section_end[last]])
    order = np.argsort(sections, kind="stable")
    sampling = sample_lanes_at(odr, sections[order], s[order])
    inner = sampling.points_at(sampling.t_inner)[:, :2]
    outer = sampling.points_at(sampling.t_outer)[:, :2]
    return shapely.linestrings(np.stack([inner, outer], axis=1)), sampling.road_index


def _chains(edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Order directed edges (vertex ids) into chains: (edge index in chain order, chain number per entry).
    Open chains start where no edge ends; what is left are closed rings."""
    successor = {int(a): k for k, a in enumerate(edges[:, 0])}
    ends = set(edges[:, 1].tolist())
    seen = np.zeros(len(edges), dtype=bool)
    order, chain = [], []
    starts = [k for k, a in enumerate(edges[:, 0].tolist()) if a not in ends] + list(range(len(edges)))
    for k in starts:
        if seen[k]:
            continue
        number = len(order) and chain[-1] + 1
        while k is not None and not seen[k]:
            seen[k] = True
            order.append(k)
            chain.append(number)
            k = successor.get(int(edges[k, 1]))
    return np.asarray(order, dtype=np.int64), np.asarray(chain, dtype=np.int64)


def _chain_lines(vertices: np.ndarray, edges: np.ndarray, order: np.ndarray, chain: np.ndarray) -> np.ndarray:
    """One plan-view LineString per chain (start vertex of every edge, then the last edge's end)."""
    last = np.flatnonzero(np.append(chain[1:] != chain[:-1], True))
    ids = np.insert(edges[order, 0], last + 1, edges[order[last], 1])
    line = np.insert(chain, last + 1, chain[last])
    lines = shapely.linestrings(vertices[ids, :2], indices=line)
    # junction borders carry many collinear vertices (grid cuts, refinement midpoints): 1 mm is invisible
    return shapely.simplify(lines, SIMPLIFY, preserve_topology=True)


class _BorderHeights:
    """Height of, and face behind, the nearest open border point (points every HEIGHT_STEP along the edges)."""

    def __init__(self, vertices: np.ndarray, edges: np.ndarray, face: np.ndarray):
        from scipy.spatial import cKDTree

        a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
        count = np.maximum(1, np.ceil(np.hypot(*(b - a)[:, :2].T) / HEIGHT_STEP).astype(np.int64))
        edge = np.repeat(np.arange(len(a)), count + 1)
        u = (np.arange(len(edge)) - np.repeat(np.cumsum(count + 1) - count - 1, count + 1)) / count[edge]
        points = a[edge] + u[:, None] * (b[edge] - a[edge])
        self.z = points[:, 2]
        self.face = face[edge]
        self.tree = cKDTree(points[:, :2])

    def __call__(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height, face and plan distance of the nearest border sample of every point."""
        distance, nearest = self.tree.query(xy)
        return self.z[nearest], self.face[nearest], distance


def _contours(polygons: np.ndarray, anchor: np.ndarray) -> list[np.ndarray]:
    """Every ring of the (oriented) polygons, without the closing point, relative to ``anchor``."""
    parts = shapely.get_parts(polygons)
    rings = shapely.get_rings(parts[shapely.get_type_id(parts) == 3])
    coordinates, ring = shapely.get_coordinates(rings, return_index=True)
    cuts = np.flatnonzero(np.diff(ring)) + 1
    return [part[:-1] - anchor for part in np.split(coordinates, cuts)]
