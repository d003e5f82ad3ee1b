"""Why are the bodies' members off the objects? Per moving object and per instant the simulator
recorded points at: initial points inside it (1.2 cm) / of those, flagged as seeing the scene change
(changing_points) / of those, matched to an instant by observed_time (the candidates for a body).
Then, per way of flagging (changing_points as dtg's defaults, transient_points as body discovery),
the candidates observed_time matches to its instant t_seen: how many lie on a moving object at
t_seen (1.2 cm), and on one at any of the simulator's 8 recorded instants. Development datasets
only (the simulator's objects are read):

    python bench/results/flow-tracks-prior/probe_bodies.py DATA... > probe_bodies.txt

At a commit that has ModelConfig.body_hot_kelvin (members on hot pixels only: tried, removed after)
it also prints, per body, members inside a moving object at t_c (1.2 cm) / members, without and
with the switch at 10 K (-> probe_hot.txt).

With --composition it prints only each body of dtg's starting model as members:(inside a moving
object)m/(inside a static one)s at t_c, and a summary (-> probe_composition.txt; no training, so
it may read the never-tuned seeds' datasets: nothing is chosen from it)."""
import sys, json
from pathlib import Path
import numpy as np, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle, SAMPLES
from recon.config import make_config
from recon.data import load_dataset
from recon.scene import Scene
from recon.train.initial import initial_model, initial_points
from recon.dtg.points import changing_points, observed_time, transient_points
torch.set_grad_enabled(False)


def composition(names):
    counts = {'bodies': 0, 'mostly on a moving object': 0, 'on no object': 0, 'mostly on a static object': 0}
    for name in names:
        d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
        o = Oracle(meta['variant'], meta['seed'])
        cfg = make_config('dtg')
        model, _ = initial_model(cfg, Scene(load_dataset(d)), torch.Generator().manual_seed(cfg.seed), lambda *a: None)
        b = model.gaussians['motion_basis'].long().numpy(); x = model.gaussians['means'].numpy()
        tc = cfg.curriculum.center
        out = []
        for k in range(1, b.max() + 1):
            xs = x[b == k]; mov = np.zeros(len(xs), bool); sta = np.zeros(len(xs), bool)
            for ob in o.scene.objects:
                inst = ob.instance(tc * o.scene.duration_s, o.scene.duration_s)
                inside = ob.shape.contains((xs - inst.position) @ inst.rotation, 0.012)
                (mov if ob.moving else sta)[:] |= inside
            out.append(f'{len(xs)}:{mov.sum()}m/{sta.sum()}s')
            counts['bodies'] += 1
            counts['mostly on a moving object'] += int(mov.sum() >= len(xs) / 2)
            counts['on no object'] += int(not (mov | sta).any())
            counts['mostly on a static object'] += int(sta.sum() >= len(xs) / 2)
        print(f'{d.name:22s} t_c {tc:.2f} bodies', ' '.join(out), flush=True)
    print('SUMMARY', counts)


if sys.argv[1] == '--composition':
    composition(sys.argv[2:])
    sys.exit()
for name in sys.argv[1:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    cfg = make_config('dtg'); m = cfg.model
    scene = Scene(load_dataset(d))
    pts, rgb = initial_points(cfg, scene, torch.Generator().manual_seed(cfg.seed), log=lambda *a: None)
    flagged = changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction)
    t_seen, matched = observed_time(scene, pts[flagged], rgb[flagged])
    p = pts.numpy()
    print(d.name, 'points', len(p), 'flagged', int(flagged.sum()), 'matched', int(matched.sum()), f't_seen {t_seen:.3f}')
    for k in range(len(o.objects)):
        row = []
        for i, t in enumerate(np.linspace(0, 1, SAMPLES)):
            on = o.contains(k, t, p, 0.012)
            fl = on & flagged.numpy()
            mt = np.zeros(len(p), bool); mt[np.nonzero(flagged.numpy())[0][matched.numpy()]] = True
            row.append(f't{t:.2f}:{on.sum()}/{fl.sum()}/{(on & mt).sum()}')
        print('   obj', k, type(o.objects[k].shape).__name__, ' '.join(row))
    for label, cand in (('changing', changing_points(scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction)),
                        ('transient', transient_points(scene, pts, rgb))):
        t_seen, matched = observed_time(scene, pts[cand], rgb[cand])
        idx = np.nonzero(cand.numpy())[0][matched.numpy()]
        on = np.zeros(len(idx), bool)
        for k in range(len(o.objects)):
            on |= o.contains(k, t_seen, p[idx], 0.012)
        anyt = np.zeros(len(idx), bool)
        for k in range(len(o.objects)):
            for t in np.linspace(0, 1, 8):
                anyt |= o.contains(k, t, p[idx], 0.012)
        print(f'{d.name:22s} {label:9s} t_seen {t_seen:.3f} candidates {len(idx):4d} on an object at t_seen {on.sum():3d} on one at some instant {anyt.sum():3d}')
    if not hasattr(make_config('dtg').model, 'body_hot_kelvin'):
        continue
    out = []
    for hotk in (0.0, 10.0):
        cfg = make_config('dtg'); cfg.model.body_hot_kelvin = hotk
        logs = []
        model, _ = initial_model(cfg, scene, torch.Generator().manual_seed(cfg.seed), logs.append)
        b = model.gaussians['motion_basis'].long().numpy(); x = model.gaussians['means'].numpy()
        tc = cfg.curriculum.center
        res = []
        for k in range(1, b.max() + 1):
            on = np.zeros(int((b == k).sum()), bool)
            for j in range(len(o.objects)):
                on |= o.contains(j, tc, x[b == k], 0.012)
            res.append(f'{on.sum()}/{len(on)}')
        out.append(f'hot {hotk:g}: ' + ' '.join(res))
    print(d.name, f't_c {tc:.3f}', ' | '.join(out), [line for line in logs if 'hot bodies' in line])
