"""Georeference rules: present, parseable by PROJ, plausible (no contradictions), readable by CARLA.

What a single file cannot reveal: a consistent georeference that puts the whole map a few metres off, or
rotated by a degree, looks exactly like a correct one. Those errors need a reference: ``mapkit compare``.
"""

from __future__ import annotations

import warnings

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.validate.finding import ERROR, INFO, WARNING, Hit
from tavf_mapkit.validate.registry import rule

_DEGREES_PER_METRE = 1.0 / 111_000.0


def _georeference(ctx):
    return ctx.odr.georeference


def _bounds(ctx):
    cache = ctx.notes.setdefault("_bounds", {})
    if "value" not in cache:
        cache["value"] = ctx.odr.bounds(step=2.0) if ctx.odr.roads else None
    return cache["value"]


def _crs_or_none(geo):
    try:
        return geo.crs
    except InputError:
        return None


def _projection(geo) -> str | None:
    """The PROJ method name (``utm``, ``tmerc``, ...) also for EPSG codes and WKT."""
    try:
        with warnings.catch_warnings():  # "you will lose information converting to PROJ": we want one name only
            warnings.simplefilter("ignore", UserWarning)
            return geo.crs.to_dict().get("proj")
    except (InputError, ValueError):
        return None


def _header_line(ctx):
    return ctx.odr.header.line


@rule("georeference.missing", WARNING,
      summary="The header has a <geoReference>.",
      why="Without it the map cannot be placed on Earth: no GNSS matching, no comparison with other maps, no "
          "UDM positions.")
def missing(ctx, rule):
    if ctx.odr.georeference is None:
        yield Hit("no <geoReference>: positions cannot be placed on Earth", line=_header_line(ctx))


@rule("georeference.proj", ERROR,
      summary="The geoReference is a definition PROJ accepts (PROJ string, EPSG code or WKT).",
      why="A definition PROJ rejects places the map nowhere; tools disagree on what the author meant.")
def proj(ctx, rule):
    geo = _georeference(ctx)
    if geo is None:
        return
    try:
        _ = geo.crs
    except InputError as error:
        yield Hit(error.message, line=_header_line(ctx))


def _utm_latitude_contradiction(geo, bounds) -> str | None:
    """PROJ ignores +lat_0 for UTM (latitude origin is the equator); a far-off +lat_0 shows the author meant
    something else, as in files written for readers that take +lat_0/+lon_0 as the origin (CARLA)."""
    parameters = geo.parameters
    if _projection(geo) != "utm" or not parameters.get("lat_0") or bounds is None:
        return None
    try:
        lat_0 = float(parameters["lat_0"])
    except ValueError:
        return None
    _, lat = geo.local_to_wgs84(np.array([(bounds[0] + bounds[2]) / 2]), np.array([(bounds[1] + bounds[3]) / 2]))
    if not np.isfinite(lat[0]) or abs(lat[0] - lat_0) <= 1.0:
        return None
    return (f"+proj=utm ignores +lat_0={lat_0:g}: PROJ puts the map at latitude {lat[0]:.4f}, while +lat_0 says "
            f"{lat_0:g} (readers that use +lat_0/+lon_0 as the origin, like CARLA, put it there)")


def _utm_easting_problem(geo, bounds) -> str | None:
    """UTM eastings lie within about 160-840 km (false easting 500 km, zones 6 degrees wide); local coordinates
    used as eastings mean the <offset> is missing or wrong, even when the longitude still looks plausible."""
    if _projection(geo) != "utm" or bounds is None:
        return None
    easting, _ = geo.local_to_projected(np.array([bounds[0], bounds[2]]), np.array([bounds[1], bounds[3]]))
    if np.all((easting > 100_000.0) & (easting < 900_000.0)):
        return None
    return (f"UTM eastings of the map are {easting.min():.0f}..{easting.max():.0f} m, but UTM eastings lie within "
            "about 160 000..840 000 m: the <offset> is missing or wrong")


