"""Lanelet2 export: an OpenDRIVE map as a Lanelet2 OSM file (``mapkit export MAP.xodr --to lanelet2 -o
map.osm``).

    >>> from tavf_mapkit.lanelet2_export import export_lanelet2
    >>> summary = export_lanelet2(odr, "map.osm")          # {"lanelets": ..., "origin": (lat, lon), ...}

Every node carries the WGS84 position of its local point through the map's georeference. The origin to give
Lanelet2's projector is the WGS84 position of the local origin (0, 0): for our builds the
``+lat_0``/``+lon_0`` of the transverse Mercator. ``LocalCartesianProjector(Origin(lat, lon))`` then gives
back local coordinates close to the OpenDRIVE ones (a tangent plane instead of the transverse Mercator: they
part by millimetres within a few km of the origin); ``UtmProjector(Origin(lat, lon))`` gives UTM coordinates
relative to the origin's. See docs/export.md.
"""

from __future__ import annotations

import sys

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.lanelet2_export.laneletmap import LaneletMap, build_lanelet_map
from tavf_mapkit.lanelet2_export.osmxml import osm_chunks

__all__ = ["LaneletMap", "build_lanelet_map", "export_lanelet2", "map_georeference"]


def map_georeference(odr, origin: tuple[float, float] | None = None, name: str | None = None):
    """The georeference nodes are placed with: the map's own, or for a map without one a transverse Mercator
    whose local (0, 0) is ``origin`` (lat, lon)."""
    from tavf_mapkit.opendrive.georef import GeoReference
    from tavf_mapkit.projection import tmerc_centred_on

    if odr.georeference is not None:
        if origin is not None:
            raise InputError("has a <geoReference>; --origin is only for maps without one", file=name)
        return odr.georeference
    if origin is None:
        raise InputError(
            "has no <geoReference>: give --origin LAT,LON to place its local (0, 0) on the earth", file=name
        )
    lat, lon = origin
    return GeoReference(tmerc_centred_on(lon, lat))


def export_lanelet2(
    odr,
    output: str,
    *,
    eps: float = 0.01,
    step: float | None = None,
    origin: tuple[float, float] | None = None,
    name: str | None = None,
) -> dict:
    """Write the Lanelet2 OSM file (atomically; ``-`` for standard output) and return what it holds."""
    georeference = map_georeference(odr, origin, name)
    laneletmap = build_lanelet_map(odr, eps=eps, step=step)
    lon0, lat0 = (float(v) for v in np.ravel(georeference.local_to_wgs84(np.zeros(1), np.zeros(1))))
    if not (np.isfinite(lat0) and np.isfinite(lon0)):
        raise InputError(
            "the georeference does not place the local origin on the earth", file=name, element="geoReference"
        )
    lon, lat = georeference.local_to_wgs84(laneletmap.nodes[:, 0], laneletmap.nodes[:, 1])
    lon, lat = np.asarray(lon, dtype=float), np.asarray(lat, dtype=float)
    if not (np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))):
        raise InputError(
            "some points do not convert to WGS84 through the georeference", file=name, element="geoReference"
        )
    comment = (
        f"Lanelet2 map exported by tavf-mapkit from {name or 'an OpenDRIVE map'}. Origin (local 0, 0): "
        f"lat {lat0:.10f}, lon {lon0:.10f}; load with lanelet2.io.load(path, "
        f"lanelet2.projection.LocalCartesianProjector(lanelet2.io.Origin({lat0:.10f}, {lon0:.10f}))) "
        f"or UtmProjector with the same origin. Projection: {georeference.text}"
    )
    chunks = osm_chunks(laneletmap, lon, lat, comment)  # written as formatted: a region's file is gigabytes
    if output == "-":
        sys.stdout.writelines(chunks)
    else:
        from tavf_mapkit.fileutil import staged_file

        with staged_file(output) as temporary, open(temporary, "w", encoding="utf-8") as handle:
            handle.writelines(chunks)
    return {
        "lanelets": len(laneletmap.lanelets),
        "ways": len(laneletmap.way_nodes),
        "nodes": len(laneletmap.nodes),
        "regulatory_elements": len(laneletmap.regulatory),
        "origin": (lat0, lon0),
        "max_deviation_m": laneletmap.max_deviation,
        "unjoined_lane_ends": laneletmap.unjoined,
        "narrow_lanes_left_out": laneletmap.narrow,
        "private_bounds": laneletmap.private_bounds,
        "turned": laneletmap.turned,
    }
