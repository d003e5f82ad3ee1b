"""A 600-frame 640x480 dataset loads lazily within the memory bound (measured RSS)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from recon.data import Frame, write_dataset
from recon.data.cache import ByteLRU

ROOT = Path(__file__).resolve().parents[1]
N_RGB, N_THERMAL = 500, 100  # all decoded at once: 500 * 3.7 MB + 100 * 1.2 MB = 1.96 GB


def big_dataset(root: Path) -> None:
    """600 frames of 640x480; pixels are shared hard links so the test writes two PNGs only
    (bench/data_figures.py measures its memory figures on the same set)."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    counts = rng.integers(28000, 32000, (480, 640), dtype=np.uint16)
    first = [(Frame("rgb/0.png", "rgb", "cam0", 0.0, None, np.eye(4), 500, 500, 320, 240, 640, 480), rgb),
             (Frame("thermal/0.png", "thermal", "cam0", 0.0, None, np.eye(4), 1500, 1500, 320, 240, 640, 480),
              counts)]
    write_dataset(root, first, 0.01, (270.0, 330.0))
    doc = json.loads((root / "transforms.json").read_text())
    frames = []
    for modality, n in (("rgb", N_RGB), ("thermal", N_THERMAL)):
        template = next(f for f in doc["frames"] if f["modality"] == modality)
        for i in range(n):
            name = f"{modality}/{i}.png"
            if i:
                os.link(root / f"{modality}/0.png", root / name)
            frames.append({**template, "file_path": name, "time": i / n})
    doc["frames"] = frames
    (root / "transforms.json").write_text(json.dumps(doc))


def test_reading_every_frame_twice_stays_within_the_bound(tmp_path):
    big_dataset(tmp_path)
    code = (
        "import resource, sys, json, numpy as np; from recon.data import load_dataset\n"
        "ds = load_dataset(sys.argv[1]); total = 0\n"
        "for _ in range(2):\n"
        "    for f in ds.frames: total += float(np.nanmean(ds.image(f)[::97, ::97]))\n"
        "print(json.dumps({'frames': len(ds), 'cache': ds.cache_bytes_used,\n"
        "                  'peak_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))"
    )
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=ROOT,
                         capture_output=True, text=True, check=True)
    stats = json.loads(out.stdout)
    assert stats["frames"] == 600
    assert stats["cache"] <= 1 << 30
    assert stats["peak_mb"] < 1700, stats  # ~2 GB would be needed without the bound


def test_lru_evicts_least_recent_by_bytes():
    cache = ByteLRU(max_bytes=3000)
    make = lambda: np.zeros(1000, np.uint8)
    a, b, c = (cache.get(k, make) for k in "abc")
    cache.get("a", make)          # a is now the most recent
    cache.get("d", make)          # evicts b
    assert cache.nbytes == 3000 and len(cache) == 3
    loads = []
    cache.get("b", lambda: loads.append(1) or np.zeros(1000, np.uint8))
    assert loads == [1]           # b had been evicted
    assert cache.get("a", lambda: 1 / 0) is a  # a survived
    huge = cache.get("huge", lambda: np.zeros(5000, np.uint8))
    assert huge.nbytes == 5000 and "huge" not in cache._items
