"""What a trained run's long Gaussians are to its training views, and what bounding them would do
to its held-out views, graded on the model as trained (no retraining).

    python bench/long_gaussians.py RUN [RUN ...] --out bench/results/long-gaussians/NAME.json

For every Gaussian of each `recon run` output RUN, over the training views (both modalities, the
geometry at each view's time, routing by argmax) that have its centre in frustum:
- `across`: its largest standard deviation across the viewing ray (its 3D covariance projected
  on the plane orthogonal to the ray from the camera), the largest over those views. A needle
  that lies along every training ray it is seen by has a small `across`; a wall seen face-on has
  a large one.
- `weight`: the sum over a view's pixels of its blending weight (pixels' worth of colour it
  gives), the largest over all training views. A Gaussian hidden or transparent in every
  training view has a weight near 0.

Then the held-out views (every other test view per modality) are graded with the Gaussians'
scales clamped, or some Gaussians dropped, as each variant says:
- `none`: as trained;
- `E c`: largest scale held at c x the scene extent E (what `--max-scale c` holds while training);
- `across c`: held at c x `across`;
- `camera k`: held at k x the distance to the nearest training camera centre (an angular size);
- `weight t`: Gaussians whose `weight` is under t pixels dropped;
- `beside m`: each held-out view leaves out the Gaussians whose centre projects more than m view
  widths (heights) beyond its edges (`ModelConfig.cull_off_view` = m). Every other variant,
  `none` included, draws without that rule, whatever the run trained with.

Writes, per run: Gaussian counts (longer than 1 m; never in a training view's frustum; the ratio
of length to `across` of those longer than 1 m; how many are under each weight), and held-out RGB PSNR (dB) and thermal MAE (K) per variant.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import recon  # noqa: E402,F401  (before torch: its OpenMP wait policy, as `recon run` has it)
import torch  # noqa: E402

from recon.data import load_dataset  # noqa: E402
from recon.dtg.gaussians import SH_C0, quat_to_rotmat  # noqa: E402
from recon.eval.metrics import psnr, thermal_mae_k  # noqa: E402
from recon.render import draw, inference_masks, load_run  # noqa: E402
from recon.scene import Scene  # noqa: E402
from recon.splat import rasterization  # noqa: E402

VARIANTS = ["none", "E 0.3", "E 1", "across 3", "across 10", "camera 0.3", "camera 1", "weight 0.05", "weight 0.25",
            "beside 0.5", "beside 1", "beside 2"]


def across_ray(g: dict, camera) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,) largest std across the ray from camera to each mean; (N,) whether the mean is in
    frustum (in front, within the view widened by a tenth each side)."""
    means, scales = g["means"], g["log_scales"].exp()
    rot = quat_to_rotmat(g["quats"])
    cov = rot @ torch.diag_embed(scales * scales) @ rot.transpose(1, 2)
    view = camera.viewmat
    cam = means @ view[:3, :3].T + view[:3, 3]
    z = cam[:, 2].clamp_min(1e-6)
    u, v = cam[:, 0] / z * camera.fx + camera.cx, cam[:, 1] / z * camera.fy + camera.cy
    seen = ((cam[:, 2] > 0.05) & (u > -0.1 * camera.width) & (u < 1.1 * camera.width)
            & (v > -0.1 * camera.height) & (v < 1.1 * camera.height))
    ray = torch.nn.functional.normalize(means - camera.center, dim=1)
    plane = torch.eye(3) - ray[:, :, None] * ray[:, None, :]
    return torch.linalg.eigvalsh(plane @ cov @ plane)[:, -1].clamp_min(0).sqrt(), seen


def pixel_weights(g: dict, camera) -> torch.Tensor:
    """(N,) each Gaussian's blending weight summed over the view's pixels: the gradient of the
    summed image with respect to a constant colour."""
    colour = torch.zeros(g["means"].shape[0], 1, 1, requires_grad=True)
    out = rasterization(g["means"], g["quats"], g["log_scales"], g["opacities"], colour, camera.viewmat,
                        camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, sh_degree=0,
                        window=camera.window)
    out.image[..., 0].sum().backward()
    return colour.grad[:, 0, 0] / SH_C0


