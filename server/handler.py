"""The HTTP request handler: limits, routing to the readers, careful replies.

GET and HEAD only. Request line <= 2 KiB (else 414), header block <= 16 KiB (else 431), no
request body (413). Every path is matched against a fixed route table after percent-decoding;
paths holding "..", a backslash or NUL are refused with 400, unknown paths get 404, so no file
outside the whitelisted ones can be named. /job/N/... (a batch job's page) are the same routes
for job N's run folder, N being an index into batch.json's jobs, never a path. /view and
/api/view/{info,render,series} exist at the root only, with a renderer attached (server/viewer.py:
query values parsed and bounded there, renders coalesced per client). Replies carry
Content-Length, Cache-Control: no-store and nosniff; a client that goes away mid-reply is
counted, not raised.
"""
from __future__ import annotations

import http.client
import json
import re
import socket
import sys
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler
from urllib.parse import parse_qs, unquote, urlsplit

from server.batch_reader import JobError
from server.viewer import Unavailable, ViewerError

MAX_REQUEST_LINE = 2048
MAX_HEADER_BYTES = 16 * 1024
DEFAULT_POINTS = 500
MAX_POINTS = 5000
JSON = "application/json"
# the page is self-contained: nothing may load from anywhere but this server
PAGE_CSP = ("default-src 'none'; img-src 'self' data:; style-src 'unsafe-inline'; "
            "script-src 'unsafe-inline'; connect-src 'self'; frame-src 'self'; base-uri 'none'; form-action 'none'")
VIEWER_CSP = PAGE_CSP.replace("img-src 'self' data:", "img-src 'self' data: blob:")
RENDER_PATH = re.compile(r"/render/([^/]+)/([^/]+)")
JOB_PATH = re.compile(r"/job/(0|[1-9][0-9]{0,5})(/.*)?", re.S)    # a batch job's page: index, rest
DISCONNECTS = (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError)
LINGER_BYTES, LINGER_S = 1 << 20, 1.0


class BadRequest(Exception):
    pass


class _HeadReader:
    """Wraps the socket file while headers are parsed: past the byte budget, readline raises
    LineTooLong, which BaseHTTPRequestHandler answers with 431."""

    def __init__(self, raw, budget: int):
        self.raw, self.budget = raw, budget

    def readline(self, size: int = -1) -> bytes:
        want = self.budget + 1 if size < 0 else min(size, self.budget + 1)
        line = self.raw.readline(want)
        self.budget -= len(line)
        if self.budget < 0:
            raise http.client.LineTooLong(f"header block over {MAX_HEADER_BYTES} bytes")
        return line


def clean_path(raw_path: str) -> tuple[str, dict]:
    """Request target -> (decoded path, query dict). Raises BadRequest for traversal attempts."""
    parts = urlsplit(raw_path)
    path = unquote(parts.path, errors="strict")
    if not path.startswith("/") or "\\" in path or "\x00" in path or ".." in path.split("/"):
        raise BadRequest(f"bad path {raw_path[:80]!r}")
    return path, parse_qs(parts.query, max_num_fields=8)


def int_param(query: dict, name: str, default: int, lo: int, hi: int) -> int:
    values = query.get(name)
    if not values:
        return default
    try:
        value = int(values[0])
    except ValueError:
        raise BadRequest(f"{name} must be an integer, got {values[0][:20]!r}") from None
    if not lo <= value <= hi:
        raise BadRequest(f"{name} must be in {lo}..{hi}, got {value}")
    return value


