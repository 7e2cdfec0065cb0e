"""What the Urban Dynamic Map holds: one positioned object per record, its GeoJSON form, and WGS84 helpers.

An object is a point on the WGS84 ellipsoid (lat, lon in degrees) with a kind (``type``, ``class``), a layer
that says how fast it changes, and an optional end of validity after which nobody should see it again.
The GeoJSON form is what travels over HTTP; ``from_feature`` is the one place incoming data is checked, so the
server, the seeders and the client all reject the same things with the same messages.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from enum import IntEnum
from functools import lru_cache
from typing import Any

# Mean Earth radius (IUGG R1). The UDM answers "which objects are near the car", where the sphere's error
# against the ellipsoid (< 0.5 %) is far below a GNSS fix's own uncertainty.
EARTH_RADIUS_M = 6_371_008.8

ID_PATTERN = re.compile(r"^[A-Za-z0-9._:@~-]{1,128}$")
MAX_TYPE_LENGTH = 64
MAX_NAME_LENGTH = 256
MAX_SOURCE_LENGTH = 128


class Layer(IntEnum):
    """The four layers of a Local/Urban Dynamic Map, ordered by how quickly their content changes."""

    STATIC_MAP = 1  # roads, lanes, permanent signs: changes with map releases
    TRANSIENT_STATIC = 2  # signals, road works, speed limits in force: changes over hours to days
    TRANSIENT_DYNAMIC = 3  # congestion, signal phases, weather: changes over minutes
    HIGHLY_DYNAMIC = 4  # vehicles, pedestrians: changes every fraction of a second


class InvalidObject(ValueError):
    """An incoming feature or query cannot become an UDM object; the message says which field and why."""


@dataclass(frozen=True)
class Extent:
    """Size of an object in metres along its heading (length), across it (width) and upwards (height)."""

    length: float | None = None
    width: float | None = None
    height: float | None = None

    def to_json(self) -> dict[str, float]:
        return {key: value for key, value in vars(self).items() if value is not None}


@dataclass(frozen=True)
class UdmObject:
    """One UDM record. Times are POSIX seconds (UTC); ``heading`` is compass degrees, 0 = north, clockwise."""

    id: str
    layer: int
    type: str
    lat: float
    lon: float
    object_class: str = ""  # ``class`` in JSON; a Python keyword, hence the longer name here
    name: str = ""
    alt: float | None = None
    heading: float | None = None
    extent: Extent | None = None
    valid_until: float | None = None
    source: str = ""
    created_at: float | None = field(default=None, compare=False)
    updated_at: float | None = field(default=None, compare=False)

    def is_valid_at(self, now: float) -> bool:
        return self.valid_until is None or self.valid_until > now

    def with_times(self, created_at: float, updated_at: float) -> UdmObject:
        return replace(self, created_at=created_at, updated_at=updated_at)

    def to_feature(self) -> dict[str, Any]:
        """The GeoJSON Feature sent to clients; ``properties.id`` repeats the id for readers that drop it."""
        coordinates = [self.lon, self.lat] if self.alt is None else [self.lon, self.lat, self.alt]
        return {
            "type": "Feature",
            "id": self.id,
            "geometry": {"type": "Point", "coordinates": coordinates},
            "properties": {
                "id": self.id,
                "layer": self.layer,
                "type": self.type,
                "class": self.object_class,
                "name": self.name,
                "heading": self.heading,
                "extent": self.extent.to_json() if self.extent else None,
                "created_at": iso_utc(self.created_at),
                "updated_at": iso_utc(self.updated_at),
                "valid_until": iso_utc(self.valid_until),
                "source": self.source,
            },
        }

    def to_record(self) -> dict[str, Any]:
        """Every field, exactly (floats round-trip through JSON), for recordings; see ``from_record``."""
        record = {key: getattr(self, key) for key in _RECORD_FIELDS}
        record["extent"] = self.extent.to_json() if self.extent else None
        return record

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> UdmObject:
        """The object ``to_record`` wrote (a recording is trusted: it was written by ``to_record``)."""
        values = {key: record.get(key) for key in _RECORD_FIELDS}
        values["extent"] = Extent(**record["extent"]) if record.get("extent") else None
        for key in ("object_class", "name", "source"):
            values[key] = values[key] or ""
        return cls(**values)

    @classmethod
    def from_feature(
        cls, feature: Any, *, default_id: str | None = None, default_layer: int | None = None,
        default_source: str = "",
    ) -> UdmObject:
        """Check a GeoJSON Point Feature and build the object; raises InvalidObject naming the bad field."""
        if not isinstance(feature, dict) or feature.get("type") != "Feature":
            raise InvalidObject('expected a GeoJSON object with "type": "Feature"')
        properties = feature.get("properties") or {}
        if not isinstance(properties, dict):
            raise InvalidObject("properties must be a JSON object")
        lon, lat, alt = _point_coordinates(feature.get("geometry"))

        object_id = _object_id(feature.get("id"), properties.get("id"), default_id)
        layer = properties.get("layer", default_layer)
        if layer is None:
            raise InvalidObject("properties.layer is required (1 static map .. 4 highly dynamic)")
        return cls(
            id=object_id,
            layer=parse_layer(layer),
            type=_text(properties.get("type"), "type", MAX_TYPE_LENGTH, required=True),
            lat=lat,
            lon=lon,
            alt=alt,
            object_class=_text(properties.get("class"), "class", MAX_TYPE_LENGTH),
            name=_text(properties.get("name"), "name", MAX_NAME_LENGTH),
            heading=_heading(properties.get("heading")),
            extent=_extent(properties.get("extent")),
            valid_until=parse_time(properties.get("valid_until"), "valid_until"),
            source=_text(properties.get("source", default_source), "source", MAX_SOURCE_LENGTH),
            created_at=parse_time(properties.get("created_at"), "created_at"),
            updated_at=parse_time(properties.get("updated_at"), "updated_at"),
        )


_RECORD_FIELDS = ("id", "layer", "type", "lat", "lon", "object_class", "name", "alt", "heading", "extent",
                  "valid_until", "source", "created_at", "updated_at")


def parse_layer(value: Any) -> int:
    """A layer number 1..4 from an int or a digit string; anything else is an InvalidObject."""
    if isinstance(value, bool):
        raise InvalidObject(f"unknown layer {value!r}; layers are 1, 2, 3, 4")
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value.strip())
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or value not in Layer._value2member_map_:
        raise InvalidObject(f"unknown layer {value!r}; layers are 1, 2, 3, 4")
    return value


def parse_time(value: Any, name: str) -> float | None:
    """POSIX seconds from a number or an ISO 8601 string with a time zone; None stays None."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise InvalidObject(f"{name} must be ISO 8601 text or POSIX seconds")
    if isinstance(value, (int, float)):
        if not math.isfinite(value):
            raise InvalidObject(f"{name} must be finite")
        return float(value)
    if isinstance(value, str):
        try:
            moment = datetime.fromisoformat(value)
        except ValueError:
            raise InvalidObject(f"{name} {value!r} is not an ISO 8601 time") from None
        if moment.tzinfo is None:
            # A time without a zone means different instants on different machines.
            raise InvalidObject(f"{name} {value!r} needs a time zone, e.g. {value}Z")
        return moment.timestamp()
    raise InvalidObject(f"{name} must be ISO 8601 text or POSIX seconds")