def what_training_sees(model, scene: Scene, masks) -> dict[str, torch.Tensor]:
    n = model.num_gaussians
    across, weight = torch.zeros(n), torch.zeros(n)
    for m in scene.modalities():
        for view in scene.train[m]:
            with torch.no_grad():
                g = {k: v for k, v in model.render_inputs(m, view.time, 1.0, mask=masks[m]).items() if torch.is_tensor(v)}
                extent, inside = across_ray(g, view.camera)
                across = torch.where(inside, torch.maximum(across, extent), across)
            weight = torch.maximum(weight, pixel_weights(g, view.camera))
    return {"across": across, "weight": weight}


def changed(g: dict, variant: str, bounds: dict[str, torch.Tensor]) -> dict:
    """Render inputs g with a variant applied (bounds: per-Gaussian tensors by kind)."""
    if variant == "none" or variant.startswith("beside"):
        return g
    kind, value = variant.split()
    value = float(value)
    if kind == "weight":
        keep = bounds["weight"] >= value
        return {k: (v[keep] if torch.is_tensor(v) and v.shape[:1] == keep.shape else v) for k, v in g.items()}
    limit = value * bounds[kind]
    return {**g, "log_scales": torch.minimum(g["log_scales"], limit.clamp_min(1e-9).log()[:, None])}


def grade(model, scene: Scene, masks, variant: str, bounds: dict[str, torch.Tensor]) -> dict[str, float]:
    """Held-out RGB PSNR (mean over views, dB) and thermal MAE (mean over views, K)."""
    rgb, mae = [], []
    kind, _, value = variant.partition(" ")
    own = model.cfg.cull_off_view          # every other variant draws without the rule
    model.cfg.cull_off_view = float(value) if kind == "beside" else None
    try:
        with torch.no_grad():
            for m in scene.modalities():
                for view in scene.test[m][::2]:
                    g = changed(model.render_inputs(m, view.time, 1.0, mask=masks[m]), variant, bounds)
                    image, _ = draw(model, m, g, view.camera)
                    target, valid = scene.target(view)
                    if m == "rgb":
                        rgb.append(float(psnr(image.clamp(0, 1), target)))
                    else:
                        mae.append(float(thermal_mae_k(scene.kelvin(image[..., 0]), scene.kelvin(target), valid)))
    finally:
        model.cfg.cull_off_view = own
    out = {}
    if rgb:
        out["rgb_psnr"] = round(sum(rgb) / len(rgb), 2)
    if mae:
        out["thermal_mae_k"] = round(sum(mae) / len(mae), 3)
    return out


def study(run: Path) -> dict:
    model, facts = load_run(run)
    scene = Scene(load_dataset(Path(facts["dataset"])))
    masks = inference_masks(model) or {m: None for m in scene.modalities()}
    seen = what_training_sees(model, scene, masks)
    extent = scene.extent()
    centres = torch.stack([v.camera.center for vs in scene.train.values() for v in vs])
    means = model.gaussians["means"].detach()
    bounds = {"E": torch.full((len(means),), extent), "across": torch.where(seen["across"] > 0, seen["across"], 1e9),
              "camera": torch.cdist(means, centres).min(1).values, "weight": seen["weight"]}
    length = model.gaussians["log_scales"].detach().max(1).values.exp()
    long = length > 1.0
    never = seen["across"] == 0                   # no training view has its centre in frustum
    ratio = (length[long & ~never] / seen["across"][long & ~never]).sort().values
    return {"run": str(run), "gaussians": len(length), "extent_m": round(extent, 3),
            "never_in_frustum": int(never.sum()), "longer_than_1m": int(long.sum()),
            "long_never_in_frustum": int((long & never).sum()), "longest_m": round(float(length.max()), 2),
            "long_length_over_across": {"median": round(float(ratio.median()), 2) if len(ratio) else None,
                                        "largest": [round(float(r), 1) for r in ratio[-5:]]},
            "long_weight_px": {"min": round(float(seen["weight"][long].min()), 2) if long.any() else None,
                               "median": round(float(seen["weight"][long].median()), 1) if long.any() else None},
            "under_weight": {str(t): int((seen["weight"] < t).sum()) for t in (0.05, 0.25, 1.0)},
            "graded": {v: grade(model, scene, masks, v, bounds) for v in VARIANTS}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    results = []
    for run in args.runs:
        results.append(study(run))
        r = results[-1]
        print(f"{run}: {r['longer_than_1m']} longer than 1 m, length / across median "
              f"{r['long_length_over_across']['median']}; " +
              ", ".join(f"{v} {g.get('rgb_psnr', '-')} dB {g.get('thermal_mae_k', '-')} K" for v, g in r["graded"].items()),
              flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
