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
from tavf_mapkit.opendrive.layers import LAYERS, geojson_feature


class LatLonType(click.ParamType):
    """``LAT,LON`` in degrees."""

    name = "LAT,LON"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        try:
            lat, lon = (float(part) for part in str(value).split(","))
        except ValueError:
            self.fail(f"{value!r} is not LAT,LON in degrees (e.g. 51.5074,-0.1278)", param, ctx)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            self.fail(f"{value!r} lies outside -90..90, -180..180", param, ctx)
        return lat, lon


#: options of the layer export that mean nothing for a whole-map format (--to)
_LAYER_ONLY = ("crs", "fmt", "precision")


@click.command()
@xodr_argument()
@click.option("--layer", type=click.Choice(LAYERS), default=None, help="Which layer to export.")
@click.option("--to", "target", type=click.Choice(["lanelet2"]), default=None,
              help="Export the whole map in another map format instead of a layer: lanelet2 (OSM XML).")
@step_option
@click.option("--eps", type=click.FloatRange(min=0.001), default=0.01, show_default=True,
              help="With --to: largest distance (m) of a bound from the exact lane border; adaptive samples "
                   "(give --step for a fixed step instead).")
@click.option("--origin", type=LatLonType(), default=None,
              help="With --to, for a map without <geoReference>: where its local (0, 0) lies.")
@click.option("--crs", default=None,
              help="local (the file's own frame), wgs84, or EPSG:NNNN. Default: local for csv, wgs84 for geojson.")
@click.option("--format", "fmt", type=click.Choice(["csv", "geojson"]), default="geojson", show_default=True)
@click.option("--precision", type=click.IntRange(0, 12), default=None,
              help="Decimals of coordinates (default: 6 for metres, 9 for degrees).")
@output_option
@click.option("--json", "as_json", is_flag=True,
              help="With --to: print what the map file holds (counts, origin, warnings) as JSON on standard "
                   "output (the map then needs -o FILE).")
@click.pass_context
def export(ctx: click.Context, xodr: str, layer: str | None, target: str | None, step: float, eps: float,
           origin: tuple[float, float] | None, crs: str | None, fmt: str, precision: int | None,
           output: str, as_json: bool) -> None:
    """Export a layer of an OpenDRIVE map, or the whole map as Lanelet2.

    \b
    $ mapkit export map.xodr --layer lane-border --format csv -o borders.csv
    $ mapkit export map.xodr --layer lane --format geojson -o lanes.geojson   # opens in QGIS
    $ mapkit export map.xodr --layer lane-center --crs EPSG:25832 --format csv -
    $ mapkit export build/NAME/NAME.xodr --to lanelet2 -o map.osm
    $ mapkit export map.xodr --to lanelet2 -o map.osm --json | jq .origin

    Layers (after GDAL's XODR driver): reference-line, lane-border, lane-center, lane (polygons),
    road-mark, object, signal. CSV columns are a contract other tools rely on:
    lane-border: road,section_s0,lane,s,x,y,z (outer border of every lane but lane 0, sampled at s0,
    s0+step, ... and the section end; lane heights not applied); lane-center:
    road,section_s0,lane,type,s,x,y,z (lane heights applied). Other layers in CSV list their vertices.

    --to lanelet2 writes a Lanelet2 OSM file instead: one lanelet per lane and lane section, bounds shared
    with the neighbours, road marks as line types, signals as regulatory elements, every node at its WGS84
    position (--format, --crs and --precision do not apply). Load it with the origin the command prints, the
    local (0, 0) of the map (for our builds +lat_0/+lon_0 of the projection):
    lanelet2.io.load(path, lanelet2.projection.LocalCartesianProjector(lanelet2.io.Origin(LAT, LON))) gives
    back the OpenDRIVE x, y (to millimetres within a few km), UtmProjector the UTM easting/northing relative to
    the origin's. See docs/export.md.
    """
    from tavf_mapkit.opendrive.snapshot import load_build_map  # the build's snapshot when the file has one

    if (layer is None) == (target is None):
        raise click.UsageError("give either --layer LAYER or --to lanelet2")
    if target is not None:
        given = [name for name in _LAYER_ONLY
                 if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT]
        if given:
            option = {"fmt": "--format"}.get(given[0], f"--{given[0]}")
            raise click.UsageError(f"{option} is for --layer; --to {target} writes its own format")
        if as_json and output == "-":
            raise click.UsageError("--json prints the summary on standard output: write the map with -o FILE")
        fixed_step = step if ctx.get_parameter_source("step") is not click.core.ParameterSource.DEFAULT else None
        _export_lanelet2(load_build_map(xodr), xodr, output, eps, fixed_step, origin, as_json)
        return
    for name in ("eps", "origin", "as_json"):
        if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
            option = {"as_json": "--json"}.get(name, f"--{name}")
            raise click.UsageError(f"{option} is for --to lanelet2")

    odr = load_build_map(xodr)
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


def _export_lanelet2(odr, xodr: str, output: str, eps: float, step: float | None,
                     origin: tuple[float, float] | None, as_json: bool) -> None:
    from tavf_mapkit.lanelet2_export import export_lanelet2

    summary = export_lanelet2(odr, output, eps=eps, step=step, origin=origin, name=xodr)
    if as_json:
        click.echo(json.dumps({"output": output, **summary}, indent=2))
        return
    lat, lon = summary["origin"]
    sampling = f"every {step:g} m" if step is not None else f"within {eps:g} m"
    click.echo(f"lanelet2: {summary['lanelets']} lanelets, {summary['ways']} ways, {summary['nodes']} nodes, "
               f"{summary['regulatory_elements']} regulatory elements; bounds {sampling} of the lane borders", err=True)
    click.echo(f"origin  lat {lat:.10f} lon {lon:.10f} (local 0, 0): lanelet2.io.load(path, "
               f"lanelet2.projection.LocalCartesianProjector(lanelet2.io.Origin({lat:.10f}, {lon:.10f})))", err=True)
    for key, what in (("unjoined_lane_ends", "linked lane ends lie more than 10 cm apart: not joined"),
                      ("narrow_lanes_left_out", "lanes narrower than 1 cm everywhere: left out"),
                      ("private_bounds", "inside-out lanes given bounds of their own (no lane change there)"),
                      ("turned", "lanelets Lanelet2 will read against their lane (inside out)")):
        if summary.get(key):
            click.echo(f"warning {summary[key]} {what}", err=True)


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
    except pyproj.exceptions.CRSError:
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
        features.append(geojson_feature(feature, coords))
    collection = {"type": "FeatureCollection", "features": features}
    if crs.lower() != "wgs84":
        collection["crs"] = {"type": "name", "properties": {"name": crs}}
    json.dump(collection, stream, separators=(",", ":"))
    stream.write("\n")


