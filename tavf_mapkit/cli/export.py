"""``mapkit export``: vector layers of an OpenDRIVE map as CSV or GeoJSON."""

from __future__ import annotations

import csv
import io
import json
import sys

import click
import numpy as np

from tavf_mapkit.cli.options import output_option, step_option, xodr_argument
from tavf_mapkit.errors import InputError
from tavf_mapkit.opendrive.layers import LAYERS


@click.command()
@xodr_argument()
@click.option("--layer", type=click.Choice(LAYERS), required=True, help="Which layer to export.")
@step_option
@click.option("--crs", default=None,
              help="local (the file's own frame), wgs84, or EPSG:NNNN. Default: local for csv, wgs84 for geojson.")
@click.option("--format", "fmt", type=click.Choice(["csv", "geojson"]), default="geojson", show_default=True)
@click.option("--precision", type=click.IntRange(0, 12), default=None,
              help="Decimals of coordinates (default: 6 for metres, 9 for degrees).")
@output_option
def export(xodr: str, layer: str, step: float, crs: str | None, fmt: str, precision: int | None, output: str) -> None:
    """Export a layer of an OpenDRIVE map.

    \b
    $ mapkit export map.xodr --layer lane-border --format csv -o borders.csv
    $ mapkit export map.xodr --layer lane --format geojson -o lanes.geojson   # opens in QGIS
    $ mapkit export map.xodr --layer lane-center --crs EPSG:25832 --format csv -

    Layers (after GDAL's XODR driver): reference-line, lane-border, lane-center, lane (polygons),
    road-mark, object, signal. CSV columns are a contract other tools rely on:
    lane-border: road,section_s0,lane,s,x,y,z (outer border of every lane but lane 0, sampled at s0,
    s0+step, ... and the section end; lane heights not applied); lane-center:
    road,section_s0,lane,type,s,x,y,z (lane heights applied). Other layers in CSV list their vertices.
    """
    from tavf_mapkit.opendrive import load_opendrive

    odr = load_opendrive(xodr)
    crs = (crs or ("local" if fmt == "csv" else "wgs84")).strip()
    transform = _transform(odr, crs, xodr)
    degrees = crs.lower() == "wgs84" or crs.upper() in ("EPSG:4326", "EPSG:4258")
    digits = precision if precision is not None else (9 if degrees else 6)

    stream = sys.stdout if output == "-" else io.StringIO()
    if fmt == "csv" and layer in ("lane-border", "lane-center"):
        _lane_csv(odr, layer, step, transform, digits, stream)
    elif fmt == "csv":
        _features_csv(odr, layer, step, transform, digits, stream)
    else:
        _geojson(odr, layer, step, transform, digits, crs, stream)
    if output != "-":
        from tavf_mapkit.fileutil import write_text_atomic

        write_text_atomic(output, stream.getvalue())


def _transform(odr, crs: str, name: str):
    if crs.lower() == "local":
        return lambda x, y: (x, y)
    geo = odr.georeference
    if geo is None:
        raise InputError("has no <geoReference>: only --crs local is possible", file=name)
    if crs.lower() == "wgs84":
        return geo.local_to_wgs84
    try:
        import pyproj

        pyproj.CRS.from_user_input(crs)
    except Exception:
        raise click.BadParameter(f"{crs!r} is not a CRS PROJ understands (try EPSG:25832)", param_hint="--crs")
    return lambda x, y: geo.local_to_crs(x, y, crs)


def _lane_csv(odr, layer, step, transform, digits, stream) -> None:
    from tavf_mapkit.opendrive.sampling import sample_lanes

    sampling = sample_lanes(odr, step)
    points = sampling.outer_border_points() if layer == "lane-border" else sampling.center_points()
    x, y = transform(points[:, 0], points[:, 1])
    road_ids = np.array([road.id for road in odr.roads], dtype=object)
    columns = [road_ids[sampling.road_index], _fmt(sampling.section_s0, 6), sampling.lane_id.astype(str)]
    header = ["road", "section_s0", "lane"]
    if layer == "lane-center":
        columns.append(sampling.lane_type)
        header.append("type")
    columns += [_fmt(sampling.s, 6), _fmt(np.asarray(x), digits), _fmt(np.asarray(y), digits), _fmt(points[:, 2], 6)]
    header += ["s", "x", "y", "z"]
    stream.write(",".join(header) + "\n")
    if len(sampling.s):
        rows = np.column_stack(columns).astype(str)
        stream.write("\n".join(",".join(row) for row in rows))
        stream.write("\n")


def _fmt(values: np.ndarray, digits: int) -> np.ndarray:
    return np.char.mod(f"%.{digits}f", np.asarray(values, dtype=float))


def _features_csv(odr, layer, step, transform, digits, stream) -> None:
    from tavf_mapkit.opendrive.layers import layer_features

    writer = csv.writer(stream, lineterminator="\n")
    header_written = False
    for number, feature in enumerate(layer_features(odr, layer, step)):
        keys = list(feature.properties)
        if not header_written:
            writer.writerow(["feature", *keys, "vertex", "x", "y", "z"])
            header_written = True
        x, y = transform(feature.coordinates[:, 0], feature.coordinates[:, 1])
        x, y = np.atleast_1d(x), np.atleast_1d(y)
        for k in range(len(x)):
            writer.writerow([number, *[feature.properties[key] for key in keys], k, f"{x[k]:.{digits}f}",
                             f"{y[k]:.{digits}f}", f"{feature.coordinates[k, 2]:.6f}"])


def _geojson(odr, layer, step, transform, digits, crs, stream) -> None:
    from tavf_mapkit.opendrive.layers import layer_features

    features = []
    for feature in layer_features(odr, layer, step):
        x, y = transform(feature.coordinates[:, 0], feature.coordinates[:, 1])
        coords = np.column_stack([np.round(np.atleast_1d(x), digits), np.round(np.atleast_1d(y), digits),
                                  np.round(feature.coordinates[:, 2], 4)]).tolist()
        if feature.kind == "Point":
            geometry = {"type": "Point", "coordinates": coords[0]}
        elif feature.kind == "Polygon":
            geometry = {"type": "Polygon", "coordinates": [coords]}
        else:
            geometry = {"type": "LineString", "coordinates": coords}
        features.append({"type": "Feature", "geometry": geometry, "properties": _jsonable(feature.properties)})
    collection = {"type": "FeatureCollection", "features": features}
    if crs.lower() != "wgs84":
        collection["crs"] = {"type": "name", "properties": {"name": crs}}
    json.dump(collection, stream, separators=(",", ":"))
    stream.write("\n")


def _jsonable(properties: dict) -> dict:
    out = {}
    for key, value in properties.items():
        if isinstance(value, (np.floating, float)):
            value = float(value) if np.isfinite(value) else None
        elif isinstance(value, np.integer):
            value = int(value)
        out[key] = value
    return out
