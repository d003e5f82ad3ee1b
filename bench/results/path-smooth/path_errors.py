"""Where a path's error comes from, per moving path on development datasets (the simulator's objects
are read):

- how far its blobs' centroids are from the projected middle of the object it follows (px), how
  far the fitted path projects from its blobs and from that middle (px), and its 3D error (m) over
  its own frames and over the whole sequence. Blobs on the object with the path still off in 3D:
  the error is along the rays (depth). Blobs off the object: merged or biased blobs. Which objects
  the track followed: the majority mask label under each blob, counted;
- beyond the frames it was fitted to, is its straight continuation (what the fit's smoothness gives)
  nearer the object than holding it at its last measured place? The 3D error at the instants
  outside its span, both ways, and over all paths at the end.

    python bench/results/path-smooth/path_errors.py DATA... > bench/results/path-smooth/path_errors.txt

PATHS='{...}' (JSON) overrides PathConfig fields. SIGMA=1 adds, per path, the standard deviation along
the rays that the fit's own Jacobian predicts (1 px of pixel noise, the priors as pseudo-observations:
(J^T J)^-1 at the solution), median over its frames, and at the end its rank correlation with the 3D
error: does the fit know when its depth is loose?"""
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import least_squares
from scipy.stats import spearmanr

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / 'bench'))
from oracle import Oracle  # noqa: E402
from recon.data import load_dataset  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.train import paths as P  # noqa: E402

torch.set_grad_enabled(False)
settings = P.PathConfig(**json.loads(os.environ.get('PATHS', '{}')))
SIGMA = os.environ.get('SIGMA') == '1'


def ray_sigma(knots: np.ndarray, times: np.ndarray, projections: np.ndarray, pixels: np.ndarray, up: np.ndarray,
              centres: np.ndarray) -> np.ndarray:
    """(T,) predicted std (m) of the path knots (K, 3) along the ray from each camera centre (T, 3)
    at its time (T,), for the fit to pixels (T, 2) through projections (T, 3, 4)."""
    k = len(knots)
    basis = P.hat_basis(times, k)
    prior = P.path_priors(k, settings.smoothness, settings.level, up)

    def residuals(x):
        return np.concatenate([(P.to_pixels(projections, basis @ x.reshape(k, 3)) - pixels).ravel(), prior @ x])
    jac = least_squares(residuals, knots.ravel(), method='lm', max_nfev=1).jac
    cov = np.linalg.inv(jac.T @ jac)
    out = []
    for b, c in zip(basis, centres):
        rows = np.kron(b[None], np.eye(3))                                                   # (3, 3K)
        d = rows @ knots.ravel() - c
        d /= np.linalg.norm(d)
        out.append(float(np.sqrt(d @ rows @ cov @ rows.T @ d)))
    return np.array(out)


moved, held, sigmas = [], [], []
for name in sys.argv[1:]:
    d = Path(name)
    meta = json.loads((d / 'sim_meta.json').read_text())['config']
    o = Oracle(meta['variant'], meta['seed'])
    ds = load_dataset(d)
    scene = Scene(ds)
    views = {t: scene.views_at('thermal', t)[0] for t in scene.times if scene.views_at('thermal', t)}
    every = np.array(sorted(views))
    names = {int(i): v['name'] for i, v in ds.mask_labels.items()}
    truth = np.stack([[o.centre(k, t) for t in every] for k in range(len(o.objects))])         # (O, T, 3)
    for p in P.tracked_paths(scene, settings).moving:
        est = p.at(torch.as_tensor(every)).numpy()
        k = int(np.argmin(np.median(np.linalg.norm(est[None] - truth, axis=2), 1)))
        error = np.linalg.norm(est - truth[k], axis=1)                                         # (T,)
        seen = np.isin(every, list(p.seen))
        ts = every[seen]
        proj = np.stack([P.projection(views[t].camera) for t in ts])
        middle, blob, fit = P.to_pixels(proj, truth[k][seen]), np.stack([p.seen[t].centroid for t in ts]), P.to_pixels(proj, est[seen])
        bias = np.linalg.norm(blob - middle, axis=1)
        if SIGMA:
            centres = np.stack([np.linalg.inv(views[t].camera.viewmat.double().numpy())[:3, 3] for t in ts])
            sigma = ray_sigma(p.knots.double().numpy(), ts, proj, blob, scene.up().double().numpy(), centres)
            sigmas.append((float(np.median(sigma)), float(np.median(error[seen]))))
        labels = [int(np.bincount(ds.mask(views[t].frame).ravel()[p.seen[t].pixels]).argmax()) for t in ts]
        followed = ', '.join(f'{names.get(lab, "background")} {labels.count(lab)}' for lab in dict.fromkeys(labels))
        print(f'{d.name} {o.objects[k].name}: {len(ts)} frames ({followed}); blob to middle {np.median(bias):.2f} px '
              f'(max {bias.max():.2f}); fit to blob {np.median(np.linalg.norm(fit - blob, axis=1)):.2f} px; fit to middle '
              f'{np.median(np.linalg.norm(fit - middle, axis=1)):.2f} px; 3D {np.median(error[seen]):.3f} m '
              f'on its frames, {np.median(error):.3f} m over the sequence'
              + (f'; predicted sigma along the rays {np.median(sigma):.3f} m' if SIGMA else ''))
        lo, hi = min(p.seen), max(p.seen)
        out = (every < lo) | (every > hi)
        if np.median(error) <= 0.3 and out.any():
            at_end = p.at(torch.as_tensor(np.clip(every, lo, hi))).numpy()
            e1, e2 = error[out], np.linalg.norm(at_end - truth[k], axis=1)[out]
            moved += list(e1)
            held += list(e2)
            print(f'    span {lo:.2f}-{hi:.2f}, {out.sum()} instants outside: continued median {np.median(e1):.3f} '
                  f'max {e1.max():.3f} m | held {np.median(e2):.3f} max {e2.max():.3f} m')
        sys.stdout.flush()
print(f'all instants outside a span: continued median {np.median(moved):.3f} p90 {np.percentile(moved, 90):.3f} m | '
      f'held median {np.median(held):.3f} p90 {np.percentile(held, 90):.3f} m')
if SIGMA:
    print(f'{len(sigmas)} paths: rank correlation (Spearman) of predicted sigma with 3D error on the frames '
          f'{spearmanr(*zip(*sigmas))[0]:.2f}')
