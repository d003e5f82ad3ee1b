"""A fake iPhone: QuickTime movies like the phone's (1/600 time base, per-frame PTS that may be
variable-rate, `com.apple.quicktime.creationdate` with a UTC offset) and a copy into the drop
folder that takes a while, as AirDrop/USB copies do."""
from __future__ import annotations

import datetime as dt
import os
import shutil
import time
from pathlib import Path
from typing import Iterable

import numpy as np

from rig.simulated import write_quicktime


def iso_creationdate(unix_s: float, utc_offset_h: int = 2) -> str:
    """The phone's form: local time, whole seconds, offset without colon."""
    tz = dt.timezone(dt.timedelta(hours=utc_offset_h))
    return dt.datetime.fromtimestamp(int(unix_s), tz).strftime("%Y-%m-%dT%H:%M:%S%z")


def write_mov(path: str | Path, frames: Iterable[np.ndarray], pts_s: Iterable[float],
              creation_unix_s: float, codec: str = "libx264", utc_offset_h: int = 2) -> Path:
    """A phone movie of the given (H, W, 3) uint8 frames at `pts_s` seconds from the start."""
    return write_quicktime(path, frames, pts_s, creation_unix_s, codec=codec, utc_offset_h=utc_offset_h)


def drop_slowly(src: str | Path, drop_dir: str | Path, chunk: int = 64 << 10, delay_s: float = 0.01) -> Path:
    """Copy `src` into the drop folder in pieces, like a transfer in progress."""
    dst = Path(drop_dir) / Path(src).name
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        while data := fi.read(chunk):
            fo.write(data)
            fo.flush()
            os.fsync(fo.fileno())
            time.sleep(delay_s)
    return dst


def drop_now(src: str | Path, drop_dir: str | Path) -> Path:
    return Path(shutil.copy2(src, Path(drop_dir) / Path(src).name))
