"""The page server of ``mapkit view``: a starlette app on 127.0.0.1 only.

Everything the page needs is computed before the server starts (a map that cannot be read fails the command
in one line, not the page), serialised once and served from memory; the build's mesh and collision folders
and the vendored JavaScript are served as static files. Routes:

    /                  the page (tavf_mapkit/view/static/index.html)
    /api/map           map_data of the build (WGS84 GeoJSON layers, findings, repairs, GNSS)
    /api/scene         scene_data: mesh tiles and collision bodies for the 3D view
    /api/runs          [{index, name}] of the run folders given
    /api/runs/N        the replay of run N
    /build/mesh/...    the build's mesh/ folder;  /build/collision/...  its collision/ folder
    /static/...        the page's own files and the vendored Leaflet and three.js
    /api/live          with ``live`` (``twin drive --view``, view/live.py): the running drive's latest state
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

STATIC = Path(__file__).resolve().parent / "static"
HOST = "127.0.0.1"  # loopback only: the page serves the build's files to whoever can connect


@dataclass
class ViewData:
    """The serialised answers of the API, computed once."""

    map_json: bytes
    scene_json: bytes
    runs: list[bytes] = field(default_factory=list)
    run_names: list[str] = field(default_factory=list)
    build_path: Path | None = None
    basemap: bool = False


def load_view_data(build_path, run_paths=(), *, basemap: bool = False) -> ViewData:
    """Read a build folder and run folders into a ViewData (InputError on anything unreadable)."""
    from tavf_mapkit.opendrive.snapshot import load_build_map
    from tavf_mapkit.view.mapdata import build_map_data, display_georeference
    from tavf_mapkit.view.runs import load_run
    from tavf_mapkit.view.scene import scene_data
    from twin.sim.build import Build

    build = Build.open(build_path)
    odr = load_build_map(build.xodr)
    data = build_map_data(build, odr)
    georef, _ = display_georeference(odr)
    runs = [load_run(path, georef) for path in run_paths]
    for run in runs:
        _add_udm_local(run, georef)
        driven_on = (run.get("config") or {}).get("map_sha256")
        if driven_on and driven_on != build.map_sha256:
            # still shown (the roads may be the same), but said: positions may not fit this build's lanes
            run["notes"].insert(0, "driven on another build of the map (its OpenDRIVE sha256 differs)")
    return ViewData(map_json=_dumps(data), scene_json=_dumps(scene_data(build.path)),
                    runs=[_dumps(run) for run in runs], run_names=[run["name"] for run in runs],
                    build_path=build.path, basemap=basemap)


def _add_udm_local(run: dict, georef) -> None:
    """UDM objects come in WGS84; the 3D view needs them in the local frame too."""
    import numpy as np

    objects = [obj for answer in run.get("udm") or () for obj in answer["objects"]
               if obj.get("lat") is not None and obj.get("lon") is not None]
    if not objects:
        return
    x, y = georef.wgs84_to_local([obj["lon"] for obj in objects], [obj["lat"] for obj in objects])
    for obj, ox, oy in zip(objects, np.atleast_1d(x), np.atleast_1d(y)):
        obj["x"], obj["y"] = round(float(ox), 3), round(float(oy), 3)


def _dumps(data) -> bytes:
    return json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8")


def create_app(view: ViewData, live=None):
    """The starlette app serving one ViewData (or anything with its attributes, e.g. live.LazyViewData);
    ``live``: a live.LiveState whose latest state ``/api/live`` serves, and the page then follows."""
    from starlette.applications import Starlette
    from starlette.responses import HTMLResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    def json_response(body: bytes) -> Response:
        return Response(body, media_type="application/json")

    async def page(request):
        from tavf_mapkit.view.page import live_page

        return HTMLResponse(live_page(basemap=view.basemap, live=None if live is None else live.page_options()))

    # plain functions, run in starlette's thread pool: a lazily computed map must not stall the event loop
    def api_map(request):
        return json_response(view.map_json)

    def api_scene(request):
        return json_response(view.scene_json)

    async def api_runs(request):
        return json_response(_dumps([{"index": i, "name": name} for i, name in enumerate(view.run_names)]))

    async def api_run(request):
        index = request.path_params["index"]
        if not 0 <= index < len(view.runs):
            return Response(f"no run {index}\n", status_code=404, media_type="text/plain")
        return json_response(view.runs[index])

    routes = [Route("/", page), Route("/api/map", api_map), Route("/api/scene", api_scene),
              Route("/api/runs", api_runs), Route("/api/runs/{index:int}", api_run),
              Mount("/static", app=StaticFiles(directory=STATIC), name="static")]
    if live is not None:
        async def api_live(request):
            return Response(live.body(), media_type="application/json", headers={"Cache-Control": "no-store"})

        routes.append(Route("/api/live", api_live))
    if view.build_path is not None:
        for folder in ("mesh", "collision"):
            if (view.build_path / folder).is_dir():
                routes.append(Mount(f"/build/{folder}", app=StaticFiles(directory=view.build_path / folder)))
    return Starlette(routes=routes)


def has_display() -> bool:
    """Whether a browser can open a window here (else webbrowser may start a text browser in the terminal)."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def open_in_browser(url: str) -> bool:
    """Open ``url`` in the desktop's browser, off this thread (a browser that takes its time must not hold up the
    server); False where there is no display to open one on."""
    if not has_display():
        return False
    import threading
    import webbrowser

    threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()
    return True


def bind(port: int):
    """A listening socket on 127.0.0.1:port (0: a free port); OSError when it is taken."""
    import socket

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((HOST, port))
        sock.listen(128)
    except OSError:
        sock.close()
        raise
    return sock


def make_server(app, on_ready=None):
    """A uvicorn.Server for ``app`` that calls ``on_ready()`` once it listens (set ``should_exit`` to stop it)."""
    import uvicorn

    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off",
                            timeout_graceful_shutdown=2)  # a page still fetching never holds the stop up for long
    server = uvicorn.Server(config)
    if on_ready is not None:
        startup = server.startup

        async def started(sockets=None):
            await startup(sockets=sockets)
            on_ready()

        server.startup = started
    return server


def serve(app, sock, on_ready=None) -> None:
    """Serve until Ctrl-C or SIGTERM (uvicorn handles both and shuts down cleanly)."""
    make_server(app, on_ready).run(sockets=[sock])
