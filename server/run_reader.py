"""Reads what a training run publishes in RUN/live/ (contract: recon/live/publish.py), with bounded memory.

Parsed JSON is cached per file and re-read only when the file's (inode, size, mtime) changes, so
polling browsers cost a stat() per request. Only whitelisted files are ever opened: render files
are looked up by (set name, file name) from fixed patterns, never by joining a request path.
"""
from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path

MAX_METRIC_BYTES = 8 << 20        # read at most the last 8 MiB of metrics.jsonl
MAX_METRIC_POINTS = 5000          # and keep at most this many points in memory
MAX_JSON_BYTES = 1 << 20          # status.json / renders.json larger than this are refused
RENDER_SET = re.compile(r"latest|t[0-9]{2}")
RENDER_FILES = {"rgb.png": "image/png", "thermal.png": "image/png", "kelvin.npy": "application/octet-stream"}


def is_render_name(set_name: str, file_name: str) -> bool:
    return bool(RENDER_SET.fullmatch(set_name)) and file_name in RENDER_FILES


def decimate(points: list, n: int) -> list:
    """At most n items spread evenly over `points`, first and last always kept."""
    if len(points) <= n:
        return list(points)
    if n <= 1:
        return points[-1:]
    step = (len(points) - 1) / (n - 1)
    return [points[round(i * step)] for i in range(n)]


def parse_jsonl(data: bytes) -> list[dict]:
    """Complete lines that parse as JSON objects; a torn last line (no newline) and bad lines are skipped."""
    out = []
    for line in data.split(b"\n")[:-1]:
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if isinstance(obj, dict):
            out.append(obj)
    return out


def _file_key(path: Path):
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


class CachedFile:
    """A file parsed once per version. get() -> parsed value, or None while absent/unreadable."""

    def __init__(self, path: Path, parse):
        self.path, self.parse = path, parse
        self._lock = threading.Lock()
        self._key = None
        self._value = None

    def get(self):
        key = _file_key(self.path)
        with self._lock:
            if key != self._key:
                self._value = self._load() if key is not None else None
                self._key = key
            return self._value

    def _load(self):
        try:
            return self.parse(self.path)
        except (OSError, ValueError):
            return None


def read_json(path: Path, limit: int = MAX_JSON_BYTES) -> dict | None:
    """A JSON object file of at most `limit` bytes; None if larger or not an object."""
    with open(path, "rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        return None
    obj = json.loads(data)
    return obj if isinstance(obj, dict) else None


def _read_metrics(path: Path) -> list[dict]:
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        f.seek(max(0, size - MAX_METRIC_BYTES))
        data = f.read(MAX_METRIC_BYTES)
    if size > MAX_METRIC_BYTES:
        data = data[data.find(b"\n") + 1:]     # drop the partial first line
    return parse_jsonl(data)[-MAX_METRIC_POINTS:]


class RunReader:
    """The published state of one run folder (RUN/live/)."""

    def __init__(self, run_dir: str | Path):
        self.run_dir = Path(run_dir)
        self.live = self.run_dir / "live"
        self._status = CachedFile(self.live / "status.json", read_json)
        self._metrics = CachedFile(self.live / "metrics.jsonl", _read_metrics)
        self._renders = CachedFile(self.live / "renders.json", read_json)

    def status(self) -> dict | None:
        """status.json plus age_s (seconds since the trainer wrote it), or None before the first."""
        s = self._status.get()
        if s is None:
            return None
        unix = s.get("unix")
        age = round(time.time() - unix, 3) if isinstance(unix, (int, float)) else None
        return {**s, "age_s": age}

    def metrics(self, max_points: int) -> dict | None:
        points = self._metrics.get()
        if points is None:
            return None
        return {"total": len(points), "points": decimate(points, max_points)}

    def gaussians(self, max_points: int) -> dict | None:
        """Gaussians per routing role now (status) and over wall-clock time (history)."""
        status, points = self._status.get(), self._metrics.get() or []
        if status is None and not points:
            return None
        history = [{"wall_s": p.get("wall_s"), "iteration": p.get("iteration"),
                    "gaussians": p.get("gaussians"), "roles": p.get("roles")} for p in decimate(points, max_points)]
        now = status or points[-1]
        return {"gaussians": now.get("gaussians"), "roles": now.get("roles"), "history": history}

    def renders(self) -> dict | None:
        return self._renders.get()

    def render_file(self, set_name: str, file_name: str):
        """(bytes, content type) of a whitelisted render file; None if not published yet;
        NotImplemented if no such name can exist."""
        if not is_render_name(set_name, file_name):
            return NotImplemented
        try:
            data = (self.live / "render" / set_name / file_name).read_bytes()
        except OSError:
            return None
        return data, RENDER_FILES[file_name]
