"""The viewer's endpoints: renders at any pose and time from a renderer attached to serve().

    serve(..., renderer=obj)     # obj: recon.view.RenderService or anything with the same three methods
      obj.info() -> JSON-able dict (cameras, time_range, thermal_range_k, modalities, colour_maps, size)
      obj.render(c2w (4, 4) OpenGL camera-to-world, t, width, height)
          -> {"rgb": (H, W, 3) uint8 | None, "kelvin": (H, W) float32 | None, "camera": {...}, ...}
      obj.series(c2w, t, width, height, x, y, n) -> JSON-able dict

URLs (GET only; no path from the request is ever joined to a file):
  /view                          the viewer page (server/viewer.html)
  /api/view/info                 obj.info()
  /api/view/render?c2w=16 numbers (row-major, comma-separated)&t=T&size=WxH&client=ID
                                 one binary reply: b"T4DV", uint32 LE header length, the JSON header
                                 (pose, time, intrinsics, timings, where each array is), then the arrays:
                                 rgb uint8 (H, W, 3), kelvin float32 LE (H, W); each starts 4-byte aligned
  /api/view/series?c2w=...&t=T&size=WxH&px=X,Y&n=N&client=ID   JSON: temperature over time at a point

Coalescing: one render worker per server. Each (client, kind) has one slot holding its newest
request: a request that is still waiting when a newer one of the same client arrives is not
rendered; it is answered with the newer request's render (whose pose and time its header shows).
So a drag never queues stale renders; different clients take turns. A renderer may have a
pace() method, called before each job is taken (recon.view.LiveRenderService uses it to cap the
share of CPU time rendering takes from training) and may return "pace_ms" with a render: the
page then waits that long before its next request (so requests do not sit in the server).
"""
from __future__ import annotations

import json
import math
import re
import struct
import threading
import time
from collections import OrderedDict

import numpy as np

MAGIC = b"T4DV"
CLIENT = re.compile(r"[A-Za-z0-9_-]{1,32}")
MAX_W, MAX_H, MIN_SIDE = 1280, 960, 8
MAX_SERIES = 128
MAX_CLIENTS = 64
WAIT_S = 60.0


class ViewerError(ValueError):
    """Bad query: 400 with this message."""


class Unavailable(Exception):
    """No model yet (503)."""


def _one(query: dict, name: str, default=None) -> str | None:
    values = query.get(name)
    if not values:
        if default is None:
            raise ViewerError(f"missing parameter {name}")
        return default
    return values[0]


def _floats(text: str, count: int, name: str) -> list[float]:
    parts = text.split(",")
    if len(parts) != count:
        raise ViewerError(f"{name} must be {count} comma-separated numbers, got {len(parts)}")
    try:
        out = [float(p) for p in parts]
    except ValueError:
        raise ViewerError(f"{name} holds something that is not a number") from None
    if not all(math.isfinite(v) for v in out):
        raise ViewerError(f"{name} must be finite")
    return out


def parse_view(query: dict) -> dict:
    """The pose, time and size of a render or series request; raises ViewerError."""
    c2w = np.array(_floats(_one(query, "c2w"), 16, "c2w"), np.float64).reshape(4, 4)
    if not np.allclose(c2w[3], [0, 0, 0, 1]) or abs(np.linalg.det(c2w[:3, :3])) < 1e-6:
        raise ViewerError("c2w must be a camera-to-world matrix (last row 0 0 0 1, invertible rotation)")
    t = _floats(_one(query, "t", "0"), 1, "t")[0]
    if not 0.0 <= t <= 1.0:
        raise ViewerError(f"t must be in [0, 1], got {t:g}")
    m = re.fullmatch(r"([0-9]{1,4})x([0-9]{1,4})", _one(query, "size", "320x240"))
    if not m:
        raise ViewerError("size must be WIDTHxHEIGHT, such as 320x240")
    w, h = int(m.group(1)), int(m.group(2))
    if not (MIN_SIDE <= w <= MAX_W and MIN_SIDE <= h <= MAX_H):
        raise ViewerError(f"size must be within {MIN_SIDE}x{MIN_SIDE}..{MAX_W}x{MAX_H}, got {w}x{h}")
    client = _one(query, "client", "anonymous")
    if not CLIENT.fullmatch(client):
        raise ViewerError("client must be 1-32 letters, digits, _ or -")
    return {"c2w": c2w, "t": t, "width": w, "height": h, "client": client}


