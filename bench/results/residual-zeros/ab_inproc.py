"""In-process A/B of DTGModel.render_inputs: 9e4220a's (A, its source read from git) against this
checkout's (B), alternated in blocks of 10 steps on a trained 640x480 run's windows.

    python bench/results/residual-zeros/ab_inproc.py ROUNDS [RUN]     # -> ab.txt"""
import sys, json, time, torch, subprocess, types, statistics as st
from pathlib import Path
ROOT = str(Path(__file__).resolve().parents[3]); sys.path.insert(0, ROOT + '/bench'); sys.path.insert(0, ROOT)
from recon.train.trainer import Trainer
from recon.scene import Scene
from recon.data import load_dataset
from recon.dtg import model as new
from train_step import warm_images
src = subprocess.run(['git', '-C', ROOT, 'show', '9e4220a:recon/dtg/model.py'], capture_output=True, text=True).stdout
old = types.ModuleType('recon.dtg.model_old'); old.__file__ = 'old'
exec(compile(src, 'model_old.py', 'exec'), old.__dict__)
fns = {'A': old.DTGModel.render_inputs, 'B': new.DTGModel.render_inputs}
run = Path(sys.argv[2] if len(sys.argv) > 2 else '/work/exp/s39/run-new')   # the 640x480 run of docs/training.md
data = Path(json.loads((run / "scene.json").read_text())["dataset"])
scene = Scene(load_dataset(data)); warm_images(scene)
tr = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda _: None, threads=2)
p = min(tr.progress(), 0.99); tr.progress_fn = lambda _: p
for _ in range(5): tr.step()
res = {'A': [], 'B': []}
for r in range(int(sys.argv[1]) if len(sys.argv) > 1 else 20):
    for k in ('A', 'B') if r % 2 == 0 else ('B', 'A'):
        new.DTGModel.render_inputs = fns[k]
        t = time.perf_counter()
        for _ in range(10): tr.step()
        res[k].append((time.perf_counter() - t) / 10 * 1e3)
wins = sum(b < a for a, b in zip(res['A'], res['B']))
print(f"A (9e4220a) median {st.median(res['A']):.1f} ms, B median {st.median(res['B']):.1f} ms; B faster in {wins} of {len(res['A'])} rounds")
