"""python bench/results/in-place/movers.py RUN DATA: how many non-body Gaussians F_th moves (max displacement over 13 instants), and how many of them lie on still blobs (ov-ip4-s0 in default-probes.txt)."""
import sys, torch, numpy as np
from pathlib import Path
from recon.train.checkpoint import read_checkpoint
from recon.config import config_from_dict, make_config
from recon.dtg.model import DTGModel
from recon.scene import Scene
from recon.data import load_dataset
from recon.train import paths as P
run, data = Path(sys.argv[1]), Path(sys.argv[2])
state, _ = read_checkpoint(run/'checkpoints'/'latest.pt', log=lambda *_: None)
model = DTGModel.from_checkpoint(config_from_dict(state['config']).model, state['model'])
g = model.gaussians; means = g['means'].detach()
scene = Scene(load_dataset(data)); tr = P.tracked_paths(scene, make_config('dtg').paths)
ts = torch.linspace(0.02, 0.98, 13).tolist(); idx = torch.arange(len(means))
with torch.no_grad():
    pos = torch.stack([model.means_at('thermal', t, 1.0, idx) for t in ts])
disp = (pos - means).norm(dim=2).max(0).values
body = g['motion_basis'].detach() > 0
op = torch.sigmoid(g['opacity_thermal'].detach())
for share in (0.5, 0.2, 0.05):
    on = P.on_still_blobs(scene, tr.still, means, share)
    for thr in (0.005, 0.02):
        mv = (disp > thr) & ~body
        print('share %.2f: non-body movers >%.0f mm: %d (opacity-weighted %.0f), of them on still blobs %d' % (share, thr*1000, int(mv.sum()), float(op[mv].sum()), int((mv & on).sum())))
# where do movers end up at the last time: on the blob in the last frame?
last = max(max(p.seen) for p in tr.still)
pend = pos[-1]
onend = P.on_still_blobs(scene, tr.still, pend, 0.5)
mv = (disp > 0.005) & ~body
print('movers whose last-time place is on still blobs: %d of %d' % (int((mv & onend).sum()), int(mv.sum())))
