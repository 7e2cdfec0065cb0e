"""The UDM client's HTTP: one keep-alive HTTP/1.1 connection for GET requests, on the standard library's
``http.client``.

Why not httpx: a twin asks the UDM twice a second, and with 20 twins on one machine every millisecond of CPU a
request costs is a millisecond in which it can be preempted. httpx spent ~1.0 ms of the client's CPU per
request on this machine (its pool, its URL and header models, its transport layers); ``http.client`` over a
kept-alive socket spends ~0.2 ms for the same request and answer (benchmarks/bench_udm_fleet.py, "client CPU
per request"). What httpx gave that matters here is kept: a timeout on every socket operation, no proxy
variables (``http.client`` never reads them), no redirects followed, and an idle connection the server has
closed is noticed before it is reused, so a keep-alive timeout on the server is never counted as an error.
"""

from __future__ import annotations

import http.client
import select
import ssl
from dataclasses import dataclass
from types import TracebackType
from typing import Self
from urllib.parse import urlencode, urlsplit


class TransportError(Exception):
    """The request got no answer; ``kind`` says why: "timeout", "unreachable" (no connection could be made)
    or "network" (the connection broke mid-request)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Reply:
    status_code: int
    body: bytes
    server_timing: str  # the Server-Timing header, "" without one

    @property
    def text(self) -> str:
        return self.body.decode("utf-8", "replace")


class HttpConnection:
    """GET requests to one server over one kept-alive connection, opened when first needed and again after
    the server closed it. ``timeout_s`` bounds every connect, send and read; ``headers`` go with every request.
    Not thread-safe: one per thread (the UDM client has one worker)."""

    def __init__(self, base_url: str, *, timeout_s: float, headers: dict[str, str] | None = None) -> None:
        parts = urlsplit(base_url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"UDM url {base_url!r} is not an http(s) URL")
        self._host, self._port, self._tls = parts.hostname, parts.port, parts.scheme == "https"
        self._prefix = parts.path.rstrip("/")
        self._timeout_s = timeout_s
        self._headers = dict(headers or {})
        self._connection: http.client.HTTPConnection | None = None

    def get(self, path: str, params: dict[str, str]) -> Reply:
        """The answer to ``GET BASE/path?params`` (any status); TransportError when there is none."""
        target = f"{self._prefix}/{path.lstrip('/')}?{urlencode(params, safe=',')}"
        connection = self._open()
        try:
            connection.request("GET", target, headers=self._headers)
            response = connection.getresponse()
            body = response.read()
        except TimeoutError as error:
            self.close()  # a late answer would otherwise be read as the next request's
            raise TransportError("timeout", f"ReadTimeout: {error}") from None
        except (OSError, http.client.HTTPException) as error:
            self.close()
            raise TransportError("network", f"{type(error).__name__}: {error}") from None
        if response.will_close:
            self.close()
        return Reply(response.status, body, response.getheader("server-timing", ""))

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()

    def _open(self) -> http.client.HTTPConnection:
        """The connection to send on: the kept one while the server keeps it open, else a new one."""
        if self._connection is not None and not _idle_socket_closed(self._connection.sock):
            return self._connection
        self.close()
        if self._tls:
            connection: http.client.HTTPConnection = http.client.HTTPSConnection(
                self._host, self._port, timeout=self._timeout_s, context=ssl.create_default_context())
        else:
            connection = http.client.HTTPConnection(self._host, self._port, timeout=self._timeout_s)
        try:
            connection.connect()
        except TimeoutError as error:
            connection.close()
            raise TransportError("timeout", f"ConnectTimeout: {error}") from None
        except OSError as error:  # refused, no route, unknown host (gaierror), TLS handshake
            connection.close()
            raise TransportError("unreachable", f"ConnectError: {error}") from None
        self._connection = connection
        return connection


def _idle_socket_closed(sock: object) -> bool:
    """True when an idle keep-alive socket is gone or readable: between requests the server sends nothing,
    so anything to read is its close (or garbage); either way the connection must not be reused."""
    if sock is None:
        return True
    poller = select.poll()
    poller.register(sock, select.POLLIN | select.POLLERR | select.POLLHUP)
    return bool(poller.poll(0))
