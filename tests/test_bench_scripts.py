"""bench/ must keep running against the code it measures (issue 14: every script runs on a fresh
install). Once, a changed native signature broke bench/rasterizer.py's records for weeks while it
still exited 0; these cheap runs catch that in CI."""
import importlib
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_bench_script_imports():
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        for script in sorted((ROOT / "bench").glob("*.py")):
            importlib.import_module(script.stem)  # a missing dependency raises here
    finally:
        sys.path.remove(str(ROOT / "bench"))


def test_rasterizer_bench_measures_our_implementations(tmp_path):
    out = tmp_path / "r.json"
    impls = ["recon.splat", "recon.splat:raster", "recon.splat:proj", "recon.splat:train"]
    run = subprocess.run([sys.executable, "bench/rasterizer.py", "--out", str(out), "--sizes", "2000",
                          "--reps", "5", "--impls", ",".join(impls)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    records = json.loads(out.read_text())
    assert [r["impl"] for r in records] == impls
    for r in records:
        assert r["forward_ms"] > 0 and r["forward_backward_ms"] > 0, r
    stages = records[0]["breakdown_ms"]
    assert stages["tile_pairs"] > 0 and stages["visible"] > 1000, stages
