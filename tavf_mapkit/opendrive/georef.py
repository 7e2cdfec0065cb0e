"""Georeference: the header's PROJ string and <offset>, local <-> projected <-> WGS84 <-> any CRS.

Sign convention of <offset> (ASAM OpenDRIVE 1.6+): the offset is the position and heading of the local
frame's origin in the projected CRS, so projected = offset.xy + R(offset.hdg) * local. netconvert writes
the negated SUMO netOffset there, which makes this agree with sumolib's convertXY2LonLat (tested).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.header import Offset

_WGS84 = pyproj.CRS.from_epsg(4326)
_PARAM = re.compile(r"\+([A-Za-z_0-9]+)(?:=(\S+))?")


def proj_parameters(text: str) -> dict[str, str | None]:
    """``{"proj": "utm", "zone": "32", ...}`` of a PROJ string (empty for EPSG codes or WKT)."""
    return {key: value for key, value in _PARAM.findall(text)}


def normalise_proj_text(text: str) -> str:
    """The geoReference text as PROJ accepts it: CARLA-style '+lat_0/+lon_0 only' means a transverse Mercator."""
    text = " ".join(text.split())
    if text.lower().startswith("epsg:"):
        return text.upper()
    parameters = proj_parameters(text)
    if parameters and "proj" not in parameters and "init" not in parameters:
        if "lat_0" in parameters and "lon_0" in parameters:
            return (f"+proj=tmerc +lat_0={parameters['lat_0']} +lon_0={parameters['lon_0']} +k=1 +x_0=0 +y_0=0 "
                    "+ellps=WGS84 +units=m +no_defs")
    # grids that are not installed would make PROJ fail; horizontal positions never need them
    return re.sub(r"\+geoidgrids=\S+\s*", "", text).strip()


@dataclass(frozen=True, eq=False)
class GeoReference:
    """A parsed geoReference plus offset; methods take and return numpy arrays."""

    text: str
    offset: Offset | None = None

    @cached_property
    def crs(self) -> pyproj.CRS:
        try:
            return pyproj.CRS.from_user_input(normalise_proj_text(self.text))
        except CRSError as error:
            raise InputError(f"geoReference is not a valid PROJ/EPSG definition: {error}",
                             element="geoReference") from None

    @cached_property
    def _to_wgs84(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_crs(self.crs, _WGS84, always_xy=True)

    @cached_property
    def _from_wgs84(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_crs(_WGS84, self.crs, always_xy=True)

    @property
    def parameters(self) -> dict[str, str | None]:
        return proj_parameters(self.text)

    def local_to_projected(self, x, y):
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        if self.offset is None:
            return x, y
        c, s = math.cos(self.offset.hdg), math.sin(self.offset.hdg)
        return self.offset.x + c * x - s * y, self.offset.y + s * x + c * y

    def projected_to_local(self, px, py):
        px, py = np.asarray(px, dtype=float), np.asarray(py, dtype=float)
        if self.offset is None:
            return px, py
        dx, dy = px - self.offset.x, py - self.offset.y
        c, s = math.cos(self.offset.hdg), math.sin(self.offset.hdg)
        return c * dx + s * dy, -s * dx + c * dy

    def local_to_wgs84(self, x, y):
        """(lon, lat) in degrees."""
        px, py = self.local_to_projected(x, y)
        return self._to_wgs84.transform(px, py)

    def wgs84_to_local(self, lon, lat):
        px, py = self._from_wgs84.transform(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float))
        return self.projected_to_local(px, py)

    def local_to_crs(self, x, y, crs) -> tuple[np.ndarray, np.ndarray]:
        px, py = self.local_to_projected(x, y)
        transformer = pyproj.Transformer.from_crs(self.crs, pyproj.CRS.from_user_input(crs), always_xy=True)
        return transformer.transform(px, py)

    def plausibility(self, local_bounds: tuple[float, float, float, float] | None) -> list[str]:
        """Problems that make positions wrong even though PROJ accepts the definition (empty when plausible)."""
        problems = []
        parameters = self.parameters
        try:
            crs = self.crs
        except InputError as error:
            return [error.message]
        if parameters.get("proj") == "utm" and parameters.get("zone"):
            try:
                zone = int(parameters["zone"])
            except ValueError:
                zone = None
            if zone is not None and parameters.get("lon_0"):
                lon_0 = float(parameters["lon_0"])
                west = -180.0 + 6.0 * (zone - 1)
                if not west - 3.0 <= lon_0 <= west + 9.0:
                    problems.append(
                        f"+proj=utm +zone={zone} covers longitudes {west:g}..{west + 6:g}, but +lon_0={lon_0:g} "
                        "lies elsewhere; PROJ ignores +lat_0/+lon_0 for UTM, so the file contradicts itself")
        if local_bounds is not None:
            west_x, south_y, east_x, north_y = local_bounds
            xs = np.array([west_x, east_x, east_x, west_x])
            ys = np.array([south_y, south_y, north_y, north_y])
            lon, lat = self.local_to_wgs84(xs, ys)
            if not (np.all(np.isfinite(lon)) and np.all(np.isfinite(lat))):
                problems.append("map bounds do not convert to WGS84 (outside the projection's domain)")
            elif np.any(np.abs(lat) > 90) or np.any(np.abs(lon) > 180):
                problems.append("map bounds convert to impossible WGS84 coordinates")
            else:
                area = crs.area_of_use
                if area is not None:
                    margin = 1.0
                    inside = ((lon >= area.west - margin) & (lon <= area.east + margin)
                              & (lat >= area.south - margin) & (lat <= area.north + margin))
                    if not np.all(inside):
                        problems.append(
                            f"map bounds (lon {lon.min():.4f}..{lon.max():.4f}, lat {lat.min():.4f}..{lat.max():.4f}) "
                            f"lie outside the CRS's area of use ({area.name})")
                elif parameters.get("proj") == "utm" and parameters.get("zone", "").isdigit():
                    zone_west = -180.0 + 6.0 * (int(parameters["zone"]) - 1)
                    if np.any(lon < zone_west - 3.0) or np.any(lon > zone_west + 9.0):
                        problems.append(f"map bounds (lon {lon.min():.4f}..{lon.max():.4f}) lie far outside "
                                        f"UTM zone {parameters['zone']}")
        return problems

    def carla_readable(self) -> bool:
        """CARLA reads only +lat_0 and +lon_0 from the geoReference and ignores +proj, zones and <offset>."""
        parameters = self.parameters
        no_offset = self.offset is None or (self.offset.x, self.offset.y, self.offset.hdg) == (0.0, 0.0, 0.0)
        return "lat_0" in parameters and "lon_0" in parameters and no_offset
