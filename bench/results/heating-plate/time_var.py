"""python time_var.py RUN... : std over 25 instants of F_th's residuals, mean over Gaussians, per output."""
import sys, torch
from pathlib import Path
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT))
from recon.render import load_run
for run in sys.argv[1:]:
    m = load_run(Path(run))[0]
    with torch.no_grad():
        outs = [m.stage_residuals('thermal', t, 1.0) for t in torch.linspace(0.02, 0.98, 25).tolist()]
    print(run[-60:], ' '.join('%s %.4f' % (k[:8], float(torch.stack([o[k] for o in outs]).std(0).mean())) for k in outs[0]))
