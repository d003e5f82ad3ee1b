"""python train_ov.py DATA OUT ITER 'JSON overrides'  -> OUT/checkpoints/latest.pt + metrics line"""
import sys, json, torch
from pathlib import Path
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from recon.config import make_config
from table import apply_overrides
from recon.scene import Scene
from recon.data import load_dataset
from recon.train.trainer import Trainer
from recon.run import evaluate_model
data, out, iters, ov = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), json.loads(sys.argv[4])
cfg = make_config('dtg', iterations=iters, threads=1, log_every=10**9)
apply_overrides(cfg, ov); cfg.stop.converge = False
scene = Scene(load_dataset(data))
tr = Trainer(cfg, scene, out, log=lambda _: None)
tr.train()
m = evaluate_model(tr, every=2)
th = m['regions']['thermal']
print(out.name, 'mae %.2f static %.2f moving %.2f' % (m['thermal']['mae_k'], th['static']['mae_k'], th['moving']['mae_k']),
      {k: round(v['mae_k'], 2) for k, v in m['objects']['thermal'].items()}, flush=True)
with torch.no_grad():
    outs = [tr.model.stage_residuals('thermal', t, 1.0) for t in torch.linspace(0.02, 0.98, 25).tolist()]
print(out.name, 'time std', ' '.join('%s %.4f' % (k[:8], float(torch.stack([o[k] for o in outs]).std(0).mean())) for k in outs[0]))
