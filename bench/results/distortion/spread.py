"""Mean per-pixel distortion / extent^2 of trained runs, per modality, as the loss charges it:
every 8th training view, routing by argmax.

    python bench/results/distortion/spread.py RUN [RUN ...]
"""
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from train_step import resume_held  # noqa: E402
from recon.render import inference_masks, render  # noqa: E402

for run in sys.argv[1:]:
    tr, _ = resume_held(Path(run))
    masks = inference_masks(tr.model)
    for modality in ("rgb", "thermal"):
        vals = []
        for view in tr.scene.train[modality][::8]:
            with torch.no_grad():
                _, out, _ = render(tr.model, modality, view.time, view.camera, distortion=True,
                                   mask=None if masks is None else masks[modality])
            vals.append(float(out.distortion.mean()) / tr.extent ** 2)
        vals = torch.tensor(vals)
        print(f"{run} {modality}: extent {tr.extent:.2f}, {len(vals)} views, mean {vals.mean():.2e}, max {vals.max():.2e}")
