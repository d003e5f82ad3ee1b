"""Crash-safe, append-only capture session folder: writer and reader.

Layout (documented in docs/rig.md, section "Session folder"):

    SESSION/
      session.json              created once (atomic rename): format, host clock pair, devices
      thermal/chunk-000000.raw  thermal payloads as received, back to back (little-endian uint16)
      thermal.jsonl             one record per thermal frame (block id, device/host time, IRFormat,
                                scale, losses, where its bytes are)
      rgb/IMG_0001.MOV ...      phone files as received (hard-linked or copied, never re-encoded)
      rgb.jsonl                 one record per RGB frame (file, frame number, PTS, time base)
      events.jsonl              acquisition epochs, NUCs (commanded, detected pauses), IRFormat
                                changes, sync-box markers and clock, file arrivals
      sync.json                 latest sync estimate (replaced atomically)
      closed.json               written at a clean end (summary); absent while capturing / after a crash

Durability rule: a record is appended to a `.jsonl` index only after the bytes it points to
are fsync'ed, and each append is one `write` followed by `fdatasync`. A crash can leave at
most a torn last line (no trailing newline) and unreferenced bytes at the end of a chunk;
the reader ignores both, so every frame that has a record is complete and readable.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

log = logging.getLogger(__name__)

FORMAT = "thermal4d-session"
VERSION = 1
CHUNK_BYTES = 256 << 20
DTYPES = {8: np.uint8, 16: np.dtype("<u2")}


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_json_atomic(path: Path, obj) -> None:
    """Replace `path` with `obj` as JSON so readers see the old or the new file, never half."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def host_clock_pair() -> dict:
    """Monotonic and wall-clock ns read together: converts record host_ns to UTC."""
    m0 = time.monotonic_ns()
    r = time.time_ns()
    m1 = time.monotonic_ns()
    return {"monotonic_ns": (m0 + m1) // 2, "realtime_ns": r}


class _AppendLog:
    """A JSON-lines file; every `append` is durable when it returns."""

    def __init__(self, path: Path):
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)

    def append(self, records: list[dict]) -> None:
        if records:
            data = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in records).encode()
            os.write(self.fd, data)
            os.fdatasync(self.fd)

    def close(self) -> None:
        os.close(self.fd)


class SessionWriter:
    """Append frames to a new session folder. Not thread-safe: use one writer thread."""

    def __init__(self, path: str | Path, meta: dict, chunk_bytes: int = CHUNK_BYTES):
        self.path = Path(path)
        if self.path.exists() and any(self.path.iterdir()):
            raise FileExistsError(f"session folder {self.path} exists and is not empty")
        (self.path / "thermal").mkdir(parents=True, exist_ok=True)
        (self.path / "rgb").mkdir(exist_ok=True)
        self.meta = {"format": FORMAT, "version": VERSION, "host_clock": host_clock_pair(), **meta}
        write_json_atomic(self.path / "session.json", self.meta)
        self.thermal_log = _AppendLog(self.path / "thermal.jsonl")
        self.rgb_log = _AppendLog(self.path / "rgb.jsonl")
        self.event_log = _AppendLog(self.path / "events.jsonl")
        _fsync_dir(self.path)
        self.chunk_bytes = chunk_bytes
        self.n_thermal = 0
        self.n_rgb = 0
        self._chunk = -1
        self._chunk_fd = -1
        self._chunk_size = 0

    def _chunk_name(self, i: int) -> str:
        return f"thermal/chunk-{i:06d}.raw"

    def _open_chunk(self) -> None:
        if self._chunk_fd >= 0:
            os.close(self._chunk_fd)
        self._chunk += 1
        self._chunk_fd = os.open(self.path / self._chunk_name(self._chunk),
                                 os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self._chunk_size = 0
        _fsync_dir(self.path / "thermal")

    def add_thermal(self, frames: list[tuple[bytes, dict]]) -> list[int]:
        """Append thermal frames (raw payload, record): bytes first and fsync'ed, then the
        records in one durable append. Batching several frames is a group commit.
        -> the frame indices."""
        records = []
        for data, rec in frames:
            if self._chunk_fd < 0 or (self._chunk_size and self._chunk_size + len(data) > self.chunk_bytes):
                if self._chunk_fd >= 0:
                    os.fdatasync(self._chunk_fd)
                self._open_chunk()
            os.write(self._chunk_fd, data)
            records.append({"i": self.n_thermal, **rec, "chunk": self._chunk_name(self._chunk),
                            "offset": self._chunk_size, "nbytes": len(data)})
            self._chunk_size += len(data)
            self.n_thermal += 1
        if records:
            os.fdatasync(self._chunk_fd)
            self.thermal_log.append(records)
        return [r["i"] for r in records]

    def add_rgb_file(self, src: str | Path, frames: list[dict], file_record: dict | None = None) -> str:
        """Bring a finished phone file into `rgb/` (hard link, else copy), make it durable,
        then append one record per frame (each gets `file`) and an `rgb_file` event."""
        src = Path(src)
        dest = self.path / "rgb" / src.name
        n = 1
        while dest.exists():
            dest = dest.with_name(f"{src.stem}_{n}{src.suffix}")
            n += 1
        tmp = dest.with_name(f".{dest.name}.part")
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, dest)
        _fsync_dir(dest.parent)
        rel = f"rgb/{dest.name}"
        records = []
        for rec in frames:
            records.append({"i": self.n_rgb, "file": rel, **rec})
            self.n_rgb += 1
        self.rgb_log.append(records)
        self.add_event({"event": "rgb_file", "file": rel, "source": str(src), "frames": len(frames),
                        **(file_record or {})})
        return rel

    def add_event(self, record: dict) -> None:
        self.event_log.append([record])

    def write_sync(self, result: dict) -> None:
        write_json_atomic(self.path / "sync.json", result)

    def close(self, summary: dict | None = None) -> None:
        if self._chunk_fd >= 0:
            os.fdatasync(self._chunk_fd)
            os.close(self._chunk_fd)
            self._chunk_fd = -1
        for log_ in (self.thermal_log, self.rgb_log, self.event_log):
            log_.close()
        write_json_atomic(self.path / "closed.json", {"closed_host_ns": time.monotonic_ns(),
                                                      "thermal_frames": self.n_thermal,
                                                      "rgb_frames": self.n_rgb, **(summary or {})})


