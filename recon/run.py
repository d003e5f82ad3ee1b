"""`recon run`: train a method on a prepared dataset, then render, grade and export.

RUN/ after a run:
  config.json              every hyper-parameter used
  scene.json               temperature scaling and a default camera for `recon render`
  checkpoints/latest.pt    resumable state (every 500 iterations and at the end, written atomically)
  history.json             held-out PSNR, losses, Gaussians per role against iteration and seconds
  events.json              why training stopped, and every divergence it recovered from (or not)
  renders/<file_path>      every test frame, same relative path and encoding as the ground truth
  eval/metrics.{json,md}   `recon eval` of those renders
  metrics.json             summary: per-modality means, Gaussians per role, model bytes, train time
  strips/                  GT | render | error pictures of test views (thermal in deg C)
  animation.gif            a test view across time, RGB beside temperature
  export/model.ply         canonical Gaussians, 3DGS layout + thermal/role/embedding properties
  export/deformation.pt    deformation networks, time embedding, backgrounds
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

from recon.config import DEFAULT_MINUTES, METHODS, config_to_dict, make_config
from recon.data import load_dataset
from recon.eval import evaluate_run, write_results
from recon.live.publish import LivePublisher, TrainingFeed
from recon.eval.evaluate import frame_metrics, moving_masks
from recon.eval.regions import RegionPool
from recon.eval.renders import encode_render, write_render_pixels
from recon.export import export_deformation, export_ply, model_bytes
from recon.prepare import REPORT_FILE, PrepareError, PrepareOptions, prepare_session
from recon.prepare.rgbt import is_rgbt_folder
from recon.render import render_frame
from recon.scene import Scene
from recon.train.guard import TrainingDiverged
from recon.train.resolution import coarse_to_fine
from recon.train.trainer import Trainer
from recon.view import LiveRenderService
from recon import viz
from server.cli_options import add_serve_arguments, serve_from_args
from rig.cli_format import positive_float, positive_int, unit_fraction


def test_render(trainer: Trainer, modality: str, view, scene: Scene | None = None) -> np.ndarray:
    """A test view of `scene` (default the training scene) rendered with the ground truth's
    encoding (uint8 RGB or uint16 counts)."""
    image = render_frame(trainer.model, modality, view.time, view.camera)
    # kelvin by the temperature range the model was trained in; encoded as the graded data is
    image = image.clamp(0, 1) if modality == "rgb" else trainer.scene.kelvin(image[..., 0])
    return encode_render(image.numpy(), modality, (scene or trainer.scene).dataset.thermal_scale_k)


def evaluate_model(trainer: Trainer, every: int = 1, scene: Scene | None = None) -> dict:
    """Test metrics straight from the model (every `every`-th test view), with the same encodings
    and metric code as `recon eval` on written renders, without the disk:
    {modality: {metric: mean over frames}, "regions": {modality: {region: pooled metrics}},
    "objects": {modality: {object name: pooled metrics}}}.
    scene: the test views to grade (default the training scene's; e.g. the same capture at a
    higher resolution than trained at)."""
    scene = scene or trainer.scene
    out, pool, ds = {}, RegionPool(), scene.dataset
    views = {m: scene.test[m][::every] for m in trainer.cfg.model.modalities}
    moving = moving_masks(ds, [v.frame for vs in views.values() for v in vs])
    for m, vs in views.items():
        rows = [frame_metrics(ds, v.frame, test_render(trainer, m, v, scene), None, pool,
                              moving[v.frame.file_path]) for v in vs]
        if rows:
            out[m] = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "regions"}
    out["regions"] = pool.result()
    out["objects"] = pool.objects()
    return out


def render_test_views(trainer: Trainer, run_dir: Path, scene: Scene | None = None) -> int:
    n = 0
    for m in trainer.cfg.model.modalities:
        for view in (scene or trainer.scene).test[m]:
            write_render_pixels(run_dir, view.frame, test_render(trainer, m, view, scene))
            n += 1
    return n


def write_strips(trainer: Trainer, run_dir: Path, count: int = 6) -> None:
    scene = trainer.scene
    out = run_dir / "strips"
    out.mkdir(parents=True, exist_ok=True)
    for m in trainer.cfg.model.modalities:
        views = scene.test[m]
        for view in [views[i] for i in np.linspace(0, len(views) - 1, min(count, len(views))).astype(int)] if views else []:
            pred = render_frame(trainer.model, m, view.time, view.camera)
            gt, valid = scene.target(view)
            stem = Path(view.frame.file_path).stem
            if m == "rgb":
                strip = viz.rgb_strip(gt.numpy(), pred.clamp(0, 1).numpy())
            else:
                gt_k = np.where(valid.numpy(), scene.kelvin(gt).numpy(), np.nan)
                strip = viz.thermal_strip(gt_k, scene.kelvin(pred[..., 0]).numpy())
            Image.fromarray(strip).save(out / f"{m}_{stem}.png")


def write_animation(trainer: Trainer, path: Path, frames: int = 24) -> None:
    """A test view (the first test camera) across the sequence: RGB | temperature in deg C."""
    scene = trainer.scene
    mods = trainer.cfg.model.modalities
    anchor = next((scene.test[m][0] for m in mods if scene.test[m]), None)
    if anchor is None:
        return
    images = []
    for t in np.linspace(0.0, 1.0, frames):
        panels = []
        for m in mods:
            view = min(scene.test[m] or scene.train[m], key=lambda v: abs(v.time - t))
            pred = render_frame(trainer.model, m, float(t), view.camera)
            if m == "rgb":
                panels.append((pred.clamp(0, 1).numpy() * 255 + 0.5).astype(np.uint8))
            else:
                panels.append(viz.thermal_image(scene.kelvin(pred[..., 0]).numpy(), scene.k_min, scene.k_max))
        h = max(p.shape[0] for p in panels)
        panels = [np.asarray(Image.fromarray(p).resize((round(p.shape[1] * h / p.shape[0]), h))) for p in panels]
        images.append(Image.fromarray(np.concatenate(panels, axis=1)))
    images[0].save(path, save_all=True, append_images=images[1:], duration=120, loop=0)


def finish(trainer: Trainer, run_dir: Path, dataset_dir: Path, test_scene: Scene | None = None) -> dict:
    """Render, grade, draw and export a trained run. Returns the metrics summary. test_scene: the
    test views to render and grade, of the dataset at dataset_dir (default: the training scene)."""
    t0 = time.perf_counter()
    (run_dir / "config.json").write_text(json.dumps(config_to_dict(trainer.cfg), indent=2))
    (run_dir / "scene.json").write_text(json.dumps(scene_facts(test_scene or trainer.scene, dataset_dir), indent=2))
    n = render_test_views(trainer, run_dir, test_scene)
    report = evaluate_run(run_dir, dataset_dir, modalities=trainer.cfg.model.modalities) if n else {}
    if report:
        write_results(report, run_dir / "eval")
    write_strips(trainer, run_dir)
    write_animation(trainer, run_dir / "animation.gif")
    (run_dir / "export").mkdir(parents=True, exist_ok=True)
    export_ply(trainer.model, run_dir / "export" / "model.ply")
    export_deformation(trainer.model, run_dir / "export" / "deformation.pt")
    summary = {
        "method": trainer.cfg.method, "dataset": str(dataset_dir), "iterations": trainer.iteration,
        "train_seconds": round(trainer.elapsed, 2), "gaussians": trainer.model.num_gaussians,
        "gaussians_per_role": trainer.counts(), "model_bytes": model_bytes(trainer.model),
        "metrics": {**report.get("mean", {}), "regions": report.get("regions", {}),
                    "objects": report.get("objects", {})},
        "finish_seconds": round(time.perf_counter() - t0, 2),
        "stop_reason": trainer.stop_reason(), "events": trainer.events,
    }
    (run_dir / "metrics.json").write_text(json.dumps(summary, indent=2))
    write_history(trainer, run_dir)
    return summary


def write_history(trainer: Trainer, run_dir: Path) -> None:
    (run_dir / "history.json").write_text(json.dumps(trainer.history, indent=1))
    (run_dir / "events.json").write_text(json.dumps({"stop_reason": trainer.stop_reason(),
                                                     "events": trainer.events}, indent=1))


def scene_facts(scene: Scene, data_dir: Path) -> dict:
    """What `recon render` needs besides the model: temperature scaling and a default camera."""
    views = scene.test["rgb"] or scene.test["thermal"] or scene.train["rgb"] or scene.train["thermal"]
    f = views[0].frame
    return {"dataset": str(data_dir.resolve()), "thermal_range_k": [scene.k_min, scene.k_max],
            "thermal_scale_k": scene.dataset.thermal_scale_k,
            "camera": {"c2w": np.asarray(f.c2w).tolist(), "fx": f.fx, "fy": f.fy, "cx": f.cx, "cy": f.cy,
                       "width": f.width, "height": f.height}}


def input_kind(path: Path) -> str:
    """dataset (transforms.json), session (session.json) or rgbt (an RGBT-Scenes folder: rgb/,
    thermal/, sparse/; prepared like a session, see docs/import.md)."""
    if (path / "transforms.json").exists():
        return "dataset"
    if (path / "session.json").exists():
        return "session"
    if is_rgbt_folder(path):
        return "rgbt"
    raise ValueError(f"{path}: neither a prepared dataset (transforms.json), a rig session (session.json) "
                     f"nor an RGBT-Scenes folder (rgb/ thermal/ sparse/); see FORMATS.md, `recon simulate`, "
                     f"`rig capture` or docs/import.md")


def make_trainer(args, scene: Scene, out: Path, overrides: dict) -> Trainer:
    if args.resume:
        ckpt = out / "checkpoints" / "latest.pt"
        if not ckpt.parent.is_dir():
            raise ValueError(f"{ckpt}: no checkpoint to resume from")
        trainer = Trainer.resume(ckpt, scene, out, **overrides)
        print(f"resumed at iteration {trainer.iteration}")
        return trainer
    return Trainer(config_from_args(args, overrides), scene, out)


def config_from_args(args, overrides: dict, live: bool = False):
    """The run's TrainConfig. Without --iterations the scene chooses the length (the schedule
    holds while held-out error still improves) within a --minutes cap (default 15); --fixed
    makes --minutes an exact budget; --iterations N trains exactly N iterations."""
    cfg = make_config(args.method, **overrides)
    if live:     # a capture grows in time by itself: no training window to grow, and paths
        cfg.curriculum.grow_every = 0        # fitted to its first frames only (not measured)
        cfg.curriculum.tracked_paths = False
    if not live and args.iterations is None:
        cfg.stop.converge = not args.fixed
        cfg.minutes = cfg.minutes or DEFAULT_MINUTES
    if args.max_gaussians:
        cfg.densify.max_gaussians = args.max_gaussians
    cfg.densify.auto_stop = args.auto_budget
    if args.max_scale:
        cfg.densify.max_scale = args.max_scale
    if args.crop:
        cfg.crop = args.crop
    if args.coarse_to_fine:
        cfg.resolution = coarse_to_fine(args.coarse_to_fine, cfg.stop.hold_at)
    return cfg


def prepare_options(args, kind: str = "session") -> dict:
    """The `recon prepare` options of a session or RGBT-Scenes run (prepare's defaults where not
    given; a session's 640x480 thermal frames are downscaled 4x by default, an RGBT folder's
    images are kept at their size)."""
    given = {"calibration": args.calibration, "scale": args.scale, "frames": args.frames}
    downscale = args.downscale or (4 if kind == "session" else 1)
    return {"downscale": downscale, **{k: v for k, v in given.items() if v is not None}}


def prepare_refused(session: Path, data_dir: Path, exc: Exception) -> str:
    """One paragraph for a session `recon prepare` would not turn into a dataset."""
    return (f"recon run: nothing trained: {session} could not be prepared: {exc}. What was measured is in "
            f"{data_dir / REPORT_FILE}")


def run(args: argparse.Namespace) -> int:
    inp, out = Path(args.input), Path(args.out)
    kind = input_kind(inp)
    if args.follow and (kind != "session" or args.resume or args.frames is not None):
        raise ValueError("--follow trains on a rig session while it is captured (and cannot --resume or "
                         "take --frames: it picks its own)")
    if kind == "session":
        try:
            PrepareOptions(**prepare_options(args))
        except ValueError as exc:
            print(f"recon run: {exc}", file=sys.stderr)
            return 2
    out.mkdir(parents=True, exist_ok=True)
    overrides = {k: v for k, v in {"iterations": args.iterations, "minutes": args.minutes,
                                   "seed": args.seed, "threads": args.threads,
                                   "checkpoint_every": args.checkpoint_every,
                                   "share_cores": False if args.fixed_threads else None}.items() if v is not None}
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    live = LiveRenderService() if getattr(args, "serve", False) else None     # the page's viewer panel
    handle = serve_from_args(args, run_dir=out, session_dir=inp if kind == "session" else None, renderer=live)
    feed = TrainingFeed(LivePublisher(out))
    if live:
        feed.on_step = live.chain(feed.on_step)     # hands the viewer a model copy between steps, when asked
    try:
        return train_and_finish(args, inp, out, kind, overrides, feed, log)
    except BaseException:
        feed.pub.status({"state": "failed"})
        raise
    finally:
        if handle:
            handle.stop()


def train_and_finish(args, inp: Path, out: Path, kind: str, overrides: dict, feed, log) -> int:
    if args.follow:
        from recon.live.follow import FollowError, FollowOptions, follow
        cfg = config_from_args(args, overrides, live=True)
        try:
            trainer, data_dir = follow(inp, out, cfg, FollowOptions(after_iterations=args.after), log,
                                       prepare_options=prepare_options(args), on_step=feed.on_step)
        except FollowError as exc:
            report = f" What was measured is in {exc.data_dir / REPORT_FILE}" if exc.data_dir else ""
            raise ValueError(f"recon run: nothing trained: {exc}.{report}") from None
    else:
        data_dir = inp
        if kind in ("session", "rgbt"):
            data_dir = out / "data"
            if not (data_dir / "transforms.json").exists():
                try:
                    prepare_session(inp, data_dir, **prepare_options(args, kind))
                except PrepareError as exc:     # a refusal with advice, not a crash
                    raise ValueError(prepare_refused(inp, data_dir, exc)) from None
        scene = Scene(load_dataset(data_dir))
        trainer = make_trainer(args, scene, out, overrides)
        try:
            trainer.train(on_step=feed.on_step)
        except TrainingDiverged as exc:
            feed.publish_status(trainer, state="failed")
            write_history(trainer, out)
            raise SystemExit(f"recon run: {exc}. What happened: {out / 'events.json'}") from None
    feed.publish_status(trainer, state="finishing")
    summary = finish(trainer, out, data_dir)
    feed.finish(trainer)
    print(json.dumps(summary["metrics"], indent=2))
    print(f"stopped: {summary['stop_reason']}")
    for event in trainer.events:
        print(f"{'warning' if event.get('warning') else 'divergence'}: {event}")
    print(f"{trainer.model.num_gaussians} Gaussians {summary['gaussians_per_role']}, "
          f"{summary['model_bytes'] / 1e6:.1f} MB, trained {summary['train_seconds']:.0f} s -> {out}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "run", help="train a method on a prepared dataset, then render, grade and export",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__,
        epilog="examples:\n"
               "  recon simulate data/default --frames 40 --size 160x120\n"
               "  recon run data/default --out runs/dtg --minutes 10\n"
               "  recon run data/default --method ed3dgs-thermal --out runs/ed-th --iterations 2000\n"
               "  recon run sessions/s1 --downscale 1 --coarse-to-fine 2 --crop 0.5 --out runs/s1-640   # at 640x480\n"
               "  recon run data/default --out runs/dtg --resume      # continue from the last checkpoint\n"
               "  recon run sessions/s1 --out runs/s1                 # a rig session: recon prepare, then train\n"
               "  recon run scenes/lab --out runs/lab                 # an RGBT-Scenes folder: the same\n"
               "  rig capture --duration 60 --out sessions/live &\n"
               "  recon run sessions/live --follow --out runs/live    # train while it captures")
    p.add_argument("input", metavar="DATASET_OR_SESSION",
                   help="prepared dataset folder (transforms.json), rig session (session.json) or RGBT-Scenes "
                        "folder (rgb/ thermal/ sparse/); the latter two are prepared into OUT/data with "
                        "`recon prepare` first")
    p.add_argument("--method", default="dtg", choices=list(METHODS),
                   help="dtg (full) or a baseline/ablation of the paper's Table 3 (default: dtg)")
    p.add_argument("--out", required=True, help="run folder (created)")
    p.add_argument("--iterations", type=positive_int,
                   help="train exactly N iterations (default: until held-out error has converged, "
                        "within --minutes)")
    p.add_argument("--minutes", type=positive_float,
                   help=f"wall-clock cap (default {DEFAULT_MINUTES:g}); training usually ends earlier, "
                        f"when held-out error on every 8th time step has converged")
    p.add_argument("--fixed", action="store_true",
                   help="train for exactly --minutes (the schedule stretched to fit), not until converged")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoints/latest.pt")
    p.add_argument("--checkpoint-every", type=positive_int,
                   help="iterations between checkpoints (default 500; a batch job on a cluster that may "
                        "lose nodes wants them more often)")
    p.add_argument("--max-gaussians", type=positive_int, help="Gaussian budget (default: 0.5 per pixel of a training image, within 5k..100k)")
    p.add_argument("--max-scale", type=positive_float, metavar="E",
                   help="no Gaussian longer than E scene extents (default unbounded). 0.3 removes the needles "
                        "that streak or veil views from far outside the capture's sweep, for 0.2-0.4 dB of "
                        "RGB inside it (docs/training.md, 'Long Gaussians')")
    p.add_argument("--auto-budget", action="store_true",
                   help="stop adding Gaussians when held-out PSNR stops improving")
    p.add_argument("--follow", action="store_true",
                   help="train while `rig capture` is still writing SESSION; stop --after iterations after it ends")
    p.add_argument("--after", type=int, default=1500, help="with --follow: iterations after capture ends (default 1500)")
    p.add_argument("--coarse-to-fine", type=positive_int, metavar="N",
                   help="train on views averaged to 1/2^N of their size until held-out error has converged, "
                        "then double the size N times up to full size for the rest of the run (default: full "
                        "size throughout); with --crop for native 640x480 (docs/training.md)")
    p.add_argument("--crop", type=unit_fraction, metavar="F",
                   help="train each step on a random window of the view, F of its width and height "
                        "(default 1: whole frames); 0.5 makes a 640x480 step cost about a 320x240 one "
                        "while every pixel is still trained on (docs/training.md)")
    p.add_argument("--downscale", type=positive_int,
                   help="a session's images are prepared at 1/N size (default 4: 640x480 thermal -> 160x120; "
                        "an RGBT-Scenes folder's: 1)")
    p.add_argument("--calibration", type=Path, help="a session's rig_calibration.json (see `recon prepare`)")
    p.add_argument("--scale", type=float, help="a session's metres per SfM unit (see `recon prepare`)")
    p.add_argument("--frames", type=positive_int,
                   help=f"a session's time steps (see `recon prepare`; default {PrepareOptions().frames})")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=positive_int,
                   help="CPU threads at most (default: all); one while other processes keep a core busy")
    p.add_argument("--fixed-threads", action="store_true",
                   help="always --threads, even while other processes keep cores busy: the same result whatever "
                        "else runs (torch's sums depend on the thread count); also RECON_FIXED_THREADS=1")
    add_serve_arguments(p)
    p.set_defaults(func=run)
