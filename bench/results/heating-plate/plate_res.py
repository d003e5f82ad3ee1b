"""python plate_res.py RUN : F_th's residuals on the default scene's hot plate over time (thermal-drawn Gaussians)."""
import sys, torch
from pathlib import Path
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT))
from recon.render import load_run
m = load_run(Path(sys.argv[1]))[0]; g = m.gaussians
plate = (g['means'][:, :2] - torch.tensor([-0.08, 0.06])).norm(dim=1) < 0.06
plate &= g['means'][:, 2].abs() < 0.03
roles = g['route_logits'].argmax(1)
sel = plate & (roles != 1)        # drawn in thermal
print('plate gaussians drawn in thermal', int(sel.sum()), 'bodies', torch.bincount(g['motion_basis'][sel].long()).tolist())
with torch.no_grad():
    gate = m.geometry_gate('thermal')
    for t in (0.05, 0.2, 0.4, 0.6, 0.8, 0.95):
        r = m.stage_residuals('thermal', t, 1.0)
        out = {}
        if 'means' in r:
            dmu = (r['means'] * (gate[:, None] if gate is not None else 1))[sel]
            dls = (r['log_scales'] * (gate[:, None] if gate is not None else 1))[sel]
            out['|dmu| cm'] = round(float(dmu.norm(dim=1).mean()) * 100, 2)
            out['dz cm'] = round(float(dmu[:, 2].mean()) * 100, 2)
            out['dlogscale'] = round(float(dls.mean()), 3)
        out['dop'] = round(float(r['opacity_thermal'][sel].mean()), 3)
        f = g['features_thermal'][sel].view(int(sel.sum()), -1)[:, 0] + r['features_thermal'][sel].view(int(sel.sum()), -1)[:, 0]
        out['feat'] = round(float(f.mean()), 3)
        out['opac'] = round(float(torch.sigmoid(g['opacity_thermal'][sel] + r['opacity_thermal'][sel, 0]).mean()), 3)
        print(t, out)
with torch.no_grad():
    outs = [m.stage_residuals('thermal', t, 1.0) for t in torch.linspace(0.02, 0.98, 25).tolist()]
    for k in outs[0]:
        s = torch.stack([o[k] for o in outs])      # (T, N, d)
        print(k, 'time std (mean over G) %.4f' % float(s.std(0).mean()), 'plate %.4f' % float(s[:, sel].std(0).mean()))
    te = torch.stack([m.time_embedding(t, 1.0) for t in torch.linspace(0.02, 0.98, 25).tolist()])
    print('time embedding std', float(te.std(0).mean()), 'W_t norm', float(m.deformers['thermal'].time_in.weight.norm()))
