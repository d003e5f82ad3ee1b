"""Per-time error (m) of each moving path the path fit finds (PathConfig overrides as JSON), against
the simulator's nearest object, every second thermal instant, and which instants the track saw.

    python bench/results/rest-windows/path_over_time.py JSON DATA...
"""
import json, sys
from pathlib import Path
import numpy as np, torch
ROOT = Path(__file__).resolve().parents[3]; sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle
from recon.data import load_dataset
from recon.scene import Scene
from recon.train import paths as P
torch.set_grad_enabled(False)
over = json.loads(sys.argv[1])
for name in sys.argv[2:]:
    d = Path(name); meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed']); scene = Scene(load_dataset(d))
    times = np.array([t for t in scene.times if scene.views_at('thermal', t)])
    truth = np.stack([[o.centre(k, t) for t in times] for k in range(len(o.objects))])
    found = P.tracked_paths(scene, P.PathConfig(**over)).moving
    print(d.name, [ob.name for ob in o.objects])
    for p in found:
        pos = p.at(torch.as_tensor(times)).numpy()
        dist = np.linalg.norm(pos[None] - truth, axis=2); k = int(np.argmin(np.median(dist, 1)))
        seen = sorted(p.seen)
        print(f"  path ~ {o.objects[k].name}: frames {p.frames} reproj {p.reprojection:.2f}px seen t {seen[0]:.2f}-{seen[-1]:.2f}")
        print("   t   " + " ".join(f"{t:5.2f}" for t in times[::2]))
        print("   err " + " ".join(f"{e:5.2f}" for e in dist[k][::2]))
        print("   seen" + " ".join("    x" if any(abs(t - s) < 1e-6 for s in seen) else "    ." for t in times[::2]))
