"""Buildings of an OSM input as solids: footprints (closed ways and multipolygon relations tagged ``building``)
extruded to their height.

Height: ``height`` (metres, or feet with ' / ft), else (``building:levels`` + ``roof:levels``) x LEVEL_HEIGHT,
else DEFAULT_HEIGHT. Bottom: ``min_height`` or ``building:min_level`` x LEVEL_HEIGHT above the ground, else
FOUNDATION below it. Roofs and bridge buildings (``building=roof|bridge|carport``) without a bottom start at
OVERHEAD_CLEARANCE: they stand over streets and must not block them. Underground buildings (``location=
underground`` or a negative ``layer``) and ``building=no`` are left out. The ground is the lowest road-surface
vertex near the footprint (the map has no terrain model).

OSM extracts are often not sorted by id (osmium's extract keeps the input's order, and editors write negative
ids), so footprints are assembled here from two plain passes instead of osmium's sorted-input area assembler.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import manifold3d
import numpy as np
import shapely

from tavf_mapkit.mesh.solid_kit import Solid, SolidError, to_solid

LEVEL_HEIGHT = 3.0        # m per storey
DEFAULT_HEIGHT = 10.0     # m when neither height nor levels are tagged
FOUNDATION = 0.5          # m below the ground, so no gap opens on sloped ground
OVERHEAD = frozenset({"roof", "bridge", "carport"})
OVERHEAD_CLEARANCE = 4.0  # m: bottom of an overhead building without min_height
OVERHEAD_THICKNESS = 1.0  # m: its thickness when no height above the clearance is tagged
MIN_AREA = 0.5            # m2: smaller footprints are mapping noise
MAX_HEIGHT = 1000.0       # m: taller tags are typos (the tallest building is 828 m)
PASSAGE_MARGIN = 0.5      # m of clearance beside a drivable lane that passes through a building
GROUND_NEIGHBOURS = 8     # road-surface vertices nearest to a building whose lowest is its ground
_NUMBER = re.compile(r"^\s*([-+]?\d+(?:[.,]\d+)?)\s*(m|ft|'|)\s*$")


@dataclass(frozen=True)
class Footprint:
    source: str                          # "osm way 4711" / "osm relation 12"
    tags: dict
    rings: tuple[tuple[np.ndarray, str], ...]  # ((lon, lat) (n, 2) array, "outer" | "inner")


def parse_length(text: str | None) -> float | None:
    """Metres from an OSM length tag ("12", "12.5 m", "40 ft", "40'"), None when unreadable."""
    if text is None:
        return None
    match = _NUMBER.match(text)
    if not match:
        return None
    value = float(match.group(1).replace(",", "."))
    return value * 0.3048 if match.group(2) in ("ft", "'") else value


def _number(text: str | None) -> float | None:
    try:
        return float(text) if text is not None else None
    except ValueError:
        return None


def vertical_extent(tags: dict) -> tuple[float, float] | None:
    """(bottom, top) above the ground in metres, or None when the building gets no solid."""
    kind = tags.get("building", "yes")
    layer = _number(tags.get("layer"))
    if kind == "no" or tags.get("location") == "underground" or (layer is not None and layer < 0):
        return None
    top = parse_length(tags.get("height"))
    if top is None:
        levels = _number(tags.get("building:levels"))
        if levels is not None and levels >= 0:
            top = (levels + max(0.0, _number(tags.get("roof:levels")) or 0.0)) * LEVEL_HEIGHT
    bottom = parse_length(tags.get("min_height"))
    if bottom is None:
        min_level = _number(tags.get("building:min_level"))
        bottom = min_level * LEVEL_HEIGHT if min_level is not None and min_level > 0 else None
    if bottom is None and kind in OVERHEAD:
        bottom = OVERHEAD_CLEARANCE
        if top is None or top <= bottom:
            top = bottom + OVERHEAD_THICKNESS
    if top is None or top <= 0:
        top = DEFAULT_HEIGHT
    bottom = -FOUNDATION if bottom is None or bottom <= 0 else min(bottom, MAX_HEIGHT)
    top = min(top, MAX_HEIGHT)
    return (bottom, top) if top > bottom else None


def read_footprints(osm_path: Path) -> list[Footprint]:
    """Building footprints of an OSM file (lon/lat rings), in file order."""
    import osmium

    from tavf_mapkit.osm.files import osmium_errors

    path = str(osm_path)
    relations, wanted = [], set()
    with osmium_errors(osm_path):
        for relation in osmium.FileProcessor(path, osmium.osm.RELATION):
            tags = dict(relation.tags)
            if tags.get("type") == "multipolygon" and "building" in tags:
                members = [(m.ref, m.role or "outer") for m in relation.members if m.type == "w"]
                relations.append((relation.id, tags, members))
                wanted.update(ref for ref, _ in members)
        ways = {}  # id -> (tags or None, node ids)
        for way in osmium.FileProcessor(path, osmium.osm.WAY):
            is_building = "building" in way.tags
            if is_building or way.id in wanted:
                ways[way.id] = (dict(way.tags) if is_building else None, [node.ref for node in way.nodes])
        needed = {ref for _, refs in ways.values() for ref in refs}
        ids, lonlat = [], []
        if needed:
            # node ids may be negative or unsorted (editors, extracts): a plain lookup, not osmium's
            # location index or IdFilter, which both take unsigned ids
            for node in osmium.FileProcessor(path, osmium.osm.NODE):
                if node.id in needed and node.location.valid():
                    ids.append(node.id)
                    lonlat.append((node.location.lon, node.location.lat))
    ids = np.asarray(ids, dtype=np.int64)
    order = np.argsort(ids)
    ids, lonlat = ids[order], np.asarray(lonlat, dtype=float).reshape(-1, 2)[order]

    def coordinates(refs):
        refs = np.asarray(refs, dtype=np.int64)
        at = np.clip(np.searchsorted(ids, refs), 0, max(len(ids) - 1, 0))
        if not len(ids) or not np.array_equal(ids[at], refs):
            return None  # a node outside the extract: the ring is incomplete
        return lonlat[at]

    footprints, member_lines = [], {}
    for way_id, (tags, refs) in ways.items():
        coords = coordinates(refs)
        if coords is None:
            continue
        if way_id in wanted:
            member_lines[way_id] = coords
        if tags is not None and len(refs) >= 4 and refs[0] == refs[-1]:
            footprints.append(Footprint(f"osm way {way_id}", tags, ((coords, "outer"),)))
    for relation_id, tags, members in relations:
        rings = tuple((member_lines[ref], "inner" if role == "inner" else "outer")
                      for ref, role in members if ref in member_lines)
        if rings:
            footprints.append(Footprint(f"osm relation {relation_id}", tags, rings))
    return footprints


def footprint_polygons(footprint: Footprint, to_local):
    """Valid shapely polygons of a footprint in local coordinates (member ways joined into rings)."""
    from shapely.ops import linemerge

    lines = {"outer": [], "inner": []}
    for coords, role in footprint.rings:
        x, y = to_local(coords[:, 0], coords[:, 1])
        lines[role].append(shapely.LineString(np.column_stack([x, y])))

    def area(role):
        if not lines[role]:
            return shapely.Polygon()
        merged = linemerge(lines[role]) if len(lines[role]) > 1 else lines[role][0]
        parts = shapely.get_parts(shapely.polygonize(shapely.get_parts(merged)))
        return shapely.union_all([shapely.make_valid(part) for part in parts])

    shape = shapely.make_valid(area("outer").difference(area("inner")))
    return [p for p in shapely.get_parts(shape) if p.geom_type == "Polygon" and p.area >= MIN_AREA]


def building_solids(odr, surface, osm_path: Path | None) -> tuple[list[Solid], list[str]]:
    """Extruded OSM buildings; empty when there is no OSM input or no georeference to place it."""
    from tavf_mapkit.mesh.swept_path import centre_pieces

    if osm_path is None:
        return [], []
    if odr.georeference is None:
        return [], [f"{osm_path}: no geoReference in the OpenDRIVE, buildings cannot be placed"]
    parts, skipped = building_parts(odr, osm_path)
    ground = ground_heights(surface)
    solids = []
    pieces = centre_pieces(odr) if parts else None
    for _, where, polygon, extent in passage_pieces(parts, surface, pieces=pieces):
        try:
            solids.append(extrude_building(polygon, extent, ground, where))
        except SolidError as error:
            skipped.append(f"{where}: {error}")
    return solids, skipped


def building_parts(odr, osm_path: Path) -> tuple[list[tuple], list[str]]:
    """(source, polygon, (bottom, top)) of every building part of an OSM file in local coordinates, in file
    order, and a line for every footprint that gives none."""
    parts, skipped = [], []
    for footprint in read_footprints(Path(osm_path)):
        extent = vertical_extent(footprint.tags)
        if extent is None:
            skipped.append(f"{footprint.source}: underground or building=no")
            continue
        try:
            polygons = footprint_polygons(footprint, odr.georeference.wgs84_to_local)
        except (ValueError, TypeError) as error:  # shapely refuses broken rings
            skipped.append(f"{footprint.source}: footprint unusable ({error})")
            continue
        if not polygons:
            skipped.append(f"{footprint.source}: footprint encloses no area")
        for k, polygon in enumerate(polygons):
            parts.append((footprint.source if len(polygons) == 1 else f"{footprint.source} part {k}", polygon,
                          extent))
    return parts, skipped


def passage_pieces(parts, surface, numbers=None, pieces: tuple | None = None) -> list[tuple]:
    """(part number, where, polygon, extent) of every piece to extrude: a part that stands where cars drive is
    cut there, and its piece over the lanes starts at OVERHEAD_CLEARANCE -- the road exists in the OpenDRIVE,
    so the building must let it through (a passage, mapped on the street as ``tunnel=building_passage``, or
    a corner that OSM and netconvert's lanes disagree on). Where cars drive: the drivable faces under a part,
    PASSAGE_MARGIN wide, and the swept paths of the driving lanes (``pieces``: ``swept_path.centre_pieces``
    of at least the roads near the parts), which reach beyond a lane's border in a tight turn. Pieces
    sharper than a car follows count at the straight width (``swept_path.followable``): a U-turn connector at
    its capped widening would carve whole rooms out of the buildings beside it. ``numbers``: the parts' own
    numbers (their index in ``parts`` by default)."""
    numbers = list(range(len(parts))) if numbers is None else list(numbers)
    keep_free = _drivable_near(parts, surface)
    for i, areas in _swept_near(parts, pieces).items():
        keep_free[i] = shapely.union_all([keep_free[i], *areas] if i in keep_free else areas)
    out = []
    for i, (number, (where, polygon, (bottom, top))) in enumerate(zip(numbers, parts)):
        if i not in keep_free:
            out.append((number, where, polygon, (bottom, top)))
            continue
        free = keep_free[i]
        ground_parts = shapely.get_parts(shapely.make_valid(polygon.difference(free)))
        over_parts = shapely.get_parts(shapely.make_valid(polygon.intersection(free)))
        cut = [(p, (bottom, top), "") for p in ground_parts]
        over_bottom = bottom if bottom > 0 else OVERHEAD_CLEARANCE
        if top > over_bottom:
            cut += [(p, (over_bottom, top), " over the road") for p in over_parts]
        k = 0
        for piece, extent, note in cut:
            if piece.geom_type == "Polygon" and piece.area >= MIN_AREA:
                out.append((number, f"{where} passage {k}{note}", piece, extent))
                k += 1
    return out


def _drivable_near(parts, surface) -> dict:
    """{part index: the drivable faces it stands on, grown by PASSAGE_MARGIN} for the parts on any."""
    from tavf_mapkit.mesh.kinds import DRIVABLE_KINDS
    from tavf_mapkit.mesh.labelled import KIND_CODE

    if surface is None or not parts or not len(surface.faces):
        return {}
    drivable = np.isin(surface.kind, [KIND_CODE[k] for k in DRIVABLE_KINDS])
    triangles = shapely.polygons(surface.vertices[surface.faces[drivable]][:, :, :2])
    triangles = triangles[shapely.area(triangles) > 1e-9]
    tree = shapely.STRtree([polygon for _, polygon, _ in parts])
    part_index, triangle_index = tree.query(triangles, predicate="intersects")[::-1]
    return {i: shapely.union_all(triangles[triangle_index[part_index == i]]).buffer(PASSAGE_MARGIN)
            for i in np.unique(part_index).tolist()}


def _swept_near(parts, pieces: tuple | None) -> dict:
    """{part index: the swept areas (``swept_path.swept_areas``) that overlap it, in the lanes' order} for the
    parts any overlaps. Only the overlapping ones, so that the cut does not depend on which other lanes
    were passed."""
    from tavf_mapkit.mesh.swept_path import followable, swept_areas

    if pieces is None or not parts or not len(pieces[0]):
        return {}
    lines, width = pieces[0], followable(pieces[1])
    polygons = np.array([polygon for _, polygon, _ in parts], dtype=object)
    tree = shapely.STRtree(lines)
    part_index, piece = tree.query(polygons, predicate="dwithin", distance=float(width.max()))
    if not len(piece):
        return {}
    hit, at = np.unique(piece, return_inverse=True)
    areas = swept_areas(lines[hit], width[hit])
    overlaps = shapely.intersects(polygons[part_index], areas[at])
    part_index, piece, at = part_index[overlaps], piece[overlaps], at[overlaps]
    order = np.lexsort((piece, part_index))
    part_index, at = part_index[order], at[order]
    if not len(part_index):
        return {}
    starts = np.flatnonzero(np.r_[True, part_index[1:] != part_index[:-1]])
    ends = np.r_[starts[1:], len(part_index)]
    return {int(part_index[s]): list(areas[at[s:e]]) for s, e in zip(starts, ends)}


def ground_point(polygon) -> np.ndarray:
    """The plan point of a building piece whose ground height it stands on (its representative point)."""
    centre = polygon.representative_point()
    return np.array([centre.x, centre.y])


def ground_heights(surface, reach: int = GROUND_NEIGHBOURS):
    """z of the ground near (x, y): lowest of the ``reach`` nearest road-surface vertices (0 without a surface)."""
    if surface is None or not len(surface.vertices):
        return lambda x, y: 0.0
    from scipy.spatial import cKDTree

    tree = cKDTree(surface.vertices[:, :2])
    z = surface.vertices[:, 2]

    def at(x, y):
        _, index = tree.query([x, y], k=min(reach, len(z)))
        return float(np.min(z[np.atleast_1d(index)]))

    return at


def extrude_building(polygon, extent, ground, where) -> Solid:
    """The solid of one building piece standing on ``ground(x, y)`` at its ``ground_point``."""
    bottom, top = extent
    point = ground_point(polygon)
    anchor = np.array([point[0], point[1], ground(point[0], point[1])])
    contours = [np.asarray(polygon.exterior.coords)[:-1, :2] - anchor[:2]]
    contours += [np.asarray(ring.coords)[:-1, :2] - anchor[:2] for ring in polygon.interiors]
    section = manifold3d.CrossSection(contours, manifold3d.FillRule.EvenOdd)
    if section.is_empty():
        raise SolidError("footprint encloses no area")
    solid = manifold3d.Manifold.extrude(section, top - bottom).translate([0.0, 0.0, bottom])
    return to_solid(solid, "building", where, anchor)