# -- reading ---------------------------------------------------------------------------------------

class _Tail:
    """Complete lines appended to a JSON-lines file since the last call; a torn last line
    (no newline yet, or never: the writer crashed) is left for later."""

    def __init__(self, path: Path):
        self.path = path
        self.offset = 0
        self.bad_lines = 0

    def read_new(self) -> list[dict]:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return []
        end = data.rfind(b"\n") + 1
        self.offset += end
        out = []
        for line in data[:end].splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:          # e.g. zero-filled blocks after a power loss
                self.bad_lines += 1
        return out


@dataclass
class ThermalFrame:
    """One thermal frame: `counts` (H, W) as received, `record` its index entry."""
    record: dict
    counts: np.ndarray
    epoch: dict | None = None

    @property
    def index(self) -> int:
        return self.record["i"]

    @property
    def complete(self) -> bool:
        return self.record["complete"]

    def kelvin(self) -> np.ndarray:
        """(H, W) float64 kelvin with the IRFormat in force when the frame was produced."""
        from rig.drivers import flir
        rec = self.record
        if rec.get("scale_k"):
            return self.counts.astype(np.float64) * rec["scale_k"] + rec.get("offset_k", 0.0)
        if rec.get("ir_format") == "Counts":
            raise ValueError(f"thermal frame {rec['i']}: raw counts of a camera without radiometric features "
                             f"(generic profile) and no counts-to-kelvin map; record with `rig capture "
                             f"--kelvin-map GAIN,OFFSET` to get temperatures")
        ep = self.epoch or {}
        cal = ep.get("calibration")
        return flir.counts_to_kelvin(self.counts, rec["ir_format"],
                                     flir.ObjectParameters(**ep.get("object_parameters", {})),
                                     flir.RadiometricCalibration(**cal) if cal else None)


@dataclass
class RgbFrame:
    """One decoded phone frame: `image` (H, W, 3) uint8 RGB."""
    record: dict
    image: np.ndarray

    @property
    def index(self) -> int:
        return self.record["i"]


