"""Where do given Gaussians (the veils bench/veils.py named) draw in the training views: over other
surfaces, or over the learned background? For every other thermal training view, each pixel's
coverage by those Gaussians alone, times what the rest of the model leaves uncovered there, summed
and divided by their coverage: near 1, they fill in for a background (sky) a constant colour cannot
draw; near 0, they tint surfaces the training views also see behind them.

    python bench/results/veils/veil_cover.py RUN 1375,899 > bench/results/veils/veil_cover.txt"""
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'bench'))
from recon.render import draw, inference_masks, render  # noqa: E402
from train_step import resume_held  # noqa: E402

run, ids = Path(sys.argv[1]), [int(x) for x in sys.argv[2].split(',')]
trainer, _ = resume_held(run)
model, scene = trainer.model, trainer.scene
mask = inference_masks(model)['thermal']
over_background = covered = 0.0
with torch.no_grad():
    for view in scene.train['thermal'][::2]:
        _, _, g = render(model, 'thermal', view.time, view.camera, mask=mask)
        g = {k: v for k, v in g.items() if isinstance(v, torch.Tensor)}
        rest, alone = g['opacities'].clone(), torch.zeros_like(g['opacities'])
        rest[ids], alone[ids] = 0, g['opacities'][ids]
        behind = draw(model, 'thermal', {**g, 'opacities': rest}, view.camera)[1].alpha
        veil = draw(model, 'thermal', {**g, 'opacities': alone}, view.camera)[1].alpha
        covered += float(veil.sum())
        over_background += float((veil * (1 - behind)).sum())
print(f'{run}: Gaussians {ids}, share of their coverage in the training views that lies over the learned '
      f'background: {over_background / covered:.2f}')
