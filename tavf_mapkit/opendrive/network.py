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
        """(west, south, east, north) of all lane borders in local coordinates."""
        from tavf_mapkit.opendrive.sampling import sample_lane_borders

        samples = sample_lane_borders(self, step)
        if not len(samples.x):
            return (0.0, 0.0, 0.0, 0.0)
        return (float(np.min(samples.x)), float(np.min(samples.y)), float(np.max(samples.x)), float(np.max(samples.y)))

    def with_header(self, header: Header) -> "OpenDriveMap":
        """A copy with another header (e.g. a rewritten geoReference)."""
        return OpenDriveMap(header, self.roads, self.junctions, self.controllers, self.source, self.warnings,
                            self.extra_xml)