class Coalescer:
    """One worker thread; per key, only the newest waiting job runs (see the module docstring)."""

    def __init__(self, pace=None):
        self.pace = pace                                  # called before each job is taken (rate limit)
        self._cv = threading.Condition()
        self._pending: OrderedDict = OrderedDict()       # key -> (seq, fn)
        self._done: OrderedDict = OrderedDict()          # key -> (seq, ok, value)
        self._seq = 0
        self.counts = {"submitted": 0, "rendered": 0, "superseded": 0}
        self._stop = False
        self._thread = threading.Thread(target=self._work, name="viewer-render", daemon=True)
        self._thread.start()

    def run(self, key, fn, timeout: float = WAIT_S):
        """Run fn() on the worker unless a newer job of `key` arrives first; -> that job's result
        (this one's, or the newer one's). Raises what fn raised, or TimeoutError."""
        with self._cv:
            self._seq += 1
            mine = self._seq
            self.counts["submitted"] += 1
            if key in self._pending:
                self.counts["superseded"] += 1
                del self._pending[key]
            self._pending[key] = (mine, fn)
            self._cv.notify_all()
            deadline = time.monotonic() + timeout
            while True:
                done = self._done.get(key)
                if done is not None and done[0] >= mine:
                    _, ok, value = done
                    if ok:
                        return value
                    raise value
                left = deadline - time.monotonic()
                if left <= 0 or self._stop:
                    raise TimeoutError("render did not finish in time")
                self._cv.wait(left)

    def _work(self) -> None:
        while True:
            with self._cv:
                while not self._pending and not self._stop:
                    self._cv.wait()
            if self.pace:
                self.pace()
            with self._cv:
                while not self._pending and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
                key, (seq, fn) = self._pending.popitem(last=False)     # oldest key first: clients take turns
            try:
                result = (seq, True, fn())
            except Exception as exc:       # handed to the waiting request(s)
                result = (seq, False, exc)
            with self._cv:
                self.counts["rendered"] += 1
                self._done[key] = result
                self._done.move_to_end(key)
                while len(self._done) > MAX_CLIENTS:
                    self._done.popitem(last=False)
                self._cv.notify_all()

    def stop(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()


def pack_render(header: dict, arrays: dict[str, np.ndarray | None]) -> bytes:
    """The binary reply of /api/view/render (see the module docstring)."""
    blobs, layout, offset = [], {}, 0
    for name, arr in arrays.items():
        if arr is None:
            continue
        arr = np.ascontiguousarray(arr)
        data = arr.astype("<f4").tobytes() if arr.dtype.kind == "f" else arr.tobytes()
        layout[name] = {"offset": offset, "bytes": len(data), "dtype": "float32" if arr.dtype.kind == "f" else "uint8",
                        "shape": list(arr.shape)}
        pad = (-len(data)) % 4
        blobs.append(data + b"\0" * pad)
        offset += len(data) + pad
    head = json.dumps({**header, "arrays": layout}, separators=(",", ":")).encode()
    head += b" " * ((-(8 + len(head))) % 4)
    return MAGIC + struct.pack("<I", len(head)) + head + b"".join(blobs)


def unpack_render(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """Inverse of pack_render (tests, benchmarks, scripts)."""
    if data[:4] != MAGIC:
        raise ValueError("not a viewer render reply")
    (n,) = struct.unpack("<I", data[4:8])
    header = json.loads(data[8:8 + n])
    base, out = 8 + n, {}
    for name, a in header["arrays"].items():
        buf = data[base + a["offset"]: base + a["offset"] + a["bytes"]]
        out[name] = np.frombuffer(buf, "<f4" if a["dtype"] == "float32" else np.uint8).reshape(a["shape"])
    return header, out


def _stats(kelvin: np.ndarray | None) -> dict | None:
    if kelvin is None:
        return None
    return {"min": float(kelvin.min()), "max": float(kelvin.max()), "mean": float(kelvin.mean())}


class ViewerEndpoints:
    """What the handler calls for /view and /api/view/...; -> (status, body, content type)."""

    def __init__(self, renderer):
        self.renderer = renderer
        self.coalescer = Coalescer(getattr(renderer, "pace", None))
        self.page = None

    def info(self) -> dict:
        out = self.renderer.info()
        out["counts"] = dict(self.coalescer.counts)
        return out

    def render(self, query: dict) -> bytes:
        req = parse_view(query)
        asked = time.perf_counter()

        def job():
            started = time.perf_counter()
            out = self.renderer.render(req["c2w"], req["t"], req["width"], req["height"])
            header = {"c2w": req["c2w"].tolist(), "t": req["t"], "width": req["width"], "height": req["height"],
                      "camera": out.get("camera"), "render_ms": out.get("render_ms"),
                      "gaussians": out.get("gaussians"), "kelvin_stats": _stats(out.get("kelvin")),
                      "pace_ms": out.get("pace_ms", 0),
                      "started_unix": time.time(), "queued_ms": round((started - asked) * 1000, 2)}
            return pack_render(header, {"rgb": out.get("rgb"), "kelvin": out.get("kelvin")})

        return self._run((req["client"], "render"), job)

    def series(self, query: dict) -> dict:
        req = parse_view(query)
        px = _floats(_one(query, "px"), 2, "px")
        x, y = int(px[0]), int(px[1])
        if not (0 <= x < req["width"] and 0 <= y < req["height"]):
            raise ViewerError(f"px ({x}, {y}) is outside the {req['width']}x{req['height']} view")
        try:
            n = int(_one(query, "n", "24"))
        except ValueError:
            raise ViewerError("n must be an integer") from None
        if not 2 <= n <= MAX_SERIES:
            raise ViewerError(f"n must be in 2..{MAX_SERIES}, got {n}")
        return self._run((req["client"], "series"),
                         lambda: self.renderer.series(req["c2w"], req["t"], req["width"], req["height"], x, y, n))

    def _run(self, key, fn):
        try:
            return self.coalescer.run(key, fn)
        except LookupError as exc:         # the renderer has no model yet (live training starting)
            raise Unavailable(str(exc)) from None
        except ValueError as exc:
            raise ViewerError(str(exc)) from None

    def close(self) -> None:
        self.coalescer.stop()