@rule("georeference.plausible", ERROR,
      summary="The georeference does not contradict itself or the map: the map's bounds lie inside the CRS's "
              "area of use, a UTM zone contains +lon_0, UTM eastings are real eastings (an <offset> is not "
              "missing), a UTM +lat_0 agrees with where PROJ puts the map.",
      why="A contradictory georeference puts the map in different places in different tools (often thousands of "
          "kilometres apart), which is how maps silently end up in the wrong place.")
def plausible(ctx, rule):
    geo = _georeference(ctx)
    if geo is None or _crs_or_none(geo) is None:
        return
    bounds = _bounds(ctx)
    for problem in geo.plausibility(bounds):
        yield Hit(problem, line=_header_line(ctx))
    for problem in (_utm_easting_problem(geo, bounds), _utm_latitude_contradiction(geo, bounds)):
        if problem:
            yield Hit(problem, line=_header_line(ctx))


def _box_mismatch(declared, actual) -> float:
    return float(np.max(np.abs(np.asarray(declared) - np.asarray(actual))))


@rule("georeference.header-bounds", WARNING, tolerance=25.0, unit="m",
      summary="The header's west/south/east/north agree with the map's extent, read as local, projected or WGS84 "
              "coordinates (skipped when all four are 0 or absent).",
      why="Consumers use the header box to place and tile the map; a box that fits nothing means the geometry or "
          "the georeference was changed without the other (e.g. a map moved in one tool).")
def header_bounds(ctx, rule):
    header = ctx.odr.header
    declared = (header.west, header.south, header.east, header.north)
    if not any(declared) or not all(k in header.attrib for k in ("north", "south", "east", "west")):
        return
    bounds = _bounds(ctx)
    if bounds is None:
        return
    candidates = {"local": (_box_mismatch(declared, bounds), rule.tolerance)}
    geo = _georeference(ctx)
    if geo is not None and _crs_or_none(geo) is not None:
        xs, ys = np.array([bounds[0], bounds[2]]), np.array([bounds[1], bounds[3]])
        px, py = geo.local_to_projected(xs, ys)
        candidates["projected"] = (_box_mismatch(declared, (px[0], py[0], px[1], py[1])), rule.tolerance)
        corners_x = np.array([bounds[0], bounds[2], bounds[2], bounds[0]])
        corners_y = np.array([bounds[1], bounds[1], bounds[3], bounds[3]])
        lon, lat = geo.local_to_wgs84(corners_x, corners_y)
        if np.all(np.isfinite(lon)) and np.all(np.isfinite(lat)):
            box = (lon.min(), lat.min(), lon.max(), lat.max())
            candidates["WGS84"] = (_box_mismatch(declared, box), rule.tolerance * _DEGREES_PER_METRE)
    if any(mismatch <= tolerance for mismatch, tolerance in candidates.values()):
        return
    local = candidates["local"][0]
    yield Hit(f"header bounds (west {header.west:g}, south {header.south:g}, east {header.east:g}, north "
              f"{header.north:g}) fit neither the map's local extent (west {bounds[0]:.2f}, south {bounds[1]:.2f}, "
              f"east {bounds[2]:.2f}, north {bounds[3]:.2f}; off by up to {local:.1f} m) nor its projected or "
              "WGS84 extent", line=_header_line(ctx))


@rule("georeference.carla", INFO,
      summary="CARLA can read the georeference (only +lat_0/+lon_0, no <offset>).",
      why="CARLA ignores +proj, zones and <offset>: such maps appear at the wrong place in CARLA (a note, since "
          "the file itself is fine).")
def carla(ctx, rule):
    geo = _georeference(ctx)
    if geo is None or _crs_or_none(geo) is None:
        return
    if not geo.carla_readable():
        yield Hit("CARLA reads only +lat_0/+lon_0 and ignores +proj and <offset>; it will misplace this map "
                  "(mapkit build writes a CARLA-readable transverse Mercator)", line=_header_line(ctx))