@lru_cache(maxsize=65536)
def iso_utc(seconds: float | None) -> str | None:
    """ISO 8601 UTC text with milliseconds; cached because seeded objects share a handful of timestamps."""
    if seconds is None:
        return None
    text = datetime.fromtimestamp(seconds, tz=UTC).isoformat(timespec="milliseconds")
    return text.replace("+00:00", "Z")


def _point_coordinates(geometry: Any) -> tuple[float, float, float | None]:
    if not isinstance(geometry, dict) or geometry.get("type") != "Point":
        raise InvalidObject("geometry must be a GeoJSON Point (UDM objects are positioned points)")
    coordinates = geometry.get("coordinates")
    if not isinstance(coordinates, list) or len(coordinates) not in (2, 3):
        raise InvalidObject("Point coordinates must be [lon, lat] or [lon, lat, alt]")
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in coordinates):
        raise InvalidObject("Point coordinates must be numbers")
    lon, lat = float(coordinates[0]), float(coordinates[1])
    alt = float(coordinates[2]) if len(coordinates) == 3 else None
    if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
        raise InvalidObject(f"longitude {coordinates[0]} is outside -180..180")
    if not (math.isfinite(lat) and -90.0 <= lat <= 90.0):
        raise InvalidObject(f"latitude {coordinates[1]} is outside -90..90")
    if alt is not None and not math.isfinite(alt):
        raise InvalidObject("altitude must be finite")
    return lon, lat, alt


def _object_id(feature_id: Any, property_id: Any, default_id: str | None) -> str:
    given = (feature_id, property_id)
    ids = {str(value) for value in given if value is not None and not isinstance(value, bool)}
    if len(ids) > 1:
        raise InvalidObject(f"feature id and properties.id disagree: {sorted(ids)}")
    object_id = ids.pop() if ids else default_id
    if object_id is None:
        raise InvalidObject("the feature has no id")
    if not ID_PATTERN.match(object_id):
        raise InvalidObject(f"id {object_id!r} must be 1-128 characters of A-Z a-z 0-9 . _ : @ ~ -")
    return object_id


