"""Does the smoothest path through rays from a handheld rig find a moving object's depth? Rays from
the training rig's camera centre through each family object's true centre (optionally with
direction noise), 40 steps; p_t free in 3D, minimising squared distance to the rays plus lam x
squared acceleration. Development seeds 0-3 of four family cases.

    python bench/results/triangulate/exact_rays.py > bench/results/triangulate/exact_rays.txt
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / "bench"))
from oracle import Oracle

def solve(C, D, lam, order=2):
    """p_t free (T,3): sum ||(I-dd^T)(p_t - c_t)||^2 + lam sum ||diff^order p||^2"""
    T = len(C); n = 3 * T
    H = np.zeros((n, n)); g = np.zeros(n)
    for t in range(T):
        P = np.eye(3) - np.outer(D[t], D[t])
        H[3*t:3*t+3, 3*t:3*t+3] += P; g[3*t:3*t+3] += P @ C[t]
    coef = (1, -2, 1) if order == 2 else (-1, 1)
    for t in range(T - len(coef) + 1):
        a = np.zeros(T); a[t:t+len(coef)] = coef
        H += lam * np.kron(np.outer(a, a), np.eye(3))
    p = np.linalg.solve(H + 1e-9 * np.eye(n), g)
    return p.reshape(T, 3)

res = {}
for scene in ['family-inside', 'family-outside', 'family-fast', 'family-dark']:
  for seed in [0, 1, 2, 3]:
    o = Oracle(scene, seed); fs = o.scene
    times = np.linspace(0, 1, 40)
    cams = np.array([fs.paths[0].c2w(t * fs.duration_s)[:3, 3] for t in times])
    for k, obj in enumerate(o.objects):
        P = np.array([o.pose(k, t).position for t in times])
        D = P - cams; depth = np.linalg.norm(D, axis=1); D = D / depth[:, None]
        for noise in [0.0, 0.006, 0.012]:
            rng = np.random.default_rng(seed * 10 + k)
            Dn = D + noise * rng.standard_normal(D.shape); Dn /= np.linalg.norm(Dn, axis=1)[:, None]
            for lam in [1, 10, 100, 1000]:
                p = solve(cams, Dn, lam)
                s = np.einsum('ti,ti->t', p - cams, Dn)
                err = np.abs(s - depth)
                res.setdefault((noise, lam), []).append((np.median(err), err.max()))
for key, v in sorted(res.items()):
    v = np.array(v)
    print(key, 'median of median err %.3f, median max %.3f, worst max %.3f' % (np.median(v[:, 0]), np.median(v[:, 1]), v[:, 1].max()))
