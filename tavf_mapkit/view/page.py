"""The HTML of the views: the live page ``mapkit view`` serves, and the static 2D map of report/index.html
(everything inline -- Leaflet, its stylesheet with its images as data URIs, the page's script and the map
data -- so the file opens from disk, by e-mail, with no server and no internet)."""

from __future__ import annotations

import base64
import json
import re

from tavf_mapkit.view.server import STATIC


def live_page(*, basemap: bool = False, live: dict | None = None) -> str:
    """static/index.html with the page's options filled in (``live``: the page follows a running drive)."""
    html = (STATIC / "index.html").read_text(encoding="utf-8")
    options = {"basemap": bool(basemap)} | ({"live": live} if live is not None else {})
    return html.replace("/*OPTIONS*/{}/*END*/", json.dumps(options))


def _script(text: str) -> str:
    # "</script" inside a script would end it early; "<\/" means the same to JavaScript
    return "<script>" + text.replace("</", "<\\/") + "</script>"


def _leaflet_css() -> str:
    """leaflet.css with url(images/x.png) turned into data URIs (no file beside the report to point to)."""
    folder = STATIC / "vendor" / "leaflet"
    css = (folder / "leaflet.css").read_text(encoding="utf-8")

    def inline(match: re.Match) -> str:
        image = folder / "images" / match.group(1)
        if not image.is_file():
            return match.group(0)
        return "url(data:image/png;base64," + base64.b64encode(image.read_bytes()).decode("ascii") + ")"

    return re.sub(r"url\(images/([\w.-]+\.png)\)", inline, css)


def static_map(data: dict, *, element_id: str = "map", basemap: bool = False) -> tuple[str, str]:
    """(head, body) HTML of a self-contained 2D map of ``data`` (mapdata.map_data): styles for the head,
    the map's element and scripts for the body."""
    head, body = static_map_parts(json.dumps(data, separators=(",", ":"), allow_nan=False),
                                  element_id=element_id, basemap=basemap)
    return head, "".join(body)


def static_map_parts(payload, *, element_id: str = "map", basemap: bool = False) -> tuple[str, list[str]]:
    """static_map of the map's JSON text, given as a string or as pieces (mapdata.map_json), with the body
    as pieces: a city's map is tens of megabytes, written piece by piece instead of copied into one string."""
    head = "<style>" + _leaflet_css() + (STATIC / "map2d.css").read_text(encoding="utf-8") + "</style>"
    pieces = [payload] if isinstance(payload, str) else payload
    body = [f"<div id='{element_id}' class='report-map'></div>"
            + _script((STATIC / "vendor" / "leaflet" / "leaflet.js").read_text(encoding="utf-8"))
            + _script((STATIC / "map2d.js").read_text(encoding="utf-8")) + "<script>window.MAPKIT_DATA = "]
    # _script's escape piece by piece: no piece ends in "<" (JSON text ends a piece with a value or a
    # separator), so no "</" is split between two
    body += [piece.replace("</", "<\\/") for piece in pieces]
    body.append((f";\nwindow.mapkit = {{data: window.MAPKIT_DATA, map2d: window.MapkitMap2D("
                 f"document.getElementById({json.dumps(element_id)}), window.MAPKIT_DATA, "
                 f"{json.dumps({'basemap': bool(basemap)})})}};").replace("</", "<\\/") + "</script>")
    return head, body
