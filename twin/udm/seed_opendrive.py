"""UDM objects for the OpenDRIVE ``<signal>`` and ``<object>`` elements of a build's map.

A signal sits at road coordinates (s, t); its WGS84 position is the road surface point at (s, t) taken through
the map's geoReference. Its heading is the direction of travel it governs: the reference line's heading at s,
turned by ``hOffset`` and by half a turn for ``orientation="-"``. That heading is converted to a compass
bearing from two projected points rather than by formula, so the geoReference offset's rotation and the
projection's meridian convergence are both accounted for.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive import OpenDriveMap, load_opendrive
from twin.udm.model import ID_PATTERN, MAX_TYPE_LENGTH, Extent, Layer, UdmObject

SEED_LAYER = int(Layer.TRANSIENT_STATIC)
MANIFEST = "manifest.json"
HEADING_PROBE_M = 1.0  # length of the step along the heading whose bearing gives the compass heading

# OpenDRIVE object types that name the same thing as an OSM-seeded type.
OBJECT_TYPES = {"crosswalk": "crossing"}
UNSAFE_ID_CHARACTER = re.compile(r"[^A-Za-z0-9._:@-]")


@dataclass(frozen=True)
class _Placed:
    """One signal or object at road coordinates, waiting to be converted in a single vectorised batch."""

    kind: str  # "signal" or "object"
    element: object
    road_id: str
    x: float
    y: float
    heading: float  # radians in the local frame, counter-clockwise from +x


def find_xodr(build_dir: Path) -> Path | None:
    """The build's OpenDRIVE file: the manifest's ``xodr`` artifact, else the only ``*.xodr`` at the top."""
    manifest = build_dir / MANIFEST
    if manifest.is_file():
        try:
            artifact = json.loads(manifest.read_text(encoding="utf-8")).get("artifacts", {}).get("xodr", {})
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as error:
            raise InputError(f"cannot read the build manifest: {error}", file=str(manifest)) from None
        path = artifact.get("path") if isinstance(artifact, dict) else None
        if isinstance(path, str) and (build_dir / path).is_file():
            return build_dir / path
    candidates = sorted(build_dir.glob("*.xodr"))
    return candidates[0] if len(candidates) == 1 else None


def objects_from_opendrive(build_dir: Path) -> Iterator[UdmObject]:
    """Signals and road objects of the build's OpenDRIVE map (no map file: nothing)."""
    path = find_xodr(build_dir)
    if path is None:
        return
    yield from objects_from_map(load_opendrive(path), source=f"xodr:{path.name}", file=str(path))


def objects_from_map(odr: OpenDriveMap, source: str = "xodr", file: str | None = None) -> Iterator[UdmObject]:
    placed = list(_placements(odr))
    if not placed:
        return
    georeference = odr.georeference
    if georeference is None:
        raise InputError("the OpenDRIVE map has no geoReference, so its signals cannot be placed in WGS84",
                         file=file, element="geoReference")
    x = np.array([p.x for p in placed])
    y = np.array([p.y for p in placed])
    heading = np.array([p.heading for p in placed])
    lon, lat = georeference.local_to_wgs84(x, y)
    ahead_lon, ahead_lat = georeference.local_to_wgs84(x + HEADING_PROBE_M * np.cos(heading),
                                                       y + HEADING_PROBE_M * np.sin(heading))
    bearing = compass_bearing(lat, lon, ahead_lat, ahead_lon)
    for index, item in enumerate(placed):
        maker = _signal_object if item.kind == "signal" else _road_object
        yield maker(item, float(lat[index]), float(lon[index]), float(bearing[index]), source)


def _placements(odr: OpenDriveMap) -> Iterator[_Placed]:
    for road in odr.roads:
        elements = [("signal", signal, signal.s, signal.t, signal.h_offset, signal.orientation == "-")
                    for signal in road.signals]
        elements += [("object", obj, obj.s, obj.t, obj.hdg, False) for obj in road.objects]
        if not elements:
            continue
        s = np.clip(np.array([e[2] for e in elements], dtype=float), 0.0, road.length)
        t = np.array([e[3] for e in elements], dtype=float)
        points = road.surface_point(s, t)
        ref_heading = road.reference_point(s)[3]
        for index, (kind, element, _, _, turn, reverse) in enumerate(elements):
            heading = float(ref_heading[index]) + turn + (math.pi if reverse else 0.0)
            yield _Placed(kind, element, road.id, float(points[index, 0]), float(points[index, 1]), heading)


def _signal_object(item: _Placed, lat: float, lon: float, bearing: float, source: str) -> UdmObject:
    signal = item.element
    # dynamic signals are traffic lights (OpenDRIVE catalogue 1000001, 1000011 arrows, ...); the rest are signs.
    type_ = "traffic_signals" if signal.dynamic else "traffic_sign"
    code = f"{signal.country}:{signal.type}" if signal.country else str(signal.type)
    if signal.subtype not in ("-1", "", None):
        code += f"-{signal.subtype}"
    if signal.value is not None:
        code += f"={signal.value:g}{signal.unit or ''}"
    return UdmObject(
        id=safe_id(f"xodr-signal-{signal.id}"),
        layer=SEED_LAYER,
        type=type_,
        object_class=code[:MAX_TYPE_LENGTH],
        name=(signal.name or f"road {item.road_id} signal {signal.id}")[:256],
        lat=lat,
        lon=lon,
        heading=bearing,
        extent=Extent(width=signal.width, height=signal.height) if signal.width or signal.height else None,
        source=source,
    )


def _road_object(item: _Placed, lat: float, lon: float, bearing: float, source: str) -> UdmObject:
    obj = item.element
    kind = (obj.type or "none").lower()
    has_extent = obj.length is not None or obj.width is not None or obj.height is not None
    return UdmObject(
        id=safe_id(f"xodr-object-{item.road_id}-{obj.id}"),
        layer=SEED_LAYER,
        type=OBJECT_TYPES.get(kind, "road_object"),
        object_class=kind[:MAX_TYPE_LENGTH],
        name=(obj.name or f"road {item.road_id} object {obj.id}")[:256],
        lat=lat,
        lon=lon,
        heading=bearing,
        extent=Extent(obj.length, obj.width, obj.height) if has_extent else None,
        source=source,
    )


def compass_bearing(lat1, lon1, lat2, lon2) -> np.ndarray:
    """Initial great-circle bearing from point 1 to point 2 in degrees, 0 = north, clockwise, in [0, 360)."""
    phi1, phi2 = np.radians(lat1), np.radians(lat2)
    dlambda = np.radians(np.asarray(lon2) - np.asarray(lon1))
    y = np.sin(dlambda) * np.cos(phi2)
    x = np.cos(phi1) * np.sin(phi2) - np.sin(phi1) * np.cos(phi2) * np.cos(dlambda)
    return np.degrees(np.arctan2(y, x)) % 360.0


def safe_id(text: str) -> str:
    """An UDM id for an OpenDRIVE id: characters outside the id alphabet become ``~hex``; long ids are hashed."""
    escaped = UNSAFE_ID_CHARACTER.sub(lambda match: f"~{ord(match.group()):02x}", text)
    if len(escaped) > 128:
        digest = hashlib.sha1(text.encode()).hexdigest()[:16]
        escaped = f"{escaped[:111]}~{digest}"
    assert ID_PATTERN.match(escaped), escaped
    return escaped