class Session:
    """Reader of a session folder, safe while the capture is still appending.

    `refresh()` picks up newly committed records; `thermal`/`rgb`/`events` are the records
    known so far (dicts, see docs/rig.md); `thermal_frame(i)`, `iter_thermal()`, `iter_rgb()`
    load data; `follow()` yields frames as they are committed until the capture closes.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        meta_path = self.path / "session.json"
        if not meta_path.is_file():
            raise FileNotFoundError(f"{self.path} is not a thermal4d session (no session.json)")
        self.meta = _read_json(meta_path)
        if not isinstance(self.meta, dict) or self.meta.get("format") != FORMAT:
            found = self.meta.get("format") if isinstance(self.meta, dict) else type(self.meta).__name__
            raise ValueError(f"{meta_path}: format {found!r}, expected {FORMAT!r}")
        self.thermal: list[dict] = []
        self.rgb: list[dict] = []
        self.events: list[dict] = []
        self.epochs: dict[int, dict] = {}
        self._tails = {"thermal": _Tail(self.path / "thermal.jsonl"),
                       "rgb": _Tail(self.path / "rgb.jsonl"),
                       "events": _Tail(self.path / "events.jsonl")}
        self.refresh()

    def refresh(self) -> dict[str, int]:
        """Read newly committed records. -> number of new records per index."""
        new = {}
        # events first: a frame's epoch event is committed before the frame
        for name in ("events", "thermal", "rgb"):
            recs = self._tails[name].read_new()
            getattr(self, name).extend(recs)
            new[name] = len(recs)
            if name == "events":
                for e in recs:
                    if e.get("event") == "epoch":
                        self.epochs[e["epoch"]] = e
        return new

    @property
    def closed(self) -> bool:
        """True once the capture ended cleanly (false while running or after a crash)."""
        return (self.path / "closed.json").is_file()

    @property
    def summary(self) -> dict | None:
        p = self.path / "closed.json"
        return _read_json(p) if p.is_file() else None

    @property
    def sync(self) -> dict | None:
        p = self.path / "sync.json"
        return _read_json(p) if p.is_file() else None

    @property
    def torn_or_bad_lines(self) -> int:
        return sum(t.bad_lines for t in self._tails.values())

    def host_ns_to_unix_s(self, host_ns: int) -> float:
        hc = self.meta["host_clock"]
        return (hc["realtime_ns"] + host_ns - hc["monotonic_ns"]) / 1e9

    # -- thermal --------------------------------------------------------------------------
    def thermal_frame(self, i: int) -> ThermalFrame:
        rec = self.thermal[i]
        bits = 8 if rec.get("pixel_format") == "Mono8" else 16
        with open(self.path / rec["chunk"], "rb") as f:
            f.seek(rec["offset"])
            data = f.read(rec["nbytes"])
        if len(data) != rec["nbytes"]:
            raise OSError(f"{self.path / rec['chunk']}: frame {i} truncated ({len(data)}/{rec['nbytes']} bytes)")
        counts = np.frombuffer(data, DTYPES[bits], count=rec["width"] * rec["height"])
        return ThermalFrame(rec, counts.reshape(rec["height"], rec["width"]), self.epochs.get(rec.get("epoch")))

    def iter_thermal(self, start: int = 0) -> Iterator[ThermalFrame]:
        for i in range(start, len(self.thermal)):
            yield self.thermal_frame(i)

    # -- rgb ------------------------------------------------------------------------------
    def iter_rgb(self, start: int = 0) -> Iterator[RgbFrame]:
        """Decode RGB frames of records[start:], file by file, matching PTS."""
        from rig.drivers.phone import decode_frames
        recs = self.rgb[start:]
        i = 0
        while i < len(recs):
            file = recs[i]["file"]
            j = i
            while j < len(recs) and recs[j]["file"] == file:
                j += 1
            wanted = {r["pts"]: r for r in recs[i:j]}
            for pts, image in decode_frames(self.path / file, min(wanted)):
                rec = wanted.pop(pts, None)
                if rec is not None:
                    yield RgbFrame(rec, image)
                if not wanted:
                    break
            i = j

    # -- live ------------------------------------------------------------------------------
    def follow(self, poll_s: float = 0.2, timeout_s: float | None = None
               ) -> Iterator[tuple[str, ThermalFrame | RgbFrame | dict]]:
        """Yield ("thermal", ThermalFrame), ("rgb", RgbFrame) and ("event", dict) as they are
        committed, from the start, until the capture is closed and everything was yielded
        (or nothing new arrived for `timeout_s`)."""
        nt = nr = ne = 0
        last_new = time.monotonic()
        while True:
            closed = self.closed            # read before refreshing: nothing is added after close
            self.refresh()
            progressed = False
            while ne < len(self.events):
                yield "event", self.events[ne]
                ne += 1
                progressed = True
            for frame in self.iter_thermal(nt):
                yield "thermal", frame
                nt += 1
                progressed = True
            if nr < len(self.rgb):
                for frame in self.iter_rgb(nr):
                    yield "rgb", frame
                nr = len(self.rgb)
                progressed = True
            if progressed:
                last_new = time.monotonic()
            elif closed:
                return
            elif timeout_s is not None and time.monotonic() - last_new > timeout_s:
                return
            else:
                time.sleep(poll_s)


def open_session(path: str | Path) -> Session:
    """Open a session folder for reading (also while `rig capture` is writing it)."""
    return Session(path)


def _read_json(path: Path):
    """A session's JSON file; a damaged one is a ValueError that names it."""
    try:
        return json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); restore it from a copy or record the session "
                         f"again") from None
