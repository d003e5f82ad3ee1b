"""`serve()`: the status server in a background thread of the calling process.

    handle = serve("127.0.0.1", 8765, run_dir="runs/live", session_dir="sessions/s1")
    print(handle.url)      # http://127.0.0.1:8765/
    ...
    handle.stop()          # or: with serve(...) as handle: ...

Either folder may be None (a capture without training, or training without a session) or may
not exist yet: endpoints answer 503 with {} until something is published.

    handle = serve("127.0.0.1", 8765, batch_dir="runs/b1")   # a `recon batch` folder

serves /api/batch (RUNS/batch.json) and, per job, the run page at /job/N/ (N = index into
batch.json's jobs; its API and render URLs read RUNS/<jobs[N].run_dir>/, which must lie inside RUNS).

    handle = serve("127.0.0.1", 8765, run_dir="runs/s1", renderer=RenderService.from_run("runs/s1"))

adds the viewer (any pose, any time) at /view and its API at /api/view/... (server/viewer.py); the
status page then shows it as a panel.
"""
from __future__ import annotations

import socket
import sys
import threading
from http.server import ThreadingHTTPServer
from importlib import resources
from pathlib import Path

from server.batch_reader import BatchReader, JobError
from server.handler import StatusHandler
from server.run_reader import RunReader, is_render_name
from server.session_monitor import SessionMonitor
from server.viewer import ViewerEndpoints

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
MAX_CONNECTIONS = 32          # each connection holds a thread; more are refused at once


class View:
    """What one page's URLs read: the root page's run, session and batch, or one job's run."""

    def __init__(self, run: RunReader | None, session: SessionMonitor | None = None,
                 batch: BatchReader | None = None, job: dict | None = None):
        self.run, self.session, self.batch, self.job = run, session, batch, job

    viewer = False          # the root view of a server with a renderer: the page shows the viewer panel

    def config(self) -> dict:
        run, ses = self.run, self.session
        out = {"run": str(run.run_dir) if run else None, "session": str(ses.path) if ses else None}
        if self.viewer:
            out["viewer"] = True
        if self.batch:
            out["batch"] = str(self.batch.runs_dir)
        if self.job:
            out["job"] = self.job
        return out

    def api(self, name: str, max_points: int):
        """JSON value of /api/NAME; None = nothing published yet; NotImplemented = no such endpoint."""
        run, ses, bat = self.run, self.session, self.batch
        table = {
            "status": lambda: run and run.status(),
            "metrics": lambda: run and run.metrics(max_points),
            "gaussians": lambda: run and run.gaussians(max_points),
            "renders": lambda: run and run.renders(),
            "capture": lambda: ses and ses.capture(),
            "sync": lambda: ses and ses.sync(),
            "batch": lambda: bat and bat.batch(),
            "config": self.config,
        }
        return table[name]() if name in table else NotImplemented

    def render_file(self, set_name: str, file_name: str):
        if self.run is None:
            return None if is_render_name(set_name, file_name) else NotImplemented
        return self.run.render_file(set_name, file_name)


class App:
    """What the handler serves: the page, and the views it reads (the root one, one per batch job)."""

    def __init__(self, run_dir: Path | None, session_dir: Path | None, session_poll_s: float,
                 batch_dir: Path | None = None, renderer=None):
        self.page = resources.files("server").joinpath("page.html").read_bytes()
        self.viewer = ViewerEndpoints(renderer) if renderer is not None else None
        if self.viewer:
            self.viewer.page = resources.files("server").joinpath("viewer.html").read_bytes()
        self.batch = BatchReader(batch_dir) if batch_dir else None
        self.root = View(RunReader(run_dir) if run_dir else None,
                         SessionMonitor(session_dir, session_poll_s) if session_dir else None, self.batch)
        self.root.viewer = self.viewer is not None

    def job_view(self, index: int) -> View | None:
        """The view of /job/INDEX/: that job's run folder. None while batch.json does not exist;
        raises JobError (404: no such job or no batch served; 403: run_dir outside the batch)."""
        if self.batch is None:
            raise JobError(404, "no batch is served")
        found = self.batch.job(index)
        if found is None:
            return None
        job, reader = found
        return View(reader, job={"index": index, "name": job.get("name"), "state": job.get("state")})

    def api(self, name: str, max_points: int):
        return self.root.api(name, max_points)

    def render_file(self, set_name: str, file_name: str):
        return self.root.render_file(set_name, file_name)

    def close(self) -> None:
        if self.root.session:
            self.root.session.stop()
        if self.viewer:
            self.viewer.close()


