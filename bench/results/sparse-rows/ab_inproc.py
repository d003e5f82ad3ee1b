"""Needs the tree of b70ac88 (sparse_rows), removed after this measurement.

    python bench/results/sparse-rows/ab_inproc.py ROUNDS RUN640 > bench/results/sparse-rows/ab.txt

In-process A/B on the trained 640x480 run's windows: alternate blocks of steps with the embedding
smoothness gathered by sparse_rows (B) and by gather_rows (A, as before); per-block ms/step."""
import sys, json, time, statistics, torch
ROOT = __import__('pathlib').Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT / 'bench')); sys.path.insert(0, str(ROOT))
from pathlib import Path
from recon.train.trainer import Trainer
from recon.scene import Scene
from recon.data import load_dataset
from recon.dtg import losses
from train_step import warm_images
run = Path(sys.argv[2])  # a trained 640x480 run (docs/training.md: RUN640)
data = Path(json.loads((run / "scene.json").read_text())["dataset"])
scene = Scene(load_dataset(data)); warm_images(scene)
tr = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda _: None, threads=2)
p = min(tr.progress(), 0.99); tr.progress_fn = lambda _: p
sparse = losses.sparse_rows
for _ in range(10): tr.step()
res = {'A': [], 'B': []}
for r in range(int(sys.argv[1])):
    for side in ('A', 'B') if r % 2 == 0 else ('B', 'A'):
        losses.sparse_rows = sparse if side == 'B' else losses.gather_rows
        t = time.perf_counter()
        for _ in range(15): tr.step()
        res[side].append((time.perf_counter() - t) / 15 * 1e3)
for k, v in res.items():
    print(k, 'median %.1f' % statistics.median(v), ' '.join('%.1f' % x for x in v))
print('B - A per round:', ' '.join('%.1f' % (b - a) for a, b in zip(res['A'], res['B'])))
