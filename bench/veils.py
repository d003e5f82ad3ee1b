"""Who draws an object in the held-out views. For a trained run on a simulated family dataset, each
object's thermal pixels in every k-th test view are split by where the Gaussians that draw them are
at that instant (after deformation and the bodies' motion): **on** the object (centre within 1.5x
its bounding radius) or **off** it (a veil or floater in front, a surface behind seen through a
gap), and the learned background. For each group: its share of the blend weight on the object's
pixels and its weight-averaged temperature, beside the ground truth's median. Then the same pixels
are rendered again with that view's off-object contributors left out: the object's error if nothing
but itself were drawn there (an upper bound on what removing veils could give; the other pixels are
not graded). The largest off-object contributors (summed share) are listed with their scale,
thermal opacity and role.

    python bench/veils.py RUN [RUN...] --every 4 --out bench/results/veils/NAME.json

RUN: a `recon run` folder on a dataset written by `recon simulate --variant family-*` (its
sim_meta.json names the scene and seed; the objects are rebuilt from them)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(ROOT / "bench"))
from recon.dtg import routing  # noqa: E402
from recon.dtg.gaussians import SH_C0, sh_dc_to_value  # noqa: E402
from recon.render import draw, inference_masks, render  # noqa: E402
from recon.scene import Scene  # noqa: E402
from rig.sim.family import FamilyScene  # noqa: E402
from train_step import resume_held  # noqa: E402

ROLES = ("shared", "rgb", "thermal")


def object_spheres(data: Path) -> tuple[FamilyScene, dict]:
    """The family scene a dataset was simulated from, and {object name: object}."""
    meta = json.loads((data / "sim_meta.json").read_text())["config"]
    fam = FamilyScene.build(meta["variant"].removeprefix("family-"), meta["seed"])
    return fam, {o.name: o for o in fam.objects}


def weights_on(model, view, pixels: torch.Tensor, mask: torch.Tensor):
    """Per-Gaussian blend weight summed over pixels (H, W) bool of a thermal render of view, the
    posed Gaussians (render inputs), their colours (N,), the render's alpha (H, W) and image
    (H, W, 1). The weight is read as the gradient of the pixels' sum with respect to each Gaussian's
    colour (degree-0 thermal colour: linear; a Gaussian whose colour is clamped at 0, 3DGS's
    max(SH + 0.5, 0), reads no weight)."""
    with torch.enable_grad():
        image, out, g = render(model, "thermal", view.time, view.camera, mask=mask)
        feats = g["features"]
        if feats.is_leaf:
            feats.grad = None
        else:
            feats.retain_grad()
        (image[..., 0] * pixels).sum().backward()
        w = feats.grad[:, 0, 0].detach() / SH_C0
    colour = sh_dc_to_value(feats[:, 0, 0]).clamp_min(0).detach()
    return w, {k: v.detach() for k, v in g.items() if isinstance(v, torch.Tensor)}, colour, out.alpha.detach(), image.detach()


def kelvin(scene: Scene, value: float) -> float:
    return float(scene.kelvin(torch.tensor([value]))[0])


def grade_run(run: Path, every: int) -> dict:
    trainer, _ = resume_held(run)
    model, scene = trainer.model, trainer.scene
    ds = scene.dataset
    fam, objects = object_spheres(ds.root)
    labels = {int(i): v["name"] for i, v in ds.mask_labels.items()}
    roles = routing.hard_roles(model.gaussians["route_logits"].detach()) if "route_logits" in model.gaussians else None
    mask = inference_masks(model)
    mask = None if mask is None else mask["thermal"]
    scales = model.gaussians["log_scales"].detach().exp().amax(1)
    opac = torch.sigmoid(model.gaussians["opacity_thermal"].detach())
    acc: dict[str, dict] = {}
    for view in scene.test["thermal"][::every]:
        gt, valid = scene.target(view)
        gt_k = scene.kelvin(gt).reshape(view.camera.height, view.camera.width)
        ok = torch.ones_like(gt_k, dtype=torch.bool) if valid is None else valid.bool().reshape(gt_k.shape)
        frame_mask = torch.from_numpy(ds.mask(view.frame).astype(np.int64))
        for label in frame_mask.unique().tolist():
            name = labels.get(int(label))
            if name not in objects:
                continue
            pix = (frame_mask == label) & ok
            if pix.sum() < 4:
                continue
            w, g, colour, alpha, image = weights_on(model, view, pix.float(), mask)
            centre, radius = objects[name].instance(view.time * fam.duration_s, fam.duration_s).bounding_sphere()
            on = (g["means"] - torch.as_tensor(centre, dtype=torch.float32)).norm(dim=1) <= 1.5 * radius
            n = float(pix.sum())
            a = acc.setdefault(name, {"moves": bool(objects[name].moving), "pixels": 0, "w_on": 0.0, "w_off": 0.0,
                                      "c_on": 0.0, "c_off": 0.0, "bg": 0.0, "gt_k": [], "err": 0.0, "err_alone": 0.0,
                                      "off": {}})
            a["pixels"] += n
            a["w_on"] += float(w[on].sum())
            a["w_off"] += float(w[~on].sum())
            a["c_on"] += float((w[on] * colour[on]).sum())
            a["c_off"] += float((w[~on] * colour[~on]).sum())
            a["bg"] += float((1 - alpha)[pix].sum())
            a["gt_k"].append(float(gt_k[pix].median()))
            with torch.no_grad():
                a["err"] += float((scene.kelvin(image[..., 0]) - gt_k)[pix].abs().sum())
                drop = (~on) & (w > 0)
                alone = {**g, "opacities": torch.where(drop, torch.zeros_like(g["opacities"]), g["opacities"])}
                image, _ = draw(model, "thermal", alone, view.camera)
                a["err_alone"] += float((scene.kelvin(image[..., 0]) - gt_k)[pix].abs().sum())
            for i in torch.nonzero(~on & (w > 1e-3 * n)).view(-1).tolist():
                a["off"][i] = a["off"].get(i, 0.0) + float(w[i])
    out = {}
    for name, a in acc.items():
        total = a["w_on"] + a["w_off"] + a["bg"]
        top = sorted(a["off"].items(), key=lambda kv: -kv[1])[:5]
        out[name] = {
            "moves": a["moves"], "pixels": int(a["pixels"]), "gt_median_k": round(float(np.median(a["gt_k"])), 1),
            "mae_k": round(a["err"] / a["pixels"], 2), "mae_k_on_object_alone": round(a["err_alone"] / a["pixels"], 2),
            "share_on": round(a["w_on"] / total, 3), "share_off": round(a["w_off"] / total, 3),
            "share_background": round(a["bg"] / total, 3),
            "temp_on_k": round(kelvin(scene, a["c_on"] / max(a["w_on"], 1e-9)), 1) if a["w_on"] > 0 else None,
            "temp_off_k": round(kelvin(scene, a["c_off"] / max(a["w_off"], 1e-9)), 1) if a["w_off"] > 0 else None,
            "top_off": [{"index": i, "share": round(s / total, 3), "largest_scale_m": round(float(scales[i]), 3),
                         "opacity_thermal": round(float(opac[i]), 2),
                         "role": None if roles is None else ROLES[int(roles[i])]} for i, s in top],
        }
    return {"run": str(run), "extent_m": round(scene.extent(), 3), "every": every, "objects": out}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--every", type=int, default=4, help="grade every k-th test view (default 4)")
    ap.add_argument("--out", type=Path, required=True, help="JSON file written")
    args = ap.parse_args()
    rows = []
    for run in args.runs:
        row = grade_run(run, args.every)
        rows.append(row)
        for name, o in row["objects"].items():
            print(f"{run.parent.name} {name:14s} gt {o['gt_median_k']:.0f} K  MAE {o['mae_k']:5.1f} K (on-object alone "
                  f"{o['mae_k_on_object_alone']:5.1f})  share on {o['share_on']:.2f} at {o['temp_on_k']} K, off "
                  f"{o['share_off']:.2f} at {o['temp_off_k']} K, background {o['share_background']:.2f}; largest off: "
                  + ", ".join(f"{t['share']:.2f} {t['role']} {t['largest_scale_m']} m op {t['opacity_thermal']}"
                              for t in o["top_off"][:3]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
