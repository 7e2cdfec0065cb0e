"""Signals as Lanelet2 regulatory elements: traffic lights and traffic signs, with the lanelets they govern.

One element per OpenDRIVE signal. Dynamic signals are traffic lights (``subtype=traffic_light``), the others
traffic signs (``subtype=traffic_sign``, sign code = country + type [+ "-" + subtype], e.g. ``de206``).
``refers`` is a short way at the signal's position: across the road at (s, t +- width / 2), at the signal's
zOffset above the surface, with the signal's height as a tag (Lanelet2 draws a light from that bottom edge
up). ``ref_line`` is a stop line across the governed lanes at the signal's s. The governed lanes are those of
the lane section at s that the signal's ``<validity>`` names, else every lane whose driving direction matches
its orientation ("+": with s, "-": against s, other: both); ``<signalReference>`` elements on other roads add
their lanes the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from lxml import etree

from tavf_mapkit.lanegraph.keys import drives_with_s
from tavf_mapkit.xmlsafe import safe_parser

DEFAULT_SIGNAL_WIDTH = 0.5  # m, where the signal gives none
_PEDESTRIAN_LIGHTS = frozenset({"1000002", "1000007"})  # two-light signals for pedestrians and cyclists


@dataclass
class SignalElement:
    """A regulatory element before node merging: its geometry in local coordinates and its lanelets."""

    tags: dict[str, str]
    refers_tags: dict[str, str]
    refers_points: np.ndarray  # (2, 3)
    stop_points: np.ndarray  # (k, 3), k >= 2, or (0, 3) without a stop line
    lanelets: list[int] = field(default_factory=list)


def validity_ranges(element) -> list[tuple[int, int]]:
    """(fromLane, toLane) of the ``<validity>`` children the reader kept as unparsed XML."""
    ranges = []
    for fragment in getattr(element, "extra_xml", ()) or ():
        try:
            node = etree.fromstring(fragment, safe_parser())
        except etree.XMLSyntaxError:
            continue  # the reader parsed the document: a fragment that does not reparse carries no validity
        if etree.QName(node).localname != "validity":
            continue
        try:
            low, high = int(node.get("fromLane")), int(node.get("toLane"))
        except (TypeError, ValueError):
            continue
        ranges.append((min(low, high), max(low, high)))
    return ranges


def governed_lane_ids(road, section, orientation: str, ranges: list[tuple[int, int]]) -> list[int]:
    """Side lanes of ``section`` a signal with this orientation and validity applies to."""
    if ranges:
        return sorted(lane.id for lane in section.side_lanes if any(lo <= lane.id <= hi for lo, hi in ranges))
    if orientation not in ("+", "-"):
        return sorted(lane.id for lane in section.side_lanes)
    with_s = orientation == "+"
    return sorted(lane.id for lane in section.side_lanes if drives_with_s(road, lane) == with_s)


def sign_code(signal) -> str:
    country = (signal.country or "").strip().lower()
    code = f"{country}{signal.type}"
    if signal.subtype not in (None, "", "-1", "none"):
        code += f"-{signal.subtype}"
    return code


def _tags_of(signal) -> tuple[dict[str, str], dict[str, str]]:
    """(regulatory element tags, refers way tags)."""
    source = {
        "opendrive:signal": signal.id,
        "opendrive:type": str(signal.type),
        "opendrive:subtype": str(signal.subtype),
    }
    height = f"{signal.height:g}" if signal.height is not None and np.isfinite(signal.height) else None
    if signal.dynamic:
        light = "red_green" if str(signal.type) in _PEDESTRIAN_LIGHTS else "red_yellow_green"
        way = {"type": "traffic_light", "subtype": light, **source}
        element = {"type": "regulatory_element", "subtype": "traffic_light"}
    else:
        way = {"type": "traffic_sign", "subtype": sign_code(signal), **source}
        element = {"type": "regulatory_element", "subtype": "traffic_sign"}
    if height is not None:
        way["height"] = height
    return element, way


def signal_elements(odr, lanelet_of: dict[tuple[int, int, int], int]) -> list[SignalElement]:
    """Every signal that governs at least one exported lanelet. ``lanelet_of``: (road index, section index,
    lane id) -> lanelet index."""
    elements: dict[tuple[int, str], SignalElement] = {}
    by_id: dict[str, tuple[int, object]] = {}
    for road_index, road in enumerate(odr.roads):
        for signal in road.signals:
            by_id.setdefault(signal.id, (road_index, signal))
    for road_index, road in enumerate(odr.roads):
        if not road.lane_sections:
            continue
        for signal in road.signals:
            element = _element(road_index, road, signal, signal, lanelet_of)
            if element is not None:
                elements[(road_index, signal.id)] = element
        for reference in road.signal_references:
            if reference.id not in by_id:
                continue
            home_index, signal = by_id[reference.id]
            lanes = _governed(road_index, road, reference, lanelet_of)
            if not lanes:
                continue
            known = elements.get((home_index, signal.id))
            if known is None:
                known = _element(
                    home_index, odr.roads[home_index], signal, signal, lanelet_of, require_lanes=False
                )
                elements[(home_index, signal.id)] = known
            known.lanelets = sorted(set(known.lanelets) | set(lanes))
    return [element for element in elements.values() if element.lanelets]


def _governed(road_index: int, road, placed, lanelet_of) -> list[int]:
    """Lanelet indices governed by a signal or signal reference placed on ``road``."""
    s = float(np.clip(placed.s, 0.0, road.length))
    section_index = int(road.section_index(s))
    ids = governed_lane_ids(
        road, road.lane_sections[section_index], placed.orientation, validity_ranges(placed)
    )
    return [
        lanelet_of[key]
        for key in ((road_index, section_index, lane_id) for lane_id in ids)
        if key in lanelet_of
    ]


def _element(
    road_index: int, road, placed, signal, lanelet_of, require_lanes: bool = True
) -> SignalElement | None:
    lanelets = _governed(road_index, road, placed, lanelet_of)
    if require_lanes and not lanelets:
        return None
    s = float(np.clip(placed.s, 0.0, road.length))
    width = (
        signal.width
        if signal.width is not None and np.isfinite(signal.width) and signal.width > 0
        else DEFAULT_SIGNAL_WIDTH
    )
    z_offset = signal.z_offset if np.isfinite(signal.z_offset) else 0.0
    refers = road.surface_point(
        [s, s], np.array([placed.t - width / 2, placed.t + width / 2]), np.array([z_offset, z_offset])
    )
    element_tags, way_tags = _tags_of(signal)
    return SignalElement(element_tags, way_tags, refers, _stop_line(road, s, placed), lanelets)


def _stop_line(road, s: float, placed) -> np.ndarray:
    """Points across the governed lanes at s: every border between them, from one side to the other."""
    section_index = int(road.section_index(s))
    section = road.lane_sections[section_index]
    ids = governed_lane_ids(road, section, placed.orientation, validity_ranges(placed))
    if not ids:
        return np.zeros((0, 3))
    borders = road.lane_borders(section_index, [s])
    inner = {lane_id: borders[0 if abs(lane_id) == 1 else lane_id - int(np.sign(lane_id))] for lane_id in ids}
    t = np.unique(np.concatenate([np.concatenate([inner[i], borders[i]]) for i in ids]))
    if len(t) < 2:
        return np.zeros((0, 3))
    return road.surface_point(np.full(len(t), s), t)
