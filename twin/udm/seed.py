"""Fill a UDM store with a build folder's traffic signs and signals (layer 2, no expiry).

Each seed source is a function ``build_dir -> objects``; ``SEED_SOURCES`` lists them in the order they run.
A later source replaces an earlier one's object when both use the same id. Sources: OSM nodes of the build's
OSM input, ``signals.geojson``, and the OpenDRIVE ``<signal>``/``<object>`` elements of the build's map
(``twin.udm.seed_opendrive``).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import osmium

from tavf_mapkit.errors import InputError
from twin.udm.model import InvalidObject, Layer, UdmObject
from twin.udm.seed_opendrive import objects_from_opendrive
from twin.udm.store import Store

SEED_LAYER = int(Layer.TRANSIENT_STATIC)
SIGNALS_GEOJSON = "signals.geojson"
OSM_PATTERNS = ("*.osm", "*.osm.pbf", "*.osm.bz2", "*.osm.gz")
BATCH_SIZE = 5000

# highway=* values that are signs or signals in their own right, strongest first: a node tagged both
# highway=traffic_signals and crossing=* is a signal-controlled crossing, and the signal is what a car obeys.
OSM_HIGHWAY_TYPES = ("traffic_signals", "stop", "give_way", "crossing")
OSM_CLASS_TAGS = {"traffic_signals": "traffic_signals", "crossing": "crossing"}  # type -> tag naming the kind
COMPASS_POINTS = ("N", "NNE", "NE", "ENE", "E", "ESE", "SE", "SSE",
                  "S", "SSW", "SW", "WSW", "W", "WNW", "NW", "NNW")
CARDINAL_DEGREES = {name: index * 22.5 for index, name in enumerate(COMPASS_POINTS)}


@dataclass(frozen=True)
class SeedSource:
    name: str
    objects: Callable[[Path], Iterable[UdmObject]]


def seed_from_build(store: Store, build_dir: str | Path,
                    sources: Iterable[SeedSource] | None = None) -> dict[str, int]:
    """Load every seed source of ``build_dir`` into ``store``; returns how many objects each source gave."""
    build_dir = Path(build_dir)
    if not build_dir.is_dir():
        raise InputError("the --map build folder does not exist", file=str(build_dir))
    counts = {}
    for source in SEED_SOURCES if sources is None else sources:
        counts[source.name] = 0
        objects = iter(source.objects(build_dir))
        # Batches keep memory flat on a city-sized OSM file and make each batch one transaction.
        while batch := list(islice(objects, BATCH_SIZE)):
            store.upsert(batch)
            counts[source.name] += len(batch)
    return counts


# --- OSM nodes --------------------------------------------------------------------------------------------


def objects_from_osm_files(build_dir: Path) -> Iterator[UdmObject]:
    """Signal and sign nodes from every OSM file in the build folder (searched recursively)."""
    paths = sorted({path for pattern in OSM_PATTERNS for path in build_dir.rglob(pattern)})
    for path in paths:
        yield from objects_from_osm_file(path)


def objects_from_osm_file(path: Path) -> Iterator[UdmObject]:
    """UDM objects for nodes tagged highway=traffic_signals|stop|give_way|crossing or traffic_sign=*."""
    source = f"osm:{path.name}"
    try:
        nodes = osmium.FileProcessor(str(path), osmium.osm.NODE).with_filter(
            osmium.filter.KeyFilter("highway", "traffic_sign")
        )
        for node in nodes:
            obj = object_from_osm_tags(node.id, node.location, dict(node.tags), source)
            if obj is not None:
                yield obj
    except RuntimeError as error:  # libosmium reports unreadable files as RuntimeError
        raise InputError(f"cannot read OSM data: {error}", file=str(path)) from None


def object_from_osm_tags(node_id: int, location, tags: dict[str, str], source: str) -> UdmObject | None:
    """The UDM object one OSM node stands for, or None when its tags name no sign or signal."""
    highway = tags.get("highway")
    sign = tags.get("traffic_sign")
    if highway in OSM_HIGHWAY_TYPES:
        type_ = highway
    elif sign:
        type_ = "traffic_sign"
    else:
        return None
    if not location.valid():
        return None
    # The sign code (e.g. DE:206) is the most specific class; otherwise the tag that refines the type.
    class_tag = OSM_CLASS_TAGS.get(type_)
    object_class = sign or (tags.get(class_tag, "") if class_tag else "")
    return UdmObject(
        id=f"osm-node-{node_id}",
        layer=SEED_LAYER,
        type=type_,
        object_class=object_class[:64],
        name=tags.get("name", "")[:256],
        lat=location.lat,
        lon=location.lon,
        heading=osm_direction_degrees(tags.get("direction") or tags.get("traffic_signals:direction")),
        source=source,
    )


def osm_direction_degrees(direction: str | None) -> float | None:
    """Compass degrees from an OSM ``direction`` (``45``, ``NE``); None for forward/backward or ranges.

    ``forward``/``backward`` are relative to the way the node sits on, which a node-only pass cannot see;
    the OpenDRIVE seeding knows the road direction of the signals netconvert built from these nodes.
    """
    if not direction:
        return None
    direction = direction.strip().upper()
    if direction in CARDINAL_DEGREES:
        return CARDINAL_DEGREES[direction]
    if re.fullmatch(r"-?\d+(\.\d+)?", direction):
        degrees = float(direction)
        return degrees % 360.0 if math.isfinite(degrees) else None
    return None


# --- signals.geojson -------------------------------------------------------------------------------------


def objects_from_signals_geojson(build_dir: Path) -> Iterator[UdmObject]:
    """Points from ``signals.geojson`` at the top of the build folder (absent file: nothing)."""
    path = build_dir / SIGNALS_GEOJSON
    if not path.is_file():
        return
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"cannot read GeoJSON: {error}", file=str(path)) from None
    if not isinstance(document, dict) or document.get("type") != "FeatureCollection":
        raise InputError("expected a GeoJSON FeatureCollection", file=str(path))
    features = document.get("features")
    if not isinstance(features, list):
        raise InputError("FeatureCollection.features must be a list", file=str(path))
    for index, feature in enumerate(features):
        try:
            yield UdmObject.from_feature(
                feature, default_id=f"signals-{index}", default_layer=SEED_LAYER,
                default_source=SIGNALS_GEOJSON,
            )
        except InvalidObject as error:
            raise InputError(f"features[{index}]: {error}", file=str(path)) from None


SEED_SOURCES: list[SeedSource] = [
    SeedSource("osm", objects_from_osm_files),
    SeedSource(SIGNALS_GEOJSON, objects_from_signals_geojson),
    SeedSource("opendrive", objects_from_opendrive),
]
