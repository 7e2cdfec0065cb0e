"""SUMO network coordinates <-> the OpenDRIVE local frame of the same build, both ways.

Both files of a build say where their plane lies on Earth:

- ``NAME.net.xml`` ``<location netOffset projParameter>``: net = projected_sumo + netOffset;
- ``NAME.xodr`` ``<geoReference>`` + ``<offset>``: projected_xodr = offset.xy + R(offset.hdg) * local.

When the two projections are the same CRS the mapping is an exact rigid motion (a translation, plus a rotation
if the offset has a heading) and no PROJ call happens on the hot path; otherwise positions go through pyproj
(SUMO CRS -> OpenDRIVE CRS) and headings are turned by the local grid convergence. Nothing is hard-coded: with
netconvert 1.28 the offset is the negated netOffset, so local == net, but a build whose ``<offset>`` was
normalised (local (0,0) at the projection origin) maps just as well.

Headings: the twin uses yaw in radians, counter-clockwise from the local +x axis; SUMO uses an angle in degrees,
clockwise from the net's +y axis ("north" of its plane).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pyproj

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.georef import GeoReference, normalise_proj_text
from tavf_mapkit.opendrive.header import Offset

# A metre is far below the curvature of any map projection's grid, so heading turns are exact to ~1e-9 rad.
_HEADING_PROBE_M = 1.0


@dataclass(frozen=True, eq=False)
class NetFrame:
    """The mapping between one SUMO network's coordinates and one OpenDRIVE file's local frame."""

    net_offset: tuple[float, float]
    net_proj: str  # "!" when the network is not georeferenced
    georef: GeoReference | None  # the xodr's geoReference + offset; None when it has none

    @classmethod
    def from_files(cls, net_path: str | Path, xodr_path: str | Path) -> NetFrame:
        from tavf_mapkit.projection import read_xodr_georeference
        from tavf_mapkit.sumonet import read_location

        location = read_location(net_path)
        header = read_xodr_georeference(xodr_path)
        offset = Offset(**header["offset"]) if header["offset"] else None
        georef = GeoReference(header["proj"], offset) if header["proj"] else None
        if georef is None and offset is not None:
            # an offset without a projection still places the local frame in the (unnamed) projected plane
            georef = GeoReference("", offset)
        frame = cls(tuple(location.net_offset), location.proj, georef)
        frame.check(str(net_path), str(xodr_path))
        return frame

    @classmethod
    def from_build(cls, build_dir: str | Path) -> NetFrame:
        """The frame of a build folder (``NAME.net.xml`` and ``NAME.xodr`` beside ``manifest.json``)."""
        from twin.traffic.buildfiles import build_files

        files = build_files(build_dir)
        return cls.from_files(files.net, files.xodr)

    # --- which path the mapping takes ------------------------------------------------------------------------

    @property
    def net_georeferenced(self) -> bool:
        return bool(self.net_proj) and self.net_proj != "!"

    @property
    def xodr_georeferenced(self) -> bool:
        return self.georef is not None and bool(self.georef.text)

    @cached_property
    def _net_crs(self) -> pyproj.CRS | None:
        if not self.net_georeferenced:
            return None
        try:
            return pyproj.CRS.from_user_input(normalise_proj_text(self.net_proj))
        except pyproj.exceptions.CRSError as error:
            raise InputError(f"projParameter is not a valid PROJ definition: {error}",
                             element="location") from None

    @cached_property
    def exact(self) -> bool:
        """True when both files use the same CRS (or neither has one): the mapping is a rigid motion."""
        if not self.net_georeferenced and not self.xodr_georeferenced:
            return True
        if self.net_georeferenced != self.xodr_georeferenced:
            return False
        return self._net_crs.equals(self.georef.crs, ignore_axis_order=True)

    def check(self, net_name: str = "", xodr_name: str = "") -> None:
        """Refuse a pair of files whose frames cannot be related."""
        if self.net_georeferenced != self.xodr_georeferenced:
            which = (f"the SUMO network {net_name} is georeferenced but the OpenDRIVE file {xodr_name} is not"
                     if self.net_georeferenced else
                     f"the OpenDRIVE file {xodr_name} is georeferenced but the SUMO network {net_name} is not")
            raise InputError(f"cannot relate SUMO and OpenDRIVE coordinates: {which}")
        if self.net_georeferenced:
            _ = self._net_crs, self.georef.crs  # raise InputError now rather than on the first vehicle

    @cached_property
    def _net_to_xodr(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_crs(self._net_crs, self.georef.crs, always_xy=True)

    @cached_property
    def _xodr_to_net(self) -> pyproj.Transformer:
        return pyproj.Transformer.from_crs(self.georef.crs, self._net_crs, always_xy=True)

    def _projected_to_local(self, px, py):
        return (px, py) if self.georef is None else self.georef.projected_to_local(px, py)

    def _local_to_projected(self, x, y):
        return (x, y) if self.georef is None else self.georef.local_to_projected(x, y)

    # --- positions -------------------------------------------------------------------------------------------

    def net_to_local(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """SUMO network (x, y) -> OpenDRIVE local (x, y); arrays or scalars."""
        px = np.asarray(x, dtype=float) - self.net_offset[0]
        py = np.asarray(y, dtype=float) - self.net_offset[1]
        if not self.exact:
            px, py = self._net_to_xodr.transform(px, py)
        return self._projected_to_local(px, py)

    def local_to_net(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """OpenDRIVE local (x, y) -> SUMO network (x, y)."""
        px, py = self._local_to_projected(x, y)
        if not self.exact:
            px, py = self._xodr_to_net.transform(px, py)
        return np.asarray(px) + self.net_offset[0], np.asarray(py) + self.net_offset[1]

    # --- headings --------------------------------------------------------------------------------------------

    @property
    def _offset_hdg(self) -> float:
        return 0.0 if self.georef is None or self.georef.offset is None else self.georef.offset.hdg

    def _grid_turn(self, x, y) -> np.ndarray:
        """Angle (rad, counter-clockwise) by which the net's axes appear turned in the local frame at (x, y)."""
        if self.exact:
            return np.full(np.shape(np.asarray(x, dtype=float)), -self._offset_hdg)
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        lx0, ly0 = self.net_to_local(x, y)
        lx1, ly1 = self.net_to_local(x + _HEADING_PROBE_M, y)
        return np.arctan2(ly1 - ly0, lx1 - lx0)

    def sumo_angle_to_yaw(self, angle_deg, x, y) -> np.ndarray:
        """SUMO angle (deg, clockwise from the net's +y) at net (x, y) -> local yaw (rad, ccw from +x)."""
        yaw_net = np.radians(90.0 - np.asarray(angle_deg, dtype=float))
        return wrap_angle(yaw_net + self._grid_turn(x, y))

    def yaw_to_sumo_angle(self, yaw, x, y) -> np.ndarray:
        """Local yaw (rad) at local (x, y) -> SUMO angle in degrees, in [0, 360)."""
        nx, ny = self.local_to_net(x, y)
        yaw_net = np.asarray(yaw, dtype=float) - self._grid_turn(nx, ny)
        return np.mod(90.0 - np.degrees(yaw_net), 360.0)

    # --- Earth -----------------------------------------------------------------------------------------------

    def local_to_wgs84(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(lon, lat) of local points, through the OpenDRIVE georeference."""
        if not self.xodr_georeferenced:
            raise InputError("the OpenDRIVE file has no geoReference: positions cannot be placed on Earth")
        return self.georef.local_to_wgs84(x, y)

    @cached_property
    def _geod(self) -> pyproj.Geod:
        return self.georef.crs.get_geod() or pyproj.Geod(ellps="WGS84")

    def compass_heading(self, yaw, x, y) -> np.ndarray:
        """Local yaw at local (x, y) -> compass degrees (0 = true north, clockwise), in [0, 360)."""
        yaw = np.asarray(yaw, dtype=float)
        lon0, lat0 = self.local_to_wgs84(x, y)
        lon1, lat1 = self.local_to_wgs84(np.asarray(x) + _HEADING_PROBE_M * np.cos(yaw),
                                         np.asarray(y) + _HEADING_PROBE_M * np.sin(yaw))
        azimuth, _, _ = self._geod.inv(lon0, lat0, lon1, lat1)
        return np.mod(azimuth, 360.0)


def wrap_angle(angle) -> np.ndarray:
    """Angle(s) in radians wrapped to [-pi, pi)."""
    return np.mod(np.asarray(angle, dtype=float) + math.pi, 2.0 * math.pi) - math.pi
