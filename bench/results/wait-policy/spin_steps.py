"""ms per training step of a trained run (resumed, schedule held at its end) vs GOMP_SPINCOUNT, set in the environment:
    [THREADS=N] GOMP_SPINCOUNT=S python spin_steps.py RUN CROP STEPS   (recon sets it only where the environment does not)"""
import sys, time, os
from pathlib import Path
ROOT = str(Path(__file__).resolve().parents[3]); sys.path.insert(0, ROOT); sys.path.insert(0, ROOT + '/bench')
from train_step import resume_held, warm_images
run = Path(sys.argv[1]); crop = float(sys.argv[2]); steps = int(sys.argv[3])
tr, p = resume_held(run, int(os.environ.get("THREADS", "2")), crop=crop); warm_images(tr.scene)
for _ in range(steps // 3): tr.step()
out = []
for r in range(3):
    t = time.perf_counter()
    for _ in range(steps): tr.step()
    out.append((time.perf_counter() - t) * 1000 / steps)
print(f"threads {os.environ.get('THREADS', '2')} spin {os.environ.get('GOMP_SPINCOUNT')} {run.name} crop {crop}: " + " ".join(f"{x:.1f}" for x in out), flush=True)
