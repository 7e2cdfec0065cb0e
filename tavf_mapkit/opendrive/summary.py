"""What an OpenDRIVE file holds: counts, length, bounds, georeference and its plausibility."""

from __future__ import annotations

from collections import Counter

import numpy as np
from lxml import etree

from tavf_mapkit.errors import MapkitError
from tavf_mapkit.opendrive.geometry import ELEMENT_NAMES, GeometryKind

#: the elements the build report counts (``ElementCounts``), in any namespace: some writers put OpenDRIVE in a
#: default namespace (the A9 HD map)
COUNTED_TAGS = ("{*}road", "{*}junction", "{*}signal", "{*}object")
COUNTED_NAMES = frozenset(tag.removeprefix("{*}") for tag in COUNTED_TAGS)


class ElementCounts:
    """The roads, junctions (children of the document's root only), signals and objects of an OpenDRIVE document
    and the sum of its roads' @length, counted as its elements end -- the numbers of the build report's
    "opendrive" part. One definition for both ways they are made: a streaming pass over a file
    (``pipeline.summary.opendrive_counts``) and the writer, which counts what it writes (``writer.write_opendrive``:
    a region's report need not parse the 500 MB it wrote again)."""

    __slots__ = ("junctions", "length", "objects", "roads", "signals")

    def __init__(self) -> None:
        self.roads = self.junctions = self.signals = self.objects = 0
        self.length = 0.0  # added in the order the roads end in the document, as a pass over the file adds them

    def ended(self, element) -> None:
        """One element of COUNTED_TAGS, at its end (its parent known)."""
        tag = etree.QName(element).localname
        if tag == "road":
            self.add_road(float(element.get("length", 0.0) or 0.0))
        elif tag == "junction":
            parent = element.getparent()
            if parent is not None and etree.QName(parent).localname == "OpenDRIVE":
                self.junctions += 1
        elif tag == "signal":
            self.signals += 1
        elif tag == "object":
            self.objects += 1

    def add_tree(self, element) -> None:
        """Every counted element of ``element``'s tree, itself included, in the order they end."""
        for _event, ended in etree.iterwalk(element, events=("end",), tag=COUNTED_TAGS):
            self.ended(ended)

    def add_road(self, length: float) -> None:
        self.roads += 1
        self.length += length

    def as_dict(self) -> dict:
        return {"roads": self.roads, "junctions": self.junctions, "signals": self.signals, "objects": self.objects,
                "road_length_km": round(self.length / 1000, 3)}


def summarise(odr) -> dict:
    bounds = odr.bounds(step=2.0)
    # counted from the map's tables, which the bounds have just built (a region's millions of geometry records
    # and hundreds of thousands of lanes, not visited one by one): a row per geometry, one per side lane
    arrays = odr.arrays
    lanes_by_type = Counter(arrays.lane_type.tolist())
    geometry_types = {ELEMENT_NAMES[GeometryKind(kind)]: int(count)
                      for kind, count in enumerate(np.bincount(arrays.geometries.kind).tolist())
                      if count}
    summary = {
        "file": odr.source,
        "version": odr.header.revision,
        "name": odr.header.name,
        "vendor": odr.header.vendor,
        "counts": {
            "roads": len(odr.roads),
            "junction_roads": sum(1 for road in odr.roads if road.in_junction),
            "junctions": len(odr.junctions),
            "lane_sections": len(arrays.section_road),
            "lanes": sum(lanes_by_type.values()),
            "lanes_by_type": dict(sorted(lanes_by_type.items())),
            "geometries_by_type": dict(sorted(geometry_types.items())),
            "objects": sum(len(road.objects) for road in odr.roads),
            "signals": sum(len(road.signals) for road in odr.roads),
            "controllers": len(odr.controllers),
        },
        "total_length_m": float(sum(road.length for road in odr.roads)),
        "bounds_local": dict(zip(("west", "south", "east", "north"), bounds)),
        "georeference": None,
        "warnings": [w.as_dict() for w in odr.warnings],
    }
    geo = odr.georeference
    if geo is not None:
        info = {"proj": geo.text, "offset": None, "crs": None, "bounds_wgs84": None, "problems": [],
                "carla_readable": geo.carla_readable()}
        if odr.header.offset is not None:
            o = odr.header.offset
            info["offset"] = {"x": o.x, "y": o.y, "z": o.z, "hdg": o.hdg}
        try:
            info["crs"] = geo.crs.name
            lon, lat = geo.local_to_wgs84(np.array([bounds[0], bounds[2]]), np.array([bounds[1], bounds[3]]))
            info["bounds_wgs84"] = {"west": float(min(lon)), "south": float(min(lat)), "east": float(max(lon)),
                                    "north": float(max(lat))}
        except MapkitError as error:
            info["problems"].append(error.message)
        if not info["problems"]:
            info["problems"] = geo.plausibility(bounds)
        info["plausible"] = not info["problems"]
        summary["georeference"] = info
    return summary


def format_summary(summary: dict) -> str:
    counts = summary["counts"]
    lines = [
        f"{summary['file']}",
        f"  OpenDRIVE {summary['version']}" + (f", name {summary['name']!r}" if summary["name"] else ""),
        (f"  roads {counts['roads']} ({counts['junction_roads']} in junctions), junctions {counts['junctions']}, "
         f"lane sections {counts['lane_sections']}, total length {summary['total_length_m'] / 1000:.2f} km"),
        "  lanes " + ", ".join(f"{k} {v}" for k, v in counts["lanes_by_type"].items()),
        "  geometries " + ", ".join(f"{k} {v}" for k, v in counts["geometries_by_type"].items()),
        f"  objects {counts['objects']}, signals {counts['signals']}, controllers {counts['controllers']}",
    ]
    b = summary["bounds_local"]
    lines.append(f"  bounds (local) x {b['west']:.2f} .. {b['east']:.2f}, y {b['south']:.2f} .. {b['north']:.2f}")
    geo = summary["georeference"]
    if geo is None:
        lines.append("  georeference: none (positions cannot be placed on Earth)")
    else:
        lines.append(f"  georeference: {geo['proj']}")
        if geo["offset"]:
            o = geo["offset"]
            lines.append(f"  offset: x {o['x']} y {o['y']} z {o['z']} hdg {o['hdg']}")
        if geo["bounds_wgs84"]:
            w = geo["bounds_wgs84"]
            lines.append(f"  bounds (WGS84) lon {w['west']:.6f} .. {w['east']:.6f}, "
                         f"lat {w['south']:.6f} .. {w['north']:.6f}")
        lines.append("  plausible: yes" if geo["plausible"] else "  plausible: NO")
        lines.extend(f"    - {problem}" for problem in geo["problems"])
        if not geo["carla_readable"]:
            lines.append("  note: CARLA reads only +lat_0/+lon_0 and ignores <offset>; it will misplace this map")
    if summary["warnings"]:
        lines.append(f"  warnings: {len(summary['warnings'])}")
        for warning in summary["warnings"][:10]:
            where = f"line {warning['line']}: " if warning["line"] else ""
            road = f"road {warning['road']}: " if warning["road"] is not None else ""
            lines.append(f"    - {where}{road}{warning['message']}")
        if len(summary["warnings"]) > 10:
            lines.append(f"    ... and {len(summary['warnings']) - 10} more (use --json)")
    return "\n".join(lines)
