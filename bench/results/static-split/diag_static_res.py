"""On a finished dtg run: grade the test views as trained, and with F_th's residuals zeroed on the
static Gaussians (motion_basis == 0): opacity only / geometry only / both.

    python bench/results/static-split/diag_static_res.py RUN DATA >> diag_static_res.txt"""
import sys, json, torch
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.run import evaluate_model
from recon.dtg.model import GEOMETRY
run, data = Path(sys.argv[1]), Path(sys.argv[2])
torch.set_num_threads(1)
scene = Scene(load_dataset(data))
tr = Trainer.resume(run / 'checkpoints' / 'latest.pt', scene, log=lambda _: None)
model = tr.model
orig = model.stage_residuals
MODE = set()
def patched(stage, t, progress, rows=None):
    res = orig(stage, t, progress, rows=rows)
    static = model.gaussians['motion_basis'] == 0
    out = {}
    for k, v in res.items():
        if (k.startswith('opacity') and 'op' in MODE) or (k in GEOMETRY and 'geo' in MODE):
            st = static if v.shape[0] == static.shape[0] else static[rows]
            v = torch.where(st.view(-1, *[1] * (v.dim() - 1)), torch.zeros_like(v), v)
        out[k] = v
    return out
model.stage_residuals = patched
def grade():
    m = evaluate_model(tr, every=2); r = m['regions']['thermal']; o = m['objects']['thermal']
    objs = ' '.join(f"{k.split()[0]}{'' if 'moving' not in k else k.split()[-1]}={v['mae_k']:.1f}" for k, v in o.items())
    return f"MAE {m['thermal']['mae_k']:.2f} mov {r['moving']['mae_k']:.1f} static {r['static']['mae_k']:.2f} | {objs}"
for mode in ([], ['op'], ['geo'], ['op', 'geo']):
    MODE.clear(); MODE.update(mode)
    with torch.no_grad():
        print(run.parent.name, '+'.join(mode) or 'as trained', grade(), flush=True)