def _text(value: Any, name: str, max_length: int, *, required: bool = False) -> str:
    if value is None:
        value = ""
    if not isinstance(value, str):
        raise InvalidObject(f"{name} must be a string")
    if required and not value.strip():
        raise InvalidObject(f"properties.{name} is required")
    if len(value) > max_length:
        raise InvalidObject(f"{name} is longer than {max_length} characters")
    return value


def _heading(value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidObject("heading must be a finite number of compass degrees")
    return float(value) % 360.0


def _extent(value: Any) -> Extent | None:
    if value is None:
        return None
    if not isinstance(value, dict) or not set(value) <= {"length", "width", "height"}:
        raise InvalidObject('extent must be {"length": m, "width": m, "height": m} (each optional)')
    sizes = {}
    for key, size in value.items():
        if size is None:
            continue
        if isinstance(size, bool) or not isinstance(size, (int, float)) or not (0.0 <= size < 1e5):
            raise InvalidObject(f"extent.{key} must be a number of metres >= 0")
        sizes[key] = float(size)
    return Extent(**sizes)


# --- WGS84 on a sphere: the distances and boxes the store and the client agree on -----------------------


@dataclass(frozen=True)
class BBox:
    """A longitude/latitude box in degrees, west-south-east-north as in GeoJSON and OGC API ``bbox``."""

    min_lon: float
    min_lat: float
    max_lon: float
    max_lat: float

    def contains(self, lat: float, lon: float) -> bool:
        return self.min_lat <= lat <= self.max_lat and self.min_lon <= lon <= self.max_lon

    def area_km2(self) -> float:
        """Exact area of the box on the sphere (a lat/lon box is a zone slice, so no approximation)."""
        width = math.radians(self.max_lon - self.min_lon)
        band = math.sin(math.radians(self.max_lat)) - math.sin(math.radians(self.min_lat))
        return EARTH_RADIUS_M**2 * width * band / 1e6

    def as_param(self) -> str:
        return f"{self.min_lon!r},{self.min_lat!r},{self.max_lon!r},{self.max_lat!r}"


def haversine_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance in metres; haversine keeps precision at the few-metre distances we care about."""
    phi1, phi2 = math.radians(lat1), math.radians(lat2)
    half_dphi = (phi2 - phi1) / 2.0
    half_dlambda = math.radians(lon2 - lon1) / 2.0
    a = math.sin(half_dphi) ** 2 + math.cos(phi1) * math.cos(phi2) * math.sin(half_dlambda) ** 2
    return 2.0 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def boxes_around(lat: float, lon: float, radius_m: float) -> list[BBox]:
    """Boxes that together cover every point within ``radius_m`` of (lat, lon): an exact circle bound.

    The latitude bound is the radius itself; the longitude bound is where a meridian touches the circle.
    A circle over a pole spans every longitude, and one over the antimeridian is split into two boxes,
    because a box with min_lon > max_lon is not something the index (or our API) accepts.
    """
    angle = radius_m / EARTH_RADIUS_M
    dlat = math.degrees(angle)
    min_lat, max_lat = lat - dlat, lat + dlat
    if min_lat <= -90.0 or max_lat >= 90.0 or angle >= math.pi / 2:
        return [BBox(-180.0, max(min_lat, -90.0), 180.0, min(max_lat, 90.0))]
    ratio = math.sin(angle) / math.cos(math.radians(lat))
    dlon = 180.0 if ratio >= 1.0 else math.degrees(math.asin(ratio))
    west, east = lon - dlon, lon + dlon
    if dlon >= 180.0:
        return [BBox(-180.0, min_lat, 180.0, max_lat)]
    if west < -180.0:
        return [BBox(-180.0, min_lat, east, max_lat), BBox(west + 360.0, min_lat, 180.0, max_lat)]
    if east > 180.0:
        return [BBox(west, min_lat, 180.0, max_lat), BBox(-180.0, min_lat, east - 360.0, max_lat)]
    return [BBox(west, min_lat, east, max_lat)]


def square_around(lat: float, lon: float, side_m: float) -> BBox:
    """The box of ``side_m`` x ``side_m`` metres centred on a fix, clipped at the poles and the antimeridian.

    Clipping (not splitting) is enough here: a vehicle's look-ahead square loses a sliver at +-180 deg,
    where no city we drive in lies.
    """
    half = side_m / 2.0
    dlat = math.degrees(half / EARTH_RADIUS_M)
    dlon = math.degrees(half / (EARTH_RADIUS_M * max(math.cos(math.radians(lat)), 1e-6)))
    return BBox(
        min_lon=max(lon - dlon, -180.0),
        min_lat=max(lat - dlat, -90.0),
        max_lon=min(lon + dlon, 180.0),
        max_lat=min(lat + dlat, 90.0),
    )
