"""Cut an area out of an OSM file with complete ways, or re-write a whole file, through osmium.

Every OSM input of a build passes through here before netconvert sees it: osmium's reader refuses XML
entity declarations and writes plain OSM XML back, so a hostile document never reaches netconvert's parser.

Strategy "complete ways" (as ``osmium extract -s complete_ways``): a way with at least one node in the area
is kept with all its nodes, so roads that cross the boundary keep their full geometry and netconvert sees
no dangling references. Relations are kept when they reference a kept node or way and are of a type
netconvert reads: turn restrictions always, route relations (bus and tram lines) on request.
"""

from __future__ import annotations

from array import array
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.fileutil import staged_file
from tavf_mapkit.osm.area import Area
from tavf_mapkit.osm.files import OSM_SUFFIXES, osmium_errors, require_osm_name, require_readable
from tavf_mapkit.osm.summary import ExtractSummary

GENERATOR = "tavf-mapkit extract (osmium)"


def extract(source: str | Path, target: str | Path, area: Area | None = None, *,
            routes: bool = False) -> ExtractSummary:
    """Write the part of ``source`` inside ``area`` (everything if None) to ``target``; return its counts.

    The format of both files follows their names (.osm, .osm.pbf, .osm.gz, .osm.bz2). ``target`` is
    written under a temporary name and renamed, so it is either complete or absent.
    """
    import osmium

    source, target = Path(source), Path(target)
    require_osm_name(source)
    require_osm_name(target, "output")
    require_readable(source)
    if target.exists() and target.resolve() == source.resolve():
        raise InputError("output would overwrite the input", file=str(target))
    if not target.parent.is_dir():
        raise InputError("cannot write: the output's folder does not exist", file=str(target))

    if area is None:
        selection = None
    else:
        with osmium_errors(source):
            selection = _select(source, area, routes)

    summary = ExtractSummary(output=str(target), area=area.to_dict() if area else None)
    header = osmium.io.Header()
    header.set("generator", GENERATOR)
    if area is not None:
        west, south, east, north = area.bbox
        header.add_box(osmium.osm.Box(osmium.osm.Location(west, south), osmium.osm.Location(east, north)))
    try:
        # osmium picks the format by the file's name: the temporary one ends like the target
        with staged_file(target, suffix=_suffix(target)) as partial:
            try:
                writer = osmium.SimpleWriter(str(partial), header=header, overwrite=True)
            except RuntimeError as error:
                raise InputError(f"cannot write: {error}", file=str(target)) from None
            try:
                with osmium_errors(source):
                    _write(source, writer, selection, summary)
            finally:
                writer.close()
            if summary.ways == 0:
                raise InputError(_empty_message(source, area, summary, selection), file=str(source))
    except OSError as error:
        raise InputError(f"cannot write: {error.strerror or error}", file=str(target)) from None
    return summary


class _Selection:
    """Ids to keep, and what the area test saw (for a helpful message when nothing is inside)."""

    def __init__(self) -> None:
        self.nodes: set[int] = set()
        self.ways: set[int] = set()
        self.relations: set[int] = set()
        self.nodes_read = 0
        self.nodes_inside = 0
        self.file_bbox: tuple[float, float, float, float] | None = None


def _select(source: Path, area: Area, routes: bool) -> _Selection:
    """Three reading passes: nodes inside the area, ways touching them, relations touching those."""
    import osmium
    from osmium.osm import NODE, RELATION, WAY

    selection = _Selection()
    ids, lons, lats = array("q"), array("d"), array("d")
    for node in osmium.FileProcessor(str(source), NODE):
        location = node.location
        if location.valid():
            ids.append(node.id)
            lons.append(location.lon)
            lats.append(location.lat)
    ids_np = np.frombuffer(ids, dtype=np.int64) if ids else np.empty(0, np.int64)
    lon_np = np.frombuffer(lons, dtype=np.float64) if lons else np.empty(0)
    lat_np = np.frombuffer(lats, dtype=np.float64) if lats else np.empty(0)
    inside = set(ids_np[area.contains(lon_np, lat_np)].tolist())
    selection.nodes_read, selection.nodes_inside = len(ids_np), len(inside)
    if len(ids_np):
        selection.file_bbox = (float(lon_np.min()), float(lat_np.min()),
                               float(lon_np.max()), float(lat_np.max()))

    selection.nodes = set(inside)
    for way in osmium.FileProcessor(str(source), WAY):
        refs = [node.ref for node in way.nodes]
        if any(ref in inside for ref in refs):
            selection.ways.add(way.id)
            selection.nodes.update(refs)

    wanted = ("restriction", "route") if routes else ("restriction",)
    for relation in osmium.FileProcessor(str(source), RELATION):
        kind = relation.tags.get("type", "")
        if kind.split(":")[0] not in wanted:
            continue
        for member in relation.members:
            kept = selection.nodes if member.type == "n" else selection.ways if member.type == "w" else None
            if kept is not None and member.ref in kept:
                selection.relations.add(relation.id)
                break
    return selection


def _write(source: Path, writer, selection: _Selection | None, summary: ExtractSummary) -> None:
    import osmium

    for obj in osmium.FileProcessor(str(source)):
        if obj.is_node():
            if selection is None or obj.id in selection.nodes:
                writer.add_node(obj)
                summary.count_node(obj)
        elif obj.is_way():
            if selection is None or obj.id in selection.ways:
                writer.add_way(obj)
                summary.count_way(obj)
        elif obj.is_relation() and (selection is None or obj.id in selection.relations):
            writer.add_relation(obj)
            summary.count_relation(obj)


def _empty_message(source: Path, area: Area | None, summary: ExtractSummary,
                   selection: _Selection | None) -> str:
    if area is None:
        return f"the file holds no ways ({summary.nodes} nodes): nothing to build a road network from"
    where = ""
    if selection is not None and selection.file_bbox:
        west, south, east, north = selection.file_bbox
        where = f"; the file's nodes span {west:.5f},{south:.5f},{east:.5f},{north:.5f}"
    return (f"empty extract: no way has a node inside {area.description} "
            f"({selection.nodes_inside if selection else 0} of {selection.nodes_read if selection else 0} "
            f"nodes inside{where}; the order is W,S,E,N)")


def _suffix(path: Path) -> str:
    """The full OSM suffix (".osm.pbf", ".osm.gz", ...) so osmium picks the same writer for the temp name."""
    name = path.name.lower()
    for suffix in sorted(OSM_SUFFIXES, key=len, reverse=True):
        if name.endswith(suffix):
            return path.name[-len(suffix):]
    return path.suffix
