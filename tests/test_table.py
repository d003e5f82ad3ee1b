"""bench/table.py --iterations: a run of a fixed length is the same numbers every time, so two arms
can be paired without the spread a wall-clock budget brings (its iteration count follows the
host's speed: the same dtg runs twice at 3 min differed by up to 1.3 K on a seed)."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.usefixtures("two_threads")


@pytest.fixture(scope="module")
def table():
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        import table
        yield table
    finally:
        sys.path.remove(str(ROOT / "bench"))


def test_a_fixed_length_run_grades_at_its_iterations_and_repeats_exactly(table, tmp_path):
    data = tmp_path / "data"
    simulate_dataset(data, SimulateConfig(variant="family-fast", frames=6, width=40, height=30, seed=3, points=300))
    curves = []
    for k in range(2):
        cfg = make_config("dtg", iterations=60, log_every=10**9, checkpoint_every=10**9)
        assert cfg.minutes is None and not cfg.stop.converge
        trainer, curve = table.train_with_curve(cfg, Scene(load_dataset(data)), tmp_path / f"run{k}", 3, lambda _: None)
        assert trainer.iteration == 60
        curves.append(curve)
    assert [c["iteration"] for c in curves[0]] == [20, 40, 60]
    strip = lambda c: [{k: v for k, v in row.items() if k != "seconds"} for row in c]     # noqa: E731
    assert strip(curves[0]) == strip(curves[1])
    assert curves[0][-1]["psnr_thermal"] != curves[0][0]["psnr_thermal"]       # it trained between them


def test_train_seeds_repeat_each_run_and_the_table_reports_their_mean_and_spread(tmp_path):
    """--train-seeds 0,1: each (scene seed, method) trains twice with config seeds 0 and 1; the
    two runs differ (another seed is another training), the table's cell is their mean and its
    spread line their difference."""
    out = tmp_path / "t"
    run = subprocess.run([sys.executable, "bench/table.py", "--out", str(out), "--scenes", "family-fast", "--seeds", "3",
                          "--methods", "dtg", "--iterations", "30", "--train-seeds", "0,1", "--frames", "6",
                          "--size", "40x30", "--checkpoints", "1", "--jobs", "1", "--threads", "2"],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert (out / "runs" / "family-fast-s3" / "dtg").is_dir() and (out / "runs" / "family-fast-s3" / "dtg@t1").is_dir()
    table = json.loads((out / "table.json").read_text())
    runs = sorted(table["per_run"], key=lambda r: r["train_seed"])
    assert [r["train_seed"] for r in runs] == [0, 1] and {r["method"] for r in runs} == {"dtg"}
    a, b = (r["mae_k_thermal"] for r in runs)
    assert a != b
    (cell,) = table["aggregate"].values()
    assert cell["dtg"]["seeds"] == 1
    assert cell["dtg"]["mae_k_thermal"] == pytest.approx((a + b) / 2)
    assert table["train_seed_spread"]["family-fast"]["dtg"]["mae_k_thermal"] == pytest.approx(abs(a - b))
    assert "mean of 2 training seeds" in (out / "table.md").read_text()
