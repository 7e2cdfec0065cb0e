"""The UDM as an HTTP service: a starlette app over a ``Store``, and the uvicorn runners that serve it.

Reads (``GET /objects``) are open; writes (``POST``/``DELETE``) need ``Authorization: Bearer TOKEN``.
Every refusal is JSON ``{"error": code, "message": text}`` so a client can log it without guessing.
Handlers are ``async`` and call the store directly: a query takes well under a millisecond, far less than a
hop to a worker thread would cost, and the 10 Hz queries of a vehicle fleet are exactly this hot path.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import socket
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any, Self

import uvicorn
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from twin import __version__
from twin.udm.model import ID_PATTERN, BBox, InvalidObject, Layer, UdmObject, iso_utc, parse_layer
from twin.udm.priority import realtime_policy
from twin.udm.store import DEFAULT_LIMIT, Store

# Query limits, documented in docs/udm-api.md and the OpenAPI document. They keep one careless request from
# serialising a whole city: a vehicle asks for a few hundred metres around itself.
MAX_BBOX_AREA_KM2 = 1000.0
MAX_RADIUS_M = 15_000.0
MAX_LIMIT = 10_000
MAX_FEATURES_PER_POST = 10_000
MAX_BODY_BYTES = 16 * 1024 * 1024
DEFAULT_PURGE_INTERVAL_S = 60.0
WRITE_SLICE = 500

QUERY_PARAMETERS = {"bbox", "lat", "lon", "radius", "layers", "types", "limit"}
GEOJSON = "application/geo+json"

log = logging.getLogger("twin.udm")


class ApiError(Exception):
    """A request the API refuses; becomes a JSON answer with ``status`` (400 unless said otherwise)."""

    def __init__(self, message: str, status: int = 400, code: str = "bad_request") -> None:
        super().__init__(message)
        self.message, self.status, self.code = message, status, code


class GeoJSONResponse(JSONResponse):
    media_type = GEOJSON


def create_app(store: Store, token: str, *, purge_interval_s: float = DEFAULT_PURGE_INTERVAL_S) -> Starlette:
    """The UDM app over ``store``; ``token`` guards writes, expired objects are purged every interval."""
    if not token:
        raise ValueError("a UDM server needs a non-empty write token")
    expected = f"Bearer {token}".encode()

    def authorised(request: Request) -> bool:
        # compare_digest: a plain == leaks how many leading characters of a guess were right.
        return hmac.compare_digest(request.headers.get("authorization", "").encode(), expected)

    async def landing(request: Request) -> Response:
        return JSONResponse({
            "title": "twin Urban Dynamic Map",
            "links": [
                {"rel": "service-desc", "href": "/openapi.json", "type": "application/vnd.oai.openapi+json"},
                {"rel": "items", "href": "/objects", "type": GEOJSON},
                {"rel": "status", "href": "/health", "type": "application/json"},
            ],
        })

    async def health(request: Request) -> Response:
        return JSONResponse({"status": "ok", "version": __version__, "objects": store.count()})

    async def openapi(request: Request) -> Response:
        return JSONResponse(openapi_document())

    async def list_objects(request: Request) -> Response:
        query = parse_object_query(request.query_params.multi_items())
        now = time.time()
        fetch = query["limit"] + 1  # one extra row tells us the answer was cut
        filters = {"layers": query["layers"], "types": query["types"], "now": now, "limit": fetch}
        if "bbox" in query:
            objects = store.in_bbox(query["bbox"], **filters)
        else:
            objects = store.within_radius(query["lat"], query["lon"], query["radius"], **filters)
        truncated = len(objects) > query["limit"]
        features = [obj.to_feature() for obj in objects[: query["limit"]]]
        return GeoJSONResponse({
            "type": "FeatureCollection",
            "timeStamp": iso_utc(now),
            "numberReturned": len(features),
            "truncated": truncated,
            "features": features,
        })

    async def get_object(request: Request) -> Response:
        obj = store.get(request.path_params["object_id"])
        if obj is None:
            raise ApiError(f"no object {request.path_params['object_id']!r}", 404, "not_found")
        return GeoJSONResponse(obj.to_feature())

    async def post_objects(request: Request) -> Response:
        if not authorised(request):
            return unauthorised()
        document = await read_json_body(request)
        objects, single = objects_from_document(document)
        stored = []
        # Everything was validated above, so writing in slices cannot leave half a bad request behind; the
        # pause between slices lets the fleet's queries through while a big batch is loaded.
        for start in range(0, len(objects), WRITE_SLICE):
            stored += store.upsert(objects[start:start + WRITE_SLICE])
            await asyncio.sleep(0)
        if single:
            headers = {"Location": f"/objects/{stored[0].id}"}
            return GeoJSONResponse(stored[0].to_feature(), status_code=201, headers=headers)
        return GeoJSONResponse(
            {"type": "FeatureCollection", "numberReturned": len(stored),
             "features": [obj.to_feature() for obj in stored]},
            status_code=201,
        )

    async def delete_object(request: Request) -> Response:
        if not authorised(request):
            return unauthorised()
        object_id = request.path_params["object_id"]
        if not store.delete(object_id):
            raise ApiError(f"no object {object_id!r}", 404, "not_found")
        return Response(status_code=204)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette):
        purger = asyncio.create_task(purge_periodically(store, purge_interval_s))
        try:
            yield
        finally:
            purger.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await purger

    routes = [
        Route("/", landing),
        Route("/health", health),
        Route("/openapi.json", openapi),
        Route("/objects", list_objects, methods=["GET"]),
        Route("/objects", post_objects, methods=["POST"]),
        Route("/objects/{object_id}", get_object, methods=["GET"]),
        Route("/objects/{object_id}", delete_object, methods=["DELETE"]),
    ]
    handlers = {ApiError: api_error, HTTPException: http_exception, Exception: internal_error}
    app = Starlette(routes=routes, exception_handlers=handlers, lifespan=lifespan,
                    middleware=[Middleware(ServerTiming)])
    app.state.store = store
    return app


class ServerTiming:
    """Adds ``Server-Timing: app;dur=MS`` to every answer: milliseconds from the request reaching the app to its
    answer's headers (parameter checks, the store, rendering JSON). What a client measures beyond it is the
    network, uvicorn's HTTP parsing and the waits of both ends for a core: with it a fleet's latency can be
    split into the server's own work and everything else (benchmarks/bench_udm_fleet.py). A pure ASGI
    wrapper, not BaseHTTPMiddleware, which would add a task and a queue per request."""

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()

        async def send_timed(message: dict) -> None:
            if message["type"] == "http.response.start":
                duration = f"app;dur={(time.perf_counter() - started) * 1000.0:.3f}".encode()
                message = {**message, "headers": [*message.get("headers", ()), (b"server-timing", duration)]}
            await send(message)

        await self.app(scope, receive, send_timed)


async def purge_periodically(store: Store, interval_s: float) -> None:
    """Delete expired objects every ``interval_s``; queries already hide them, this reclaims the space."""
    while True:
        await asyncio.sleep(interval_s)
        try:
            purged = store.purge_expired()
        except Exception:  # a failed purge must not end the loop; the next one may succeed
            log.exception("purging expired UDM objects failed")
            continue
        if purged:
            log.info("purged %d expired UDM objects", purged)


# --- request parsing -------------------------------------------------------------------------------------


def parse_object_query(items: list[tuple[str, str]]) -> dict[str, Any]:
    """Check ``GET /objects`` parameters; exactly one of ``bbox`` or ``lat``+``lon``+``radius`` is needed."""
    params: dict[str, str] = {}
    for key, value in items:
        if key not in QUERY_PARAMETERS:
            # A typo such as layer=2 would otherwise silently return every layer.
            raise ApiError(f"unknown parameter {key!r}; known: {', '.join(sorted(QUERY_PARAMETERS))}")
        if key in params:
            raise ApiError(f"parameter {key!r} given twice")
        params[key] = value

    query: dict[str, Any] = {
        "layers": parse_layers(params["layers"]) if "layers" in params else None,
        "types": parse_types(params["types"]) if "types" in params else None,
        "limit": parse_limit(params.get("limit")),
    }
    circle = [key for key in ("lat", "lon", "radius") if key in params]
    if "bbox" in params and circle:
        raise ApiError("give either bbox or lat/lon/radius, not both")
    if "bbox" in params:
        query["bbox"] = parse_bbox(params["bbox"])
    elif circle:
        if len(circle) != 3:
            raise ApiError("a radius query needs all of lat, lon and radius")
        query["lat"] = parse_number(params["lat"], "lat", -90.0, 90.0)
        query["lon"] = parse_number(params["lon"], "lon", -180.0, 180.0)
        query["radius"] = parse_number(params["radius"], "radius", 0.0, MAX_RADIUS_M)
        if query["radius"] <= 0.0:
            raise ApiError("radius must be more than 0 metres")
    else:
        raise ApiError("give bbox=minlon,minlat,maxlon,maxlat or lat=..&lon=..&radius=metres")
    return query


def parse_number(text: str, name: str, low: float, high: float) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ApiError(f"{name} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ApiError(f"{name} must be a finite number, not {text!r}")
    if not low <= value <= high:
        raise ApiError(f"{name} {value:g} is outside {low:g}..{high:g}")
    return value


def parse_bbox(text: str) -> BBox:
    parts = text.split(",")
    if len(parts) != 4:
        raise ApiError(f"bbox needs 4 numbers minlon,minlat,maxlon,maxlat, got {text!r}")
    min_lon = parse_number(parts[0], "bbox minlon", -180.0, 180.0)
    min_lat = parse_number(parts[1], "bbox minlat", -90.0, 90.0)
    max_lon = parse_number(parts[2], "bbox maxlon", -180.0, 180.0)
    max_lat = parse_number(parts[3], "bbox maxlat", -90.0, 90.0)
    if min_lon > max_lon or min_lat > max_lat:
        # Boxes over the antimeridian are not supported; ask with two boxes instead.
        raise ApiError(f"bbox {text!r} is inverted: need minlon <= maxlon and minlat <= maxlat")
    bbox = BBox(min_lon, min_lat, max_lon, max_lat)
    if bbox.area_km2() > MAX_BBOX_AREA_KM2:
        raise ApiError(f"bbox covers {bbox.area_km2():.0f} km2; the limit is {MAX_BBOX_AREA_KM2:g} km2")
    return bbox


def parse_layers(text: str) -> list[int]:
    try:
        return sorted({parse_layer(part) for part in text.split(",")})
    except InvalidObject as error:
        raise ApiError(str(error)) from None


def parse_types(text: str) -> list[str]:
    types = [part.strip() for part in text.split(",")]
    if not all(types):
        raise ApiError(f"types {text!r} has an empty entry")
    if len(types) > 50:
        raise ApiError("at most 50 types per query")
    return types


def parse_limit(text: str | None) -> int:
    if text is None:
        return DEFAULT_LIMIT
    if not text.isdigit() or not 1 <= int(text) <= MAX_LIMIT:
        raise ApiError(f"limit must be a whole number 1..{MAX_LIMIT}, not {text!r}")
    return int(text)


async def read_json_body(request: Request) -> Any:
    """The request body as JSON, read with a size cap so a huge upload is refused before it fills memory."""
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > MAX_BODY_BYTES:
        raise ApiError(f"body is larger than {MAX_BODY_BYTES} bytes", 413, "too_large")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY_BYTES:
            raise ApiError(f"body is larger than {MAX_BODY_BYTES} bytes", 413, "too_large")
        chunks.append(chunk)
    try:
        return json.loads(b"".join(chunks))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ApiError(f"body is not JSON: {error}") from None


def objects_from_document(document: Any) -> tuple[list[UdmObject], bool]:
    """Objects from a posted Feature or FeatureCollection, and whether it was a single Feature."""
    kind = document.get("type") if isinstance(document, dict) else None
    if kind == "Feature":
        features, single = [document], True
    elif kind == "FeatureCollection":
        features, single = document.get("features"), False
        if not isinstance(features, list):
            raise ApiError("FeatureCollection.features must be a list")
        if len(features) > MAX_FEATURES_PER_POST:
            raise ApiError(f"at most {MAX_FEATURES_PER_POST} features per request", 413, "too_large")
    else:
        raise ApiError('body must be a GeoJSON Feature or FeatureCollection ("type" says which)')

    objects, seen = [], set()
    for index, feature in enumerate(features):
        where = "feature" if single else f"features[{index}]"
        try:
            obj = UdmObject.from_feature(feature, default_id=uuid.uuid4().hex)
        except InvalidObject as error:
            raise ApiError(f"{where}: {error}") from None
        if obj.id in seen:
            raise ApiError(f"{where}: id {obj.id!r} appears twice in one request")
        seen.add(obj.id)
        objects.append(obj)
    return objects, single


# --- error answers ---------------------------------------------------------------------------------------


def json_error(status: int, code: str, message: str, headers: dict[str, str] | None = None) -> Response:
    return JSONResponse({"error": code, "message": message}, status_code=status, headers=headers)


def unauthorised() -> Response:
    return json_error(
        401, "unauthorized", "writes need the header 'Authorization: Bearer TOKEN' with the server's token",
        headers={"WWW-Authenticate": 'Bearer realm="udm"'},
    )


async def api_error(request: Request, error: Exception) -> Response:
    assert isinstance(error, ApiError)
    return json_error(error.status, error.code, error.message)


async def http_exception(request: Request, error: Exception) -> Response:
    assert isinstance(error, HTTPException)
    codes = {404: "not_found", 405: "method_not_allowed", 413: "too_large"}
    return json_error(error.status_code, codes.get(error.status_code, "http_error"), str(error.detail),
                      headers=error.headers)


async def internal_error(request: Request, error: Exception) -> Response:
    log.error("UDM request %s %s failed", request.method, request.url.path, exc_info=error)
    return json_error(500, "internal_error", "the server failed to answer; see its log")


# --- OpenAPI ---------------------------------------------------------------------------------------------


def openapi_document() -> dict[str, Any]:
    """The API description served at /openapi.json (OpenAPI 3.1); docs/udm-api.md explains it in prose."""
    error = {"$ref": "#/components/responses/Error"}
    string, number, integer = {"type": "string"}, {"type": "number"}, {"type": "integer"}
    layer_names = ", ".join(f"{layer.value} {layer.name.lower()}" for layer in Layer)

    def query(name: str, schema: dict, description: str = "", **extra: Any) -> dict[str, Any]:
        return {"name": name, "in": "query", "schema": schema, "description": description, **extra}

    def geojson(schema: str) -> dict[str, Any]:
        return {GEOJSON: {"schema": {"$ref": f"#/components/schemas/{schema}"}}}

    list_parameters = [
        query("bbox", string, "minlon,minlat,maxlon,maxlat in WGS84 degrees; at most "
                              f"{MAX_BBOX_AREA_KM2:g} km2; no antimeridian crossing.",
              example="9.985,53.548,9.995,53.552"),
        query("lat", number, "Centre of a radius query, degrees."),
        query("lon", number, "Centre of a radius query, degrees."),
        query("radius", {**number, "exclusiveMinimum": 0, "maximum": MAX_RADIUS_M},
              "Great-circle metres; results come nearest first."),
        query("layers", string, f"Comma-separated layers: {layer_names}.", example="2,4"),
        query("types", string, "Comma-separated object types (exact match).", example="traffic_signals,stop"),
        query("limit", {**integer, "minimum": 1, "maximum": MAX_LIMIT, "default": DEFAULT_LIMIT}),
    ]
    object_properties = {
        "id": string,
        "layer": {**integer, "enum": [layer.value for layer in Layer]},
        "type": {**string, "maxLength": 64},
        "class": {**string, "maxLength": 64},
        "name": {**string, "maxLength": 256},
        "heading": {"type": ["number", "null"], "description": "Compass degrees, 0 north, clockwise"},
        "extent": {"type": ["object", "null"], "description": "Metres",
                   "properties": {"length": number, "width": number, "height": number}},
        "valid_until": {"type": ["string", "number", "null"],
                        "description": "ISO 8601 with a zone, or POSIX seconds; null: no end"},
        "source": {**string, "maxLength": 128},
        "created_at": {**string, "readOnly": True},
        "updated_at": {**string, "readOnly": True},
    }
    feature = {
        "type": "object",
        "required": ["type", "geometry", "properties"],
        "properties": {
            "type": {"const": "Feature"},
            "id": {**string, "pattern": ID_PATTERN.pattern},
            "geometry": {"type": "object", "properties": {
                "type": {"const": "Point"},
                "coordinates": {"type": "array", "items": number, "minItems": 2, "maxItems": 3,
                                "description": "[lon, lat] or [lon, lat, alt]"},
            }},
            "properties": {"type": "object", "required": ["layer", "type"], "properties": object_properties},
        },
    }
    feature_collection = {
        "type": "object",
        "properties": {
            "type": {"const": "FeatureCollection"},
            "timeStamp": string,
            "numberReturned": integer,
            "truncated": {"type": "boolean", "description": "More objects matched than limit allowed"},
            "features": {"type": "array", "items": {"$ref": "#/components/schemas/Feature"}},
        },
    }
    object_id = {"name": "object_id", "in": "path", "required": True, "schema": string}
    bearer = [{"bearer": []}]
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "twin Urban Dynamic Map",
            "version": __version__,
            "description": "Positioned map objects in four layers, queried by box or radius, answered as "
                           "OGC API - Features style GeoJSON. Writes need a bearer token.",
        },
        "paths": {
            "/objects": {
                "get": {
                    "summary": "Unexpired objects in a box or within a radius",
                    "parameters": list_parameters,
                    "responses": {"200": {"description": "Objects", "content": geojson("FeatureCollection")},
                                  "400": error},
                },
                "post": {
                    "summary": "Create or replace objects by id",
                    "security": bearer,
                    "requestBody": {"required": True, "content": {GEOJSON: {"schema": {"oneOf": [
                        {"$ref": "#/components/schemas/Feature"},
                        {"$ref": "#/components/schemas/FeatureCollection"},
                    ]}}}},
                    "responses": {"201": {"description": "The stored objects, with ids and timestamps"},
                                  "400": error, "401": error, "413": error},
                },
            },
            "/objects/{object_id}": {
                "parameters": [object_id],
                "get": {"summary": "One unexpired object",
                        "responses": {"200": {"description": "Object", "content": geojson("Feature")},
                                      "404": error}},
                "delete": {"summary": "Remove one object", "security": bearer,
                           "responses": {"204": {"description": "Deleted"}, "401": error, "404": error}},
            },
            "/health": {"get": {"summary": "Liveness and object count",
                                "responses": {"200": {"description": "{status, version, objects}"}}}},
        },
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "responses": {"Error": {"description": "Refusal", "content": {"application/json": {"schema": {
                "type": "object", "properties": {"error": string, "message": string},
            }}}}},
            "schemas": {"Feature": feature, "FeatureCollection": feature_collection},
        },
    }


# --- running it ------------------------------------------------------------------------------------------


def bind_socket(host: str, port: int) -> socket.socket:
    """A listening-ready TCP socket; port 0 picks a free port, which ``getsockname()`` then reveals."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    # IPPROTO_TCP, not the default 0: asyncio only sets TCP_NODELAY on sockets whose proto says TCP, and
    # without it every response waits ~40 ms for the client's delayed ACK (Nagle).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


