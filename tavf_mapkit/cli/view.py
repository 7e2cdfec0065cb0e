"""``mapkit view``: a build and its drives in the browser (2D map, 3D view, replay), served on 127.0.0.1."""

from __future__ import annotations

import json
import sys

import click

from tavf_mapkit.cli.options import json_option


@click.command()
@click.argument("build", type=click.Path(file_okay=False, path_type=str))
@click.argument("runs", nargs=-1, type=click.Path(file_okay=False, path_type=str))
@click.option("--port", type=click.IntRange(0, 65535), default=8780, show_default=True,
              help="Port on 127.0.0.1 (0: any free port).")
@click.option("--no-browser", is_flag=True, help="Do not open a browser; just print the address.")
@click.option("--basemap", is_flag=True,
              help="Show OpenStreetMap's online tiles under the 2D map (off by default: the page needs no "
                   "internet otherwise).")
@click.option("-o", "--output", default=None, metavar="PAGE.html",
              help="Write the static 2D page (data embedded, like the build's report/index.html) and exit "
                   "instead of serving.")
@json_option
def view(build: str, runs: tuple[str, ...], port: int, no_browser: bool, basemap: bool, output: str | None,
         as_json: bool) -> None:
    """Show a build and the drives of RUN folders in the browser: 2D map, 3D view, replay.

    \b
    $ mapkit view build/sample                          # opens http://127.0.0.1:8780/
    $ mapkit view build/sample runs/a runs/b --port 0   # replay two `twin drive` outputs, any free port
    $ mapkit view build/sample -o sample.html           # the static 2D page, no server

    The 2D map (WGS84) shows the lanes coloured by type, road marks, signals, objects, junction outlines,
    every validation finding as a marker naming rule, road, lane and s, the roads the build repaired, and
    the GNSS trace with its matched path when the build's check stage had one. The 3D view shows the mesh
    tiles and the collision world (orbit, or fly with W/A/S/D/R/F and drag to look). Each RUN folder
    (`twin drive -o RUN`) is replayed on both with a time slider: ego, SUMO vehicles and pedestrians,
    UDM objects. The page is served on 127.0.0.1 only and needs no internet (--basemap adds online tiles).
    Stop it with Ctrl-C. See docs/view.md.
    """
    from tavf_mapkit.errors import InputError
    from tavf_mapkit.view.server import bind, create_app, load_view_data, open_in_browser, serve

    if output is not None:
        if runs:
            raise click.UsageError("-o/--output writes the static 2D page, which has no replay; give no RUN")
        _write_static(build, output, basemap, as_json)
        return
    view_data = load_view_data(build, runs, basemap=basemap)
    try:
        sock = bind(port)
    except OSError as error:
        raise InputError(f"cannot listen on 127.0.0.1:{port}: {error.strerror or error} "
                         f"(give another --port; 0 picks a free one)") from None
    url = f"http://127.0.0.1:{sock.getsockname()[1]}/"

    def ready() -> None:
        if as_json:
            click.echo(json.dumps({"url": url, "build": str(view_data.build_path), "runs": view_data.run_names}))
        else:
            click.echo(f"mapkit view: {url}  (Ctrl-C to stop)", err=True)
        sys.stdout.flush()
        if not no_browser and not open_in_browser(url):
            click.echo("mapkit view: no display to open a browser on; open the address above", err=True)

    serve(create_app(view_data), sock, on_ready=ready)


def _write_static(build: str, output: str, basemap: bool, as_json: bool) -> None:
    from tavf_mapkit.fileutil import write_text_atomic
    from tavf_mapkit.view.mapdata import build_map_data
    from tavf_mapkit.view.page import static_map
    from twin.sim.build import Build

    opened = Build.open(build)
    data = build_map_data(opened)
    head, body = static_map(data, basemap=basemap)
    import html

    title = html.escape(f"mapkit view: {data['name']}")
    write_text_atomic(output, f"<!doctype html>\n<html lang='en'><head><meta charset='utf-8'><title>{title}"
                              f"</title>{head}<style>body{{margin:0}}.report-map{{height:100vh}}</style></head>"
                              f"<body>{body}</body></html>\n")
    if as_json:
        click.echo(json.dumps({"output": output, "lanes": data["lane_count"],
                               "findings": len(data["layers"]["findings"]["features"])}))
    else:
        click.echo(f"wrote {output}: {data['lane_count']} lanes, "
                   f"{len(data['layers']['findings']['features'])} findings", err=True)
