import sys, torch, json
from pathlib import Path
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT))
from recon.config import config_from_dict
from recon.dtg.model import DTGModel
from recon.train.checkpoint import read_checkpoint
for run in sys.argv[1:]:
    state, _ = read_checkpoint(Path(run) / 'checkpoints' / 'latest.pt', lambda m: None)
    cfg = config_from_dict(state['config'])
    m = DTGModel.from_checkpoint(cfg.model, state['model'])
    with torch.no_grad():
        outs = [m.stage_residuals('thermal', t, 1.0) for t in torch.linspace(0.02, 0.98, 25).tolist()]
    print(run[-60:], ' '.join('%s %.4f' % (k[:8], float(torch.stack([o[k] for o in outs]).std(0).mean())) for k in outs[0]))