def url_of(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def uvicorn_server(app: Any, *, log_level: str = "warning", graceful_s: float = 2.0) -> uvicorn.Server:
    # Access logs off: at fleet query rates the log line costs about as much as the query itself. No proxy
    # headers: nothing here uses the client's address, and uvicorn's middleware for them walked every request's
    # headers (~0.1 ms of the server's ~0.7 ms CPU per query).
    config = uvicorn.Config(app, log_level=log_level, access_log=False, lifespan="on", proxy_headers=False,
                            timeout_graceful_shutdown=graceful_s)
    return uvicorn.Server(config)


def run_server(app: Any, host: str, port: int, *, on_listening: Callable[[str], None] | None = None,
               log_level: str = "warning", realtime: bool = False) -> None:
    """Serve ``app`` until interrupted; ``on_listening(url)`` runs once the port is bound (port 0 allowed).

    ``realtime``: this thread, which runs uvicorn's event loop (with uvloop and httptools the whole server is
    this one thread), serves under SCHED_FIFO (twin.udm.priority); where that is not permitted, a warning and
    normal priority."""
    sock = bind_socket(host, port)
    if realtime:
        reason = realtime_policy("the UDM server")
        if reason:
            log.warning("%s", reason)
    if on_listening:
        on_listening(url_of(sock))
    uvicorn_server(app, log_level=log_level).run(sockets=[sock])


class ServerThread:
    """An app served by uvicorn on a background thread, for tests, benchmarks and embedding in a twin run.

    >>> with ServerThread(create_app(SqliteRtreeStore(), "secret")) as server:
    ...     httpx.get(server.url + "/health")
    """

    def __init__(self, app: Any, host: str = "127.0.0.1", port: int = 0, *, graceful_s: float = 0.5) -> None:
        self._sock = bind_socket(host, port)
        self.url = url_of(self._sock)
        self._server = uvicorn_server(app, graceful_s=graceful_s)
        self._thread = threading.Thread(target=self._server.run, kwargs={"sockets": [self._sock]},
                                        name=f"udm-server {self.url}", daemon=True)

    def start(self, timeout_s: float = 10.0) -> ServerThread:
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"the UDM server at {self.url} did not start")
            time.sleep(0.01)
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        self._server.should_exit = True
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        self._sock.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
