"""What an OSM extract holds, counted while it is written: the figures a person checks before building."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field


@dataclass
class ExtractSummary:
    """Counts of one written extract; ``bbox`` is (W, S, E, N) of the nodes written (None if none)."""

    output: str
    area: dict | None = None
    nodes: int = 0
    ways: int = 0
    relations: int = 0
    highway_ways: Counter = field(default_factory=Counter)
    traffic_signals: int = 0
    traffic_signs: int = 0
    buildings: int = 0
    turn_restrictions: int = 0
    routes: int = 0
    bbox: tuple[float, float, float, float] | None = None

    def count_node(self, node) -> None:
        self.nodes += 1
        tags = node.tags
        # netconvert builds signals from highway=traffic_signals nodes (tls.guess-signals reads them too)
        if tags.get("highway") == "traffic_signals":
            self.traffic_signals += 1
        if "traffic_sign" in tags:
            self.traffic_signs += 1
        if node.location.valid():
            self._grow_bbox(node.location.lon, node.location.lat)

    def count_way(self, way) -> None:
        self.ways += 1
        tags = way.tags
        highway = tags.get("highway")
        if highway:
            self.highway_ways[highway] += 1
        if "traffic_sign" in tags:
            self.traffic_signs += 1
        if tags.get("building", "no") != "no":
            self.buildings += 1

    def count_relation(self, relation) -> None:
        self.relations += 1
        tags = relation.tags
        kind = tags.get("type", "")
        if kind == "restriction" or kind.startswith("restriction:"):
            self.turn_restrictions += 1
        elif kind == "route":
            self.routes += 1
        if tags.get("building", "no") != "no":
            self.buildings += 1

    def _grow_bbox(self, lon: float, lat: float) -> None:
        if self.bbox is None:
            self.bbox = (lon, lat, lon, lat)
        else:
            west, south, east, north = self.bbox
            self.bbox = (min(west, lon), min(south, lat), max(east, lon), max(north, lat))

    @property
    def centre(self) -> tuple[float, float] | None:
        """(lon, lat) of the bbox centre, rounded to 7 decimals (OSM's own precision, ~1 cm)."""
        if self.bbox is None:
            return None
        west, south, east, north = self.bbox
        return round((west + east) / 2, 7), round((south + north) / 2, 7)

    def to_dict(self) -> dict:
        return {
            "output": self.output,
            "area": self.area,
            "nodes": self.nodes,
            "ways": self.ways,
            "relations": self.relations,
            "highway_ways": dict(self.highway_ways.most_common()),
            "traffic_signals": self.traffic_signals,
            "traffic_signs": self.traffic_signs,
            "buildings": self.buildings,
            "turn_restrictions": self.turn_restrictions,
            "routes": self.routes,
            "bbox": list(self.bbox) if self.bbox else None,
            "centre": list(self.centre) if self.centre else None,
        }

    def to_text(self) -> str:
        """A few lines for a person: totals, then ways by highway type, most common first."""
        lines = [
            f"wrote {self.output}: {self.nodes} nodes, {self.ways} ways, {self.relations} relations"
            + (f" ({self.turn_restrictions} turn restrictions)" if self.turn_restrictions else ""),
        ]
        if self.area:
            lines.append(f"  area: {self.area['description']}")
        if self.bbox:
            west, south, east, north = self.bbox
            lines.append(f"  extent: {west:.5f},{south:.5f},{east:.5f},{north:.5f} (W,S,E,N)"
                         f" ~{_width_m(self.bbox):.0f} x {_height_m(self.bbox):.0f} m")
        highways = ", ".join(f"{count} {kind}" for kind, count in self.highway_ways.most_common())
        total = sum(self.highway_ways.values())
        lines.append(f"  highway ways: {total}" + (f" ({highways})" if highways else ""))
        lines.append(f"  traffic signals: {self.traffic_signals}, traffic signs: {self.traffic_signs}, "
                     f"buildings: {self.buildings}")
        return "\n".join(lines)


def _width_m(bbox) -> float:
    west, south, east, north = bbox
    return math.radians(east - west) * 6371008.8 * math.cos(math.radians((south + north) / 2))


def _height_m(bbox) -> float:
    return math.radians(bbox[3] - bbox[1]) * 6371008.8
