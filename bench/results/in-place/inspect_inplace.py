"""python bench/results/in-place/inspect_inplace.py RUN DATA: a train_ov run's held Gaussians, those on still blobs now, their displacement and F_th's temperature residuals over time."""
import sys, torch, numpy as np
from pathlib import Path
from recon.train.checkpoint import read_checkpoint
from recon.config import config_from_dict
from recon.dtg.model import DTGModel
from recon.scene import Scene
from recon.data import load_dataset
from recon.train import paths as P
from recon.config import make_config
run, data = Path(sys.argv[1]), Path(sys.argv[2])
state, _ = read_checkpoint(run/'checkpoints'/'latest.pt', log=print)
model = DTGModel.from_checkpoint(config_from_dict(state['config']).model, state['model'])
g = model.gaussians
scene = Scene(load_dataset(data))
tr = P.tracked_paths(scene, make_config('dtg').paths)
means = g['means'].detach()
on = P.on_still_blobs(scene, tr.still, means)
ip = g['in_place'].detach() > 0 if 'in_place' in g else torch.zeros(len(means), dtype=torch.bool)
op = torch.sigmoid(g['opacity_thermal'].detach())
print('N', len(means), 'in_place', int(ip.sum()), 'on still blobs now', int(on.sum()), 'both', int((ip & on).sum()))
print('thermal opacity mean: in_place %.3f, on-blob-not-held %.3f' % (op[ip].mean(), op[on & ~ip].mean()))
# how far do F_th's residuals move on-blob Gaussians over time
with torch.no_grad():
    ts = torch.linspace(0.02, 0.98, 13).tolist()
    idx = torch.arange(len(means))
    pos = torch.stack([model.means_at('thermal', t, 1.0, idx) for t in ts])
    disp = (pos - means).norm(dim=2).max(0).values
print('max displacement (m) median: held %.4f, on-blob not held %.4f, elsewhere %.4f' % (disp[ip].median(), disp[on & ~ip].median(), disp[~on].median()))
with torch.no_grad():
    outs = [model.stage_residuals('thermal', t, 1.0) for t in ts]
    f = torch.stack([o['features_thermal'].reshape(len(means), -1)[:, 0] for o in outs])   # (T, N)
    o_ = torch.stack([o['opacity_thermal'][:, 0] for o in outs])
    for name, sel in (('held', ip), ('on-blob not held', on & ~ip), ('elsewhere', ~on)):
        if sel.any():
            print('%s: temp residual time-std %.3f, first->last mean %.3f -> %.3f; opacity-logit time-std %.3f' % (
                name, f[:, sel].std(0).mean(), f[0, sel].mean(), f[-1, sel].mean(), o_[:, sel].std(0).mean()))