class StatusHandler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"      # keep-alive: a polling page reuses its connections
    server_version = "thermal4d"
    timeout = 10                       # idle or slow clients are dropped after this many seconds
    disable_nagle_algorithm = True     # headers and body go out as separate writes: no 40 ms ACK wait

    linger = False                     # set when an error reply closes a request not read to its end

    # ------------------------------------------------------------------ request parsing with limits
    def handle_one_request(self) -> None:
        self.command, self.request_version, self.requestline = "", "HTTP/1.0", ""
        try:
            self.raw_requestline = self.rfile.readline(MAX_REQUEST_LINE + 1)
        except DISCONNECTS:
            self.close_connection = True
            return
        if len(self.raw_requestline) > MAX_REQUEST_LINE:
            self.close_connection = True
            self.reply(HTTPStatus.REQUEST_URI_TOO_LONG, {"error": f"request line over {MAX_REQUEST_LINE} bytes"})
            return
        if not self.raw_requestline:
            self.close_connection = True
            return
        if self.parse_request():
            self.dispatch()
        try:
            self.wfile.flush()
        except DISCONNECTS:
            self.close_connection = True

    def parse_request(self) -> bool:
        real, self.rfile = self.rfile, _HeadReader(self.rfile, MAX_HEADER_BYTES)
        try:
            return super().parse_request()
        finally:
            self.rfile = real

    def handle(self) -> None:
        try:
            super().handle()
        except DISCONNECTS:
            self.server.count("disconnects")

    def finish(self) -> None:
        try:
            super().finish()
            if self.linger:
                self._lingering_close()
        except OSError:
            pass

    def _lingering_close(self) -> None:
        """Read and drop what the client still sends (bounded) before closing: closing a socket with
        unread input sends a reset, which can destroy the error reply before the client reads it."""
        self.connection.shutdown(socket.SHUT_WR)
        self.connection.settimeout(0.2)
        deadline, total = time.monotonic() + LINGER_S, 0
        while time.monotonic() < deadline and total < LINGER_BYTES:
            chunk = self.connection.recv(65536)
            if not chunk:
                return
            total += len(chunk)

    def send_error(self, code, message=None, explain=None) -> None:
        """The stdlib's parse errors, as JSON with our headers; the connection is closed after."""
        self.close_connection = True
        if self.request_version == "HTTP/0.9":      # garbage parses as 0.9, which has no status line
            self.request_version = "HTTP/1.0"
        self.reply(code, {"error": message or HTTPStatus(code).phrase})

    def log_message(self, fmt, *args) -> None:
        if self.server.verbose:
            super().log_message(fmt, *args)

    # ------------------------------------------------------------------ replies
    def reply(self, code: int, body, ctype: str = JSON, headers: dict | None = None) -> None:
        """Send one response; dict/list bodies become JSON. A vanished client is only counted."""
        data = json.dumps(body, separators=(",", ":")).encode() if isinstance(body, (dict, list)) else body
        self.linger = self.linger or (code >= 400 and self.close_connection)
        try:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            if self.close_connection:
                self.send_header("Connection", "close")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(data)
        except DISCONNECTS:
            self.close_connection = True
            self.server.count("disconnects")
        self.server.count("requests")

    def dispatch(self) -> None:
        if self.command not in ("GET", "HEAD"):
            self.close_connection = True
            self.reply(HTTPStatus.METHOD_NOT_ALLOWED, {"error": f"{self.command} not allowed"},
                       headers={"Allow": "GET, HEAD"})
            return
        length = self.headers.get("Content-Length", "0").strip() or "0"
        if length != "0" or "Transfer-Encoding" in self.headers:
            self.close_connection = True          # the body is never read, so the connection cannot go on
            self.reply(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, {"error": "GET/HEAD take no request body"})
            return
        try:
            path, query = clean_path(self.path)
            self.route(path, query)
        except (BadRequest, ValueError) as exc:
            self.reply(HTTPStatus.BAD_REQUEST, {"error": str(exc)})

    def route(self, path: str, query: dict) -> None:
        app = self.server.app
        m = JOB_PATH.fullmatch(path)
        if m is None:
            self.route_view(app.root, path, query)
            return
        index = int(m.group(1))
        if m.group(2) is None:            # /job/N: the page's relative URLs need the trailing slash
            self.reply(HTTPStatus.MOVED_PERMANENTLY, {"error": "see /job/%d/" % index},
                       headers={"Location": "/job/%d/" % index})
            return
        try:
            view = app.job_view(index)
        except JobError as exc:
            self.reply(exc.status, {"error": str(exc)})
            return
        if view is None:                  # no batch.json yet
            self.reply(HTTPStatus.SERVICE_UNAVAILABLE, {}, headers={"Retry-After": "1"})
        else:
            self.route_view(view, m.group(2), query)

    def route_view(self, view, path: str, query: dict) -> None:
        """The fixed routes of one page: at the root, or below /job/N/ for a batch job's run."""
        if path in ("/", "/index.html"):
            self.reply(HTTPStatus.OK, self.server.app.page, "text/html; charset=utf-8",
                       {"Content-Security-Policy": PAGE_CSP})
            return
        if view is self.server.app.root and (path == "/view" or path.startswith("/api/view/")):
            self.route_viewer(path, query)
            return
        if path.startswith("/api/"):
            value = view.api(path[5:], int_param(query, "max", DEFAULT_POINTS, 2, MAX_POINTS))
            if value is NotImplemented:
                self.reply(HTTPStatus.NOT_FOUND, {"error": f"no endpoint {path}"})
            elif value is None:           # nothing published yet: not an error, come back later
                self.reply(HTTPStatus.SERVICE_UNAVAILABLE, {}, headers={"Retry-After": "1"})
            else:
                self.reply(HTTPStatus.OK, value)
            return
        m = RENDER_PATH.fullmatch(path)
        found = view.render_file(*m.groups()) if m else NotImplemented
        if found is NotImplemented:
            self.reply(HTTPStatus.NOT_FOUND, {"error": f"no such path {path[:80]}"})
        elif found is None:
            self.reply(HTTPStatus.SERVICE_UNAVAILABLE, b"", "text/plain", {"Retry-After": "1"})
        else:
            self.reply(HTTPStatus.OK, *found)

    def route_viewer(self, path: str, query: dict) -> None:
        """/view and /api/view/{info,render,series}: only with a renderer attached (else 404)."""
        viewer = self.server.app.viewer
        if viewer is None:
            self.reply(HTTPStatus.NOT_FOUND, {"error": "no renderer attached (recon view RUN serves one)"})
            return
        try:
            if path == "/view":
                self.reply(HTTPStatus.OK, viewer.page, "text/html; charset=utf-8", {"Content-Security-Policy": VIEWER_CSP})
            elif path == "/api/view/info":
                self.reply(HTTPStatus.OK, viewer.info())
            elif path == "/api/view/render":
                self.reply(HTTPStatus.OK, viewer.render(query), "application/octet-stream")
            elif path == "/api/view/series":
                self.reply(HTTPStatus.OK, viewer.series(query))
            else:
                self.reply(HTTPStatus.NOT_FOUND, {"error": f"no endpoint {path[:80]}"})
        except ViewerError as exc:
            self.reply(HTTPStatus.BAD_REQUEST, {"error": str(exc)})
        except (Unavailable, TimeoutError) as exc:
            self.reply(HTTPStatus.SERVICE_UNAVAILABLE, {"error": str(exc)}, headers={"Retry-After": "1"})
        except Exception as exc:          # the renderer failed: say so in one line, keep serving
            self.server.count("errors")
            print(f"server: viewer render failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            self.reply(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": f"render failed: {type(exc).__name__}: {exc}"})
