"""Options shared by several subcommands (the rasterio ``rio/options.py`` pattern)."""

from __future__ import annotations

from pathlib import Path

import click

from tavf_mapkit.errors import InputError


class BBoxType(click.ParamType):
    """``W,S,E,N`` in degrees -> an Area; a malformed box is a usage error (exit code 2)."""

    name = "W,S,E,N"

    def convert(self, value, param, ctx):
        from tavf_mapkit.osm.area import Area, parse_bbox

        if isinstance(value, Area):
            return value
        try:
            return parse_bbox(value)
        except InputError as error:
            self.fail(error.message, param, ctx)


bbox_option = click.option(
    "--bbox", type=BBoxType(), default=None,
    help="Area to keep: west,south,east,north in degrees (e.g. 9.95,53.543,10.01,53.57).",
)
polygon_option = click.option(
    "--polygon", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="AREA.geojson",
    help="Area to keep: a GeoJSON file with Polygon/MultiPolygon geometries (lon/lat).",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON for machines instead of text.")
output_option = click.option("-o", "--output", default="-", show_default=True,
                             help="Output file, or - for standard output.")
step_option = click.option("--step", type=click.FloatRange(min=0.001), default=0.5, show_default=True,
                           help="Sampling step along s in metres.")


def xodr_argument(name: str = "xodr"):
    return click.argument(name, type=click.Path(dir_okay=False, path_type=str))


def area_from(bbox, polygon: Path | None):
    """The Area of --bbox or --polygon (at most one), or None for the whole file."""
    if bbox is not None and polygon is not None:
        raise click.UsageError("give --bbox or --polygon, not both")
    if polygon is not None:
        from tavf_mapkit.osm.area import load_polygon

        return load_polygon(polygon)
    return bbox
