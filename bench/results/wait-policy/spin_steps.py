"""ms per training step of a trained run (resumed, schedule held at its end) vs GOMP_SPINCOUNT, set in the environment:
    GOMP_SPINCOUNT=S python spin_steps.py RUN CROP STEPS   (recon sets it only where the environment does not)"""
import sys, json, time, os
from pathlib import Path
ROOT = str(Path(__file__).resolve().parents[3]); sys.path.insert(0, ROOT); sys.path.insert(0, ROOT + '/bench')
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from train_step import warm_images
run = Path(sys.argv[1]); crop = float(sys.argv[2]); steps = int(sys.argv[3])
scene = Scene(load_dataset(Path(json.loads((run / "scene.json").read_text())["dataset"]))); warm_images(scene)
tr = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda _: None, threads=2)
p = min(tr.progress(), 0.99); tr.progress_fn = lambda _: p; tr.cfg.crop = crop
for _ in range(steps // 3): tr.step()
out = []
for r in range(3):
    t = time.perf_counter()
    for _ in range(steps): tr.step()
    out.append((time.perf_counter() - t) * 1000 / steps)
print(f"spin {os.environ.get('GOMP_SPINCOUNT')} {run.name} crop {crop}: " + " ".join(f"{x:.1f}" for x in out), flush=True)
