"""The whole OpenDRIVE map: header, roads, junctions, controllers, and what the reader noticed."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tavf_mapkit.opendrive.diagnostics import Diagnostic
from tavf_mapkit.opendrive.georef import GeoReference
from tavf_mapkit.opendrive.header import Header
from tavf_mapkit.opendrive.junction import Controller, Junction
from tavf_mapkit.opendrive.road import Road


BOUNDS_CHUNK = 250_000  # lane samples per pass of ``OpenDriveMap.bounds``


@dataclass(frozen=True, eq=False)
class OpenDriveMap:
    header: Header
    roads: tuple[Road, ...]
    junctions: tuple[Junction, ...] = ()
    controllers: tuple[Controller, ...] = ()
    source: str | None = None
    warnings: tuple[Diagnostic, ...] = ()
    extra_xml: tuple[bytes, ...] = field(default=(), compare=False)  # unknown top-level elements, verbatim

    @cached_property
    def road_by_id(self) -> dict[str, Road]:
        return {road.id: road for road in self.roads}

    @cached_property
    def road_index(self) -> dict[str, int]:
        return {road.id: index for index, road in enumerate(self.roads)}

    @cached_property
    def junction_by_id(self) -> dict[str, Junction]:
        return {junction.id: junction for junction in self.junctions}

    @cached_property
    def georeference(self) -> GeoReference | None:
        if not self.header.geo_reference:
            return None
        return GeoReference(self.header.geo_reference, self.header.offset)

    @cached_property
    def arrays(self):
        """Flattened tables of the whole map for vectorised evaluation (built once)."""
        from tavf_mapkit.opendrive.arrays import NetworkArrays

        return NetworkArrays.build(self)

    def bounds(self, step: float = 2.0) -> tuple[float, float, float, float]:
        """(west, south, east, north) of all lane borders (outer borders sampled every ``step`` m, section ends
        included) in local coordinates. Sampled a few hundred thousand points at a time, so the memory does
        not grow with the map."""
        from tavf_mapkit.opendrive.sampling import sample_lanes_at, section_chunks, section_samples

        arrays = self.arrays
        low, high = np.full(2, np.inf), np.full(2, -np.inf)
        for part in section_chunks(arrays, step, BOUNDS_CHUNK):
            border = sample_lanes_at(self, *section_samples(arrays, step, True, part)).outer_border_points()
            if len(border):
                low = np.minimum(low, border[:, :2].min(axis=0))
                high = np.maximum(high, border[:, :2].max(axis=0))
        if not np.isfinite(low[0]):
            return (0.0, 0.0, 0.0, 0.0)
        return (float(low[0]), float(low[1]), float(high[0]), float(high[1]))

    def with_header(self, header: Header) -> "OpenDriveMap":
        """A copy with another header (e.g. a rewritten geoReference)."""
        return OpenDriveMap(header, self.roads, self.junctions, self.controllers, self.source, self.warnings,
                            self.extra_xml)
