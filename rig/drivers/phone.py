"""Phone drop folder: videos (MOV/MP4, HEVC or H.264) and photos (HEIC/JPEG) as the phone hands
them over (AirDrop, USB copy, a synced folder).

A file counts as arrived once its size and mtime have stayed the same for `settle_s` and the
container opens; partial names (`.part`, `.tmp`, `.crdownload`, hidden files) are ignored.
Frame times are each frame's presentation timestamp (iPhone movies use a 1/600 time base and
may be variable-rate), never index / fps. `com.apple.quicktime.creationdate` (local time with
UTC offset, 1 s resolution) only places a file roughly; `rig.sync` does the fine alignment.
"""
from __future__ import annotations

import datetime as dt
import logging
import os
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import av
import numpy as np

from rig.sync import change_energy, thumbnail

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = {".mov", ".mp4", ".m4v"}
PHOTO_SUFFIXES = {".heic", ".heif", ".jpg", ".jpeg"}
PARTIAL_SUFFIXES = {".part", ".tmp", ".crdownload", ".download", ".partial"}


def parse_creationdate(text: str) -> float | None:
    """ISO-8601 with offset ('2024-05-01T12:34:56+0200', '...Z') -> Unix seconds."""
    if not text:
        return None
    s = text.strip().replace("Z", "+00:00")
    if len(s) >= 5 and s[-5] in "+-" and s[-3] != ":":       # +0200 -> +02:00
        s = s[:-2] + ":" + s[-2:]
    try:
        t = dt.datetime.fromisoformat(s)
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.timezone.utc)
    return t.timestamp()


@dataclass
class VideoInfo:
    path: Path
    codec: str
    width: int
    height: int
    time_base: tuple[int, int]
    creationdate: str | None          # as written by the phone
    creation_unix_s: float | None
    frames: list[dict] = field(default_factory=list)   # {"frame", "pts", "pts_s", "motion"}

    @property
    def duration_s(self) -> float:
        return self.frames[-1]["pts_s"] - self.frames[0]["pts_s"] if len(self.frames) > 1 else 0.0

    def file_record(self) -> dict:
        return {"codec": self.codec, "width": self.width, "height": self.height,
                "time_base": list(self.time_base), "creationdate": self.creationdate,
                "creation_unix_s": self.creation_unix_s, "duration_s": self.duration_s}


def pts_drops(pts_s) -> int:
    """Frames missing from a variable-rate video, judged by its (N,) frame times in seconds:
    an interval over 1.5 median intervals lacks round(interval / median) - 1 frames."""
    d = np.diff(np.asarray(pts_s, float))
    if len(d) < 2:
        return 0
    med = float(np.median(d))
    return int(sum(round(g / med) - 1 for g in d if g > 1.5 * med))


def probe_video(path: str | Path) -> VideoInfo:
    """Decode a whole video once: per-frame PTS and motion energy (`rig.sync.change_energy` of
    grey thumbnails, 0 for the first), plus the container's creation date."""
    path = Path(path)
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        meta = {**container.metadata, **stream.metadata}
        created = meta.get("com.apple.quicktime.creationdate") or meta.get("creation_time")
        tb = stream.time_base or Fraction(1, 600)
        info = VideoInfo(path, stream.codec_context.name, stream.codec_context.width,
                         stream.codec_context.height, (tb.numerator, tb.denominator), created,
                         parse_creationdate(created) if created else None)
        prev = None
        for frame in container.decode(stream):
            if frame.pts is None:
                continue
            g = thumbnail(frame.to_ndarray(format="gray"))
            motion = change_energy(prev, g)
            prev = g
            info.frames.append({"frame": len(info.frames), "pts": int(frame.pts),
                                "pts_s": float(frame.pts * tb), "motion": motion})
    if not info.frames:
        raise ValueError(f"{path}: no decodable video frames")
    return info


def decode_frames(path: str | Path, start_pts: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (pts, (H, W, 3) uint8 RGB) in presentation order, from `start_pts` on."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        if start_pts:
            container.seek(start_pts, stream=stream, backward=True, any_frame=False)
        for frame in container.decode(stream):
            if frame.pts is None or (start_pts is not None and frame.pts < start_pts):
                continue
            yield int(frame.pts), frame.to_ndarray(format="rgb24")


def read_photo(path: str | Path) -> np.ndarray:
    """HEIC/HEIF (needs pillow-heif) or JPEG -> (H, W, 3) uint8 RGB."""
    from PIL import Image
    path = Path(path)
    if path.suffix.lower() in (".heic", ".heif"):
        try:
            import pillow_heif
        except ImportError as exc:
            raise RuntimeError(f"{path}: reading HEIC needs the pillow-heif package") from exc
        pillow_heif.register_heif_opener()
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


class DropFolder:
    """Watches a folder; `poll()` returns files that finished arriving, each once, oldest first."""

    def __init__(self, path: str | Path, settle_s: float = 1.0):
        self.path = Path(path)
        if not self.path.is_dir():
            raise NotADirectoryError(f"phone drop folder {self.path} does not exist")
        self.settle_s = settle_s
        self._seen: dict[Path, tuple[int, int, float]] = {}   # path -> (size, mtime_ns, stable since)
        self._done: set[Path] = set()

    @staticmethod
    def wanted(p: Path) -> bool:
        suffix = p.suffix.lower()
        return (not p.name.startswith(".") and suffix not in PARTIAL_SUFFIXES
                and suffix in VIDEO_SUFFIXES | PHOTO_SUFFIXES)

    def poll(self, now: float | None = None) -> list[Path]:
        import time
        now = time.monotonic() if now is None else now
        ready = []
        for p in sorted(self.path.iterdir(), key=lambda q: q.name):
            if p in self._done or not p.is_file() or not self.wanted(p):
                continue
            try:
                st = os.stat(p)
            except FileNotFoundError:       # renamed away between listing and stat
                continue
            key = (st.st_size, st.st_mtime_ns)
            prev = self._seen.get(p)
            if prev is None or prev[:2] != key:
                self._seen[p] = (*key, now)
            elif st.st_size > 0 and now - prev[2] >= self.settle_s:
                ready.append(p)
        return ready

    def pending(self) -> list[Path]:
        """Wanted files seen in the folder and not yet handed over."""
        return [p for p in self.path.iterdir()
                if p.is_file() and self.wanted(p) and p not in self._done]

    def mark_done(self, path: Path) -> None:
        self._done.add(path)
        self._seen.pop(path, None)