class StatusServer(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    request_queue_size = 64          # listen backlog: a burst of connects is not left to SYN retries

    def __init__(self, address, app: App, verbose: bool = False):
        self.app, self.verbose = app, verbose
        self.counts = {"requests": 0, "disconnects": 0, "refused": 0, "errors": 0}
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        super().__init__(address, StatusHandler)

    def count(self, key: str) -> None:
        with self._lock:
            self.counts[key] += 1

    def process_request(self, request, client_address) -> None:
        if not self._slots.acquire(blocking=False):
            self.count("refused")
            try:
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\n"
                                b"Retry-After: 1\r\nConnection: close\r\n\r\n")
            except OSError:
                pass
            self.shutdown_request(request)
            return
        with self._lock:
            self._open.add(request)
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            with self._lock:
                self._open.discard(request)
            self._slots.release()

    def handle_error(self, request, client_address) -> None:
        self.count("errors")
        exc = sys.exc_info()[1]
        print(f"server: error answering {client_address[0]}: {type(exc).__name__}: {exc}", file=sys.stderr)

    def close_connections(self) -> None:
        """End kept-alive connections so no handler thread outlives stop()."""
        with self._lock:
            sockets = list(self._open)
        for s in sockets:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class ServerHandle:
    """A running server: .url, .host, .port, .counts (requests, disconnects, refused, errors), .stop()."""

    def __init__(self, httpd: StatusServer, thread: threading.Thread):
        self._httpd, self._thread = httpd, thread
        self.host, self.port = httpd.server_address[:2]
        shown = f"[{self.host}]" if ":" in self.host else self.host
        self.url = f"http://{shown}:{self.port}/"

    @property
    def counts(self) -> dict:
        return dict(self._httpd.counts)

    @property
    def viewer_counts(self) -> dict | None:
        """{"submitted", "rendered", "superseded"} of the viewer's renders; None without a renderer."""
        v = self._httpd.app.viewer
        return dict(v.coalescer.counts) if v else None

    def stop(self) -> None:
        """Stop accepting, close open connections and the session monitor; idempotent."""
        if self._thread.is_alive():
            self._httpd.shutdown()
            self._thread.join()
        self._httpd.close_connections()
        self._httpd.server_close()
        self._httpd.app.close()

    def __enter__(self) -> "ServerHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def serve(host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, run_dir: str | Path | None = None,
          session_dir: str | Path | None = None, verbose: bool = False,
          session_poll_s: float = 1.0, batch_dir: str | Path | None = None, renderer=None) -> ServerHandle:
    """Start the status server in a daemon thread and return its handle (port 0: any free port).
    batch_dir: a `recon batch` folder (RUNS/): /api/batch and one run page per job at /job/N/.
    renderer: renders at any pose and time (recon.view.RenderService, or the same three methods,
    see server/viewer.py): the viewer at /view and a viewer panel on the status page.
    Raises OSError if the address cannot be bound (e.g. the port is taken)."""
    app = App(Path(run_dir) if run_dir else None, Path(session_dir) if session_dir else None, session_poll_s,
              Path(batch_dir) if batch_dir else None, renderer)
    try:
        httpd = StatusServer((host, port), app, verbose)
    except OSError:
        app.close()
        raise
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.25},
                              name=f"status-server:{port}", daemon=True)
    thread.start()
    return ServerHandle(httpd, thread)
