"""Map projections the build passes to netconvert, and the georeference netconvert writes back.

Default: a transverse Mercator centred on the data. CARLA reads only ``+lat_0``/``+lon_0`` of an
OpenDRIVE geoReference and assumes the map origin sits there, and a centred projection keeps the local
coordinates small (metres from the centre instead of 5,900,000 m of UTM northing).
"""

from __future__ import annotations

import re
from pathlib import Path

_PARAMETER = re.compile(r"\+([A-Za-z_0-9]+)(?:=(\S+))?")


def tmerc_centred_on(lon: float, lat: float) -> str:
    """PROJ string of a transverse Mercator (scale 1, WGS84) whose origin is (lon, lat), 7 decimals."""
    return (f"+proj=tmerc +lat_0={_decimal(lat)} +lon_0={_decimal(lon)} +k=1 +x_0=0 +y_0=0 "
            "+ellps=WGS84 +units=m +no_defs")


def proj_parameters(text: str) -> dict[str, str | None]:
    """``{"proj": "utm", "zone": "32", ...}`` of a PROJ string."""
    return {key: value for key, value in _PARAMETER.findall(text or "")}


def as_tmerc(proj: str) -> str:
    """The same projection written as +proj=tmerc with explicit +lat_0/+lon_0, where that is exact.

    UTM zone z is a transverse Mercator with lat_0=0, lon_0=6z-183, k=0.9996, x_0=500000 (y_0=10000000
    south of the equator). Writing it that way keeps every coordinate valid and lets readers that look
    only for +lat_0/+lon_0 find them. Other projections are returned unchanged.
    """
    parameters = proj_parameters(proj)
    if parameters.get("proj") != "utm" or not (parameters.get("zone") or "").isdigit():
        return proj
    zone = int(parameters["zone"])
    false_northing = 10000000 if "south" in parameters else 0
    datum = f" +datum={parameters['datum']}" if parameters.get("datum") else ""
    ellps = parameters.get("ellps") or "WGS84"
    return (f"+proj=tmerc +lat_0=0 +lon_0={6 * zone - 183} +k=0.9996 +x_0=500000 +y_0={false_northing} "
            f"+ellps={ellps}{datum} +units=m +no_defs")


def read_xodr_georeference(path: str | Path) -> dict:
    """``{"proj": str | None, "offset": {"x","y","z","hdg"} | None}`` from an OpenDRIVE header.

    Reads only up to the end of <header>, so it costs the same on a 100 MB file as on a small one.
    """
    from lxml import etree

    proj, offset = None, None
    context = etree.iterparse(str(path), events=("end",), resolve_entities=False, no_network=True,
                              load_dtd=False, huge_tree=True)
    for _event, element in context:
        if element.tag == "geoReference":
            proj = " ".join((element.text or "").split()) or None
        elif element.tag == "offset" and element.getparent() is not None \
                and element.getparent().tag == "header":
            offset = {key: float(element.get(key, 0.0)) for key in ("x", "y", "z", "hdg")}
        elif element.tag == "header":
            break
    return {"proj": proj, "offset": offset}


def describe_georeference(georeference: dict) -> dict:
    """Add what a reader checks: does PROJ accept it, and what are +lat_0/+lon_0."""
    proj = georeference.get("proj")
    result = dict(georeference)
    parameters = proj_parameters(proj or "")
    result["lat_0"] = _float_or_none(parameters.get("lat_0"))
    result["lon_0"] = _float_or_none(parameters.get("lon_0"))
    result["crs_valid"] = False
    if proj:
        import pyproj

        try:
            pyproj.CRS.from_user_input(proj)
            result["crs_valid"] = True
        except pyproj.exceptions.CRSError:
            pass
    return result


def _decimal(value: float) -> str:
    text = f"{round(value, 7):.7f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _float_or_none(text: str | None) -> float | None:
    try:
        return float(text) if text is not None else None
    except ValueError:
        return None
