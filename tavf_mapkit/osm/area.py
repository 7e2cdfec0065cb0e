"""The area to extract: a W,S,E,N box or a GeoJSON (multi)polygon, tested against arrays of lon/lat."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tavf_mapkit.errors import InputError


@dataclass(frozen=True, eq=False)
class Area:
    """Where to cut: ``bbox`` is (W, S, E, N) in degrees; ``polygon`` (shapely, lon/lat) refines it."""

    bbox: tuple[float, float, float, float]
    description: str
    polygon: object | None = None

    def contains(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Boolean mask of the points inside (a point on the boundary counts as inside)."""
        west, south, east, north = self.bbox
        inside = (lon >= west) & (lon <= east) & (lat >= south) & (lat <= north)
        if self.polygon is not None and inside.any():
            import shapely

            candidates = np.flatnonzero(inside)
            inside[candidates] = shapely.intersects_xy(self.polygon, lon[candidates], lat[candidates])
        return inside

    def to_dict(self) -> dict:
        return {"bbox": list(self.bbox), "description": self.description}


def parse_bbox(text: str) -> Area:
    """``"9.95,53.543,10.01,53.57"`` (W,S,E,N, the order of osmium, Overpass `bbox=` and GeoJSON) -> Area."""
    parts = [part.strip() for part in str(text).split(",")]
    if len(parts) != 4:
        raise InputError(f"bbox must be four numbers W,S,E,N (got {text!r})")
    try:
        west, south, east, north = (float(part) for part in parts)
    except ValueError:
        raise InputError(f"bbox must be four numbers W,S,E,N (got {text!r})") from None
    return bbox_area((west, south, east, north))


def bbox_area(bbox) -> Area:
    """An Area from a (W, S, E, N) sequence, checked for order and range."""
    west, south, east, north = (float(value) for value in bbox)
    if not (-180 <= west <= 180 and -180 <= east <= 180 and -90 <= south <= 90 and -90 <= north <= 90):
        raise InputError(f"bbox {west},{south},{east},{north} is outside lon -180..180 / lat -90..90")
    if west >= east or south >= north:
        raise InputError(f"bbox {west},{south},{east},{north} is empty: need W < E and S < N (order W,S,E,N)")
    return Area((west, south, east, north), f"bbox {west},{south},{east},{north}")


def load_polygon(path: str | Path) -> Area:
    """The union of all Polygon/MultiPolygon geometries in a GeoJSON file (lon/lat, RFC 7946)."""
    import shapely
    from shapely.geometry import shape

    name = str(path)
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("polygon file not found", file=name) from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"cannot read polygon file: {error}", file=name) from None
    except json.JSONDecodeError as error:
        raise InputError(f"not valid JSON: {error.msg}", file=name, line=error.lineno) from None

    geometries = []
    for geometry in _geometries(document):
        if geometry.get("type") not in ("Polygon", "MultiPolygon"):
            raise InputError(f"expected Polygon or MultiPolygon geometries, found {geometry.get('type')}",
                             file=name)
        try:
            geometries.append(shape(geometry))
        except (ValueError, TypeError, AttributeError, IndexError) as error:
            raise InputError(f"malformed {geometry.get('type')}: {error}", file=name) from None
    if not geometries:
        raise InputError("no Polygon or MultiPolygon in the GeoJSON", file=name)
    polygon = shapely.make_valid(shapely.union_all(geometries))
    if polygon.is_empty or polygon.area == 0:
        raise InputError("the polygon has no area", file=name)
    shapely.prepare(polygon)
    west, south, east, north = polygon.bounds
    return Area((west, south, east, north), f"polygon {Path(path).name}", polygon)


def _geometries(document) -> list[dict]:
    if not isinstance(document, dict):
        return []
    kind = document.get("type")
    if kind == "FeatureCollection":
        return [geometry for feature in document.get("features") or [] for geometry in _geometries(feature)]
    if kind == "Feature":
        return _geometries(document.get("geometry") or {})
    if kind == "GeometryCollection":
        return [geometry for part in document.get("geometries") or [] for geometry in _geometries(part)]
    return [document] if kind else []
