"""The trainer's thread share through idle / one core busy / idle phases (ticks, as recon run does):
    [GOMP_SPINCOUNT=S] python share_phases.py RUN CROP share|fixed"""
import sys, json, time, os, subprocess
from pathlib import Path
ROOT = str(Path(__file__).resolve().parents[3]); sys.path.insert(0, ROOT); sys.path.insert(0, ROOT + '/bench')
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from train_step import warm_images
run = Path(sys.argv[1]); crop = float(sys.argv[2]); share = sys.argv[3] == 'share'
scene = Scene(load_dataset(Path(json.loads((run / "scene.json").read_text())["dataset"]))); warm_images(scene)
logs = []
tr = Trainer.resume(run / "checkpoints" / "latest.pt", scene, log=lambda m: logs.append((round(time.monotonic() - T0, 2), m)), threads=2, share_cores=share)
T0 = time.monotonic()
p = min(tr.progress(), 0.99); tr.progress_fn = lambda _: p; tr.cfg.crop = crop
tr.cfg.log_every = tr.cfg.eval_every = tr.cfg.checkpoint_every = 10**9
for _ in range(5): tr.tick()
busy = None
for phase, secs in (("idle", 6), ("busy", 8), ("idle again", 6)):
    if phase == "busy":
        busy = subprocess.Popen([sys.executable, "-c", "while 1: pass"])
    elif busy:
        busy.kill()
    t = time.perf_counter(); n = 0
    while time.perf_counter() - t < secs:
        tr.tick(); n += 1
    print(f"{'share' if share else 'fixed'} GOMP_SPINCOUNT {os.environ.get('GOMP_SPINCOUNT')} {run.name} {phase}: {1000 * (time.perf_counter() - t) / n:.1f} ms/step ({n} steps)", flush=True)
for l in logs: print("  ", *l)
