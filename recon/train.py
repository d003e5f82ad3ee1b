"""Training loop: per iteration an RGB stage update, then a thermal stage update (DTG paper 4.1).

The schedule is a function of progress p in [0, 1] (iterations done / iterations, or elapsed /
budget with ``minutes``): learning-rate decay, active SH degree, routing phases, densification
window. A checkpoint holds everything needed to continue bit-for-bit: parameters, optimizer
moments, densification statistics, random generator states, history.
"""
from __future__ import annotations

import copy
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from recon import routing
from recon.config import TrainConfig, config_from_dict, config_to_dict
from recon.eval import psnr
from recon.gaussians import extend_knots, init_gaussians, knn_mean_sq_dist, trajectory_knots
from recon.losses import EmbeddingSmoothness, rgb_loss, thermal_loss, trimmed_l1
from recon.model import DTGModel, check_params, time_rows
from recon.motion import connected_clusters
from recon.curriculum import TimeWindow, extrapolate_rows, place_bases
from recon.checkpoint import PREVIOUS_CHECKPOINT, read_checkpoint
from recon.guard import DivergenceGuard, Event, TrainingDiverged, nonfinite_parameter
from recon.points import changing_points, initial_temperatures, observed_time
from recon.priors import MotionPriors
from recon.schedule import Schedule
from recon.render import inference_masks, render
from recon.scene import Scene
from recon.strategy import Strategy, swap_parameter
from recon.time_embedding import resample_rows


def log_lerp(a: float, b: float, p: float) -> float:
    """Exponential (log-linear) decay from a to b as p goes 0 -> 1 (3DGS get_expon_lr_func)."""
    p = min(max(p, 0.0), 1.0)
    return math.exp(math.log(a) * (1 - p) + math.log(b) * p)


def initial_background(scene: Scene, modality: str) -> torch.Tensor:
    """Median of the image borders over a few training views: a start for the learned background."""
    views = scene.train[modality][:: max(1, len(scene.train[modality]) // 4)][:4]
    border = []
    for view in views:
        img, valid = scene.target(view)
        img = img if img.dim() == 3 else img[..., None]
        ring = torch.cat([img[0], img[-1], img[:, 0], img[:, -1]])
        if valid is not None:
            ring = ring[torch.cat([valid[0], valid[-1], valid[:, 0], valid[:, -1]])]
        border.append(ring)
    return torch.cat(border).median(0).values if border else torch.zeros(3 if modality == "rgb" else 1)


class Trainer:
    def __init__(self, cfg: TrainConfig, scene: Scene, out_dir: Path | None = None,
                 model: DTGModel | None = None, log=None):
        self.cfg = cfg
        self.scene = scene
        self.out_dir = Path(out_dir) if out_dir else None
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        missing = [m for m in cfg.model.modalities if not scene.train[m]]
        if missing:
            raise ValueError(f"method {cfg.method} trains {missing} but the dataset has no such training frames")
        if cfg.threads:
            torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.extent = scene.extent()
        self.model = model if model is not None else self._init_model()
        check_params(cfg.model, dict(self.model.gaussians))
        self.optimizer = self._build_optimizer()
        if not cfg.densify.max_gaussians:
            v = next(iter(scene.train[cfg.model.modalities[0]]))
            cfg.densify.max_gaussians = int(min(max(0.5 * v.camera.width * v.camera.height, 5000), 100_000))
        self.strategy = Strategy(cfg.densify, cfg.model.modalities, self.extent, self.gen)
        self.smoothness = EmbeddingSmoothness(cfg.loss.embedding_knn, cfg.loss.embedding_knn_sample,
                                              cfg.loss.embedding_knn_falloff, self.extent)
        self.priors = MotionPriors(cfg.priors, self.extent)
        self.iteration = 0
        self.elapsed = 0.0
        self.history: list[dict] = []
        self.best_holdout = -math.inf
        self.rounds_without_gain = 0
        self.schedule = Schedule(cfg.iterations, cfg.minutes, cfg.stop.converge, cfg.stop.hold_at,
                                 cfg.stop.patience, cfg.stop.min_gain_db)
        self.guard = DivergenceGuard(cfg.guard)
        self.lr_scale = 1.0          # lowered by each rollback
        self.events: list[dict] = []   # divergences and rollbacks, for the log, history and status
        self._snapshot: dict | None = None
        self._hold_over = False
        self.progress_fn = None    # live training (recon.follow) drives the schedule itself
        self.holdout = self._holdout_views()
        self.window = TimeWindow(cfg.curriculum, scene.times, cfg.iterations)
        if self.cfg.stop.converge and not self.validation_times:
            self.schedule.release("no held-out time steps to judge convergence (fewer than "
                                  f"{cfg.stop.validation_every // 2 + 1}): the nominal schedule")

    # ------------------------------------------------------------------ set-up
    def _init_model(self) -> DTGModel:
        ds = self.scene.dataset
        if ds.points_xyz is None or len(ds.points_xyz) == 0:
            raise ValueError(f"{ds.root}: no initial points (points3d.ply); recon needs an SfM point cloud")
        pts = torch.as_tensor(np.asarray(ds.points_xyz), dtype=torch.float32)
        rgb = torch.as_tensor(np.asarray(ds.points_rgb if ds.points_rgb is not None else np.full((len(pts), 3), 0.5)),
                              dtype=torch.float32)
        if rgb.max() > 1.0:
            rgb = rgb / 255.0
        if len(pts) > self.cfg.max_points:
            keep = torch.randperm(len(pts), generator=self.gen)[: self.cfg.max_points]
            pts, rgb = pts[keep], rgb[keep]
        n_times = self.scene.steps_per_unit_time()
        m = self.cfg.model
        bases = m.motion_bases and m.deformation != "none"
        dynamic = changing_points(self.scene, pts, m.split_rgb, m.split_kelvin, m.split_fraction) \
            if m.motion_split or bases else None
        if dynamic is not None:
            self.log(f"static/dynamic split: {int(dynamic.sum())} of {len(pts)} initial points see a "
                     f"changing scene and may move")
        basis, pivots = None, None
        if bases:
            pts, rgb, dynamic, basis, pivots = self._motion_init(pts, rgb, dynamic)
        temps = initial_temperatures(self.scene, pts) if "thermal" in self.cfg.model.modalities else None
        params = init_gaussians(pts, rgb, temps, m, self.cfg.routing, self.gen,
                                trajectory_knots(m, n_times), dynamic if m.motion_split else None, basis)
        bgs = {m: initial_background(self.scene, m) for m in self.cfg.model.modalities}
        return DTGModel(self.cfg.model, params, n_times=n_times, backgrounds=bgs, pivots=pivots)

    def _motion_init(self, pts, rgb, dynamic):
        """Motion bases from the initial points: the moving points as seen at one instant, one
        rigid basis per spatially connected group of them (recon/motion.py). Points of moving
        things seen at other instants (ghosts along their paths) are dropped: from that instant
        on they would be in the wrong place. -> (points, colours, dynamic flags, basis (M,), pivots)"""
        m, c = self.cfg.model, self.cfg.curriculum
        flagged = dynamic.clone()
        seen = observed_time(self.scene, pts[flagged], rgb[flagged]) if flagged.any() else None
        if seen is not None:
            t_seen, matched = seen
            if c.center < 0:
                c.center = t_seen
                self.log(f"the moving points match the views best at t = {t_seen:.3f}: motion is learned "
                         f"outwards from there")
            ghosts = flagged.nonzero()[:, 0][~matched]
            keep = torch.ones(len(pts), dtype=torch.bool)
            keep[ghosts] = False
            pts, rgb, dynamic, flagged = pts[keep], rgb[keep], dynamic[keep], flagged[keep]
            self.log(f"{len(ghosts)} moving points seen at other instants dropped")
        basis = torch.zeros(len(pts))
        index = flagged.nonzero()[:, 0]
        if len(index) < max(m.basis_points // 5, 3):
            self.log("motion bases: no moving points; every Gaussian is static")
            return pts, rgb, dynamic, basis, torch.zeros(0, 3)
        spacing = knn_mean_sq_dist(pts[index], k=1).sqrt().median()
        labels = connected_clusters(pts[index], float(3 * spacing))
        sizes = torch.bincount(labels)
        usable = [k for k in range(len(sizes)) if sizes[k] >= max(m.basis_points // 5, 3)][: m.motion_bases]
        if not usable:
            self.log("motion bases: the moving points form no body; every Gaussian is static")
            return pts, rgb, dynamic, basis, torch.zeros(0, 3)
        pivots = torch.stack([pts[index][labels == k].mean(0) for k in usable])
        for b, k in enumerate(usable):
            basis[index[labels == k]] = b + 1
        self.log(f"motion bases: {len(usable)} rigid bodies from {int((basis > 0).sum())} moving points")
        return pts, rgb, dynamic, basis, pivots

    def _base_lr(self, key: str) -> float:
        lr = self.cfg.lr
        if key == "means":
            return lr.means_scene[0] * self.extent
        if key.startswith("features_"):
            if key.endswith("_rest"):
                return lr.rgb_rest if "rgb" in key else lr.thermal / 20
            return lr.rgb_dc if "rgb" in key else lr.thermal
        if key == "trajectory":
            return lr.trajectory_scene[0] * self.extent
        if key == "dynamic_logit":
            return lr.dynamic
        table = {"quats": lr.quats, "log_scales": lr.scales, "route_logits": self.cfg.routing.lr}
        if key in table:
            return table[key]
        if key.startswith("opacity_"):
            return lr.opacity
        if key.startswith("embedding"):
            return lr.embedding
        raise KeyError(f"no learning rate for Gaussian parameter {key!r}")

    def _build_optimizer(self) -> torch.optim.Optimizer:
        groups = [{"params": [p], "name": k, "lr": self._base_lr(k), "base_lr": self._base_lr(k)}
                  for k, p in self.model.gaussians.items() if p.requires_grad]
        if self.cfg.model.deformation != "none":
            groups.append({"params": list(self.model.deformers.parameters()), "name": "deformation",
                           "lr": self.cfg.lr.deformation_scene[0] * self.extent})
            groups.append({"params": list(self.model.time_embedding.parameters()), "name": "time_embedding",
                           "lr": self.cfg.lr.time_embedding[0]})
        if self.model.motion is not None:
            lr = self.cfg.lr
            groups.append({"params": [self.model.motion.rotation], "name": "motion_rotation",
                           "lr": lr.motion_rotation[0]})
            groups.append({"params": [self.model.motion.translation], "name": "motion_translation",
                           "lr": lr.motion_translation_scene[0] * self.extent})
        groups.append({"params": list(self.model.backgrounds.parameters()), "name": "backgrounds",
                       "lr": self.cfg.lr.thermal_background, "base_lr": self.cfg.lr.thermal_background})
        return torch.optim.Adam(groups, lr=0.0, eps=1e-15, fused=True)

    def uses_validation(self) -> bool:
        """Whether held-out training time steps decide anything (when to stop, how many Gaussians)."""
        return (self.cfg.stop.converge or self.cfg.densify.auto_stop) and self.progress_fn is None

    def _holdout_views(self):
        """Views for the progress line and, when held-out error decides when to stop or how many
        Gaussians to grow, for that decision. The progress line shows the test view nearest the
        middle of the sequence; decisions must not look at test data, so they use every 8th
        training time step instead (offset 4), kept out of training until the schedule's hold
        ends (with the automatic budget alone: for the whole run)."""
        out = {}
        every = self.cfg.stop.validation_every
        held = set(self.scene.times[every // 2::every]) if self.uses_validation() else set()
        self.validation_times = held
        self.train_times = [t for t in self.scene.times if t not in held]
        for m in self.cfg.model.modalities:
            if held:
                out[m] = [v for v in self.scene.train[m] if v.time in held]
            else:
                views = self.scene.test[m] or self.scene.train[m]
                out[m] = [min(views, key=lambda v: abs(v.time - 0.5))] if views else []
        return out

    def replace_scene(self, scene: Scene) -> None:
        """Continue on a grown scene (live training): same model, optimizer and statistics; new
        frames and time steps. The scene extent, hence step sizes, stays that of the first scene.
        When the time steps grew at least twice as dense, the time embedding is refined to match."""
        self.scene = scene
        self.holdout = self._holdout_views()
        self.window = TimeWindow(self.cfg.curriculum, scene.times, self.cfg.iterations)
        if self.cfg.model.deformation != "none":
            want = time_rows(self.cfg.model, scene.steps_per_unit_time())[1]
            have = self.model.time_embedding.fine.shape[0]
            factor = (want - 1) // max(have - 1, 1)
            if factor >= 2:
                self.refine_time(factor)
                self.model.n_times = scene.steps_per_unit_time()

    def extend_time(self, factor: int) -> None:
        """Make the time embedding (and trajectories) cover a `factor` times longer span without
        losing what they learned (TimeEmbedding.extended); Adam moments are padded with zeros."""
        def pad(v: torch.Tensor, rows: int) -> torch.Tensor:
            return torch.cat([v, v.new_zeros(rows - v.shape[0], *v.shape[1:])])
        self._replace_time_tables(self.model.time_embedding.extended(factor), pad)
        self._resize_trajectories(lambda x, moment: extend_knots(x, factor, zero=moment))
        self._resize_motion(lambda x, moment: extend_knots(x, factor, zero=moment))

    def refine_time(self, factor: int) -> None:
        """`factor` times more time-embedding rows (and trajectory knots) over the same span
        (TimeEmbedding.refined); Adam moments are interpolated like the rows."""
        self._replace_time_tables(self.model.time_embedding.refined(factor), resample_rows)
        refine = lambda x, _: resample_rows(x, (x.shape[1] - 1) * factor + 1, dim=1)  # noqa: E731
        self._resize_trajectories(refine)
        self._resize_motion(refine)

    @torch.no_grad()
    def _resize_motion(self, fn) -> None:
        """fn(knots (B, K, 3), is_moment) -> (B, K', 3) for the motion bases and their Adam moments."""
        motion = self.model.motion
        if motion is None:
            return
        for name in ("rotation", "translation"):
            old = getattr(motion, name)
            param = torch.nn.Parameter(fn(old.detach(), False).clone())
            group = next(g for g in self.optimizer.param_groups if g["name"] == f"motion_{name}")
            group["params"] = [param]
            state = self.optimizer.state.pop(old, {})
            if state:
                self.optimizer.state[param] = {k: (fn(v, True) if torch.is_tensor(v) and v.dim() == 3 else v)
                                               for k, v in state.items()}
            setattr(motion, name, param)

    def _resize_trajectories(self, fn) -> None:
        """fn(knots (N, K, 3), is_moment) -> (N, K', 3) for the trajectory and its Adam moments."""
        if "trajectory" in self.model.gaussians:
            swap_parameter(self.model.gaussians, self.optimizer, "trajectory",
                           lambda x: fn(x, False), lambda x: fn(x, True))

    @torch.no_grad()
    def _replace_time_tables(self, new: dict[str, torch.Tensor], moments) -> None:
        """Install new time-embedding tables as fresh parameters of the optimizer;
        moments(old (R, D) Adam moment, new row count) -> its (R', D) successor."""
        te = self.model.time_embedding
        group = next(g for g in self.optimizer.param_groups if g["name"] == "time_embedding")
        for name, table in new.items():
            old = getattr(te, name)
            param = torch.nn.Parameter(table.clone())
            state = self.optimizer.state.pop(old, {})
            group["params"] = [param if p is old else p for p in group["params"]]
            if state:
                self.optimizer.state[param] = {k: (moments(v, table.shape[0]) if torch.is_tensor(v) and v.dim() == 2 else v)
                                               for k, v in state.items()}
            setattr(te, name, param)

    # ------------------------------------------------------------------ schedule
    def progress(self) -> float:
        if self.progress_fn is not None:
            return self.progress_fn(self)
        return self.schedule.progress(self.iteration, self.elapsed)

    def done(self) -> bool:
        return self.progress() >= 1.0

    def stop_reason(self) -> str:
        return self.schedule.end_reason(self.iteration)

    def expected_iterations(self) -> float:
        """Iterations this run will make: the budget, or with --minutes the pace so far."""
        if self.cfg.minutes and not self.cfg.stop.converge and self.iteration >= 20 and self.progress() > 0:
            return self.iteration / self.progress()
        return float(self.cfg.iterations)

    def _update_lrs(self, p: float) -> None:
        lr = self.cfg.lr
        routing_scale = max(1.0, self.cfg.routing.lr_reference_iterations / max(self.expected_iterations(), 1.0))
        # the ramp takes at most a tenth of a short run
        ramp = min(lr.deformation_warmup, 0.1 * self.expected_iterations())
        warm = min(1.0, (self.iteration + 1) / ramp) if ramp >= 1 else 1.0
        for group in self.optimizer.param_groups:
            if group["name"] == "route_logits":
                value = self.cfg.routing.lr * routing_scale
            elif group["name"] == "means":
                value = log_lerp(*lr.means_scene, p) * self.extent
            elif group["name"] == "trajectory":
                value = log_lerp(*lr.trajectory_scene, p) * self.extent
            elif group["name"] == "deformation":
                value = log_lerp(*lr.deformation_scene, p) * self.extent * warm
            elif group["name"] == "motion_rotation":
                value = log_lerp(*lr.motion_rotation, p)
            elif group["name"] == "motion_translation":
                value = log_lerp(*lr.motion_translation_scene, p) * self.extent
            elif group["name"] == "time_embedding":
                value = log_lerp(*lr.time_embedding, p) * warm
            else:
                value = group["base_lr"]
            group["lr"] = value * self.lr_scale

    def active_sh_degree(self, modality: str, p: float) -> int:
        full = self.cfg.model.rgb_sh_degree if modality == "rgb" else self.cfg.model.thermal_sh_degree
        return min(full, int(p / self.cfg.sh_increase_every)) if self.cfg.sh_increase_every > 0 else full

    # ------------------------------------------------------------------ one iteration
    def _routing_noise(self, p: float) -> torch.Tensor | None:
        """Gumbel noise (N, 3) for this iteration while routing learns, else None."""
        if not self.cfg.model.routing or routing.phase(self.cfg.routing, p) not in ("learn", "specialise"):
            return None
        return routing.gumbel_noise(self.model.gaussians["route_logits"].shape, self.gen)

    def _motion_priors(self, g: dict, t: float, p: float, stats: dict):
        """The motion priors on the geometry g of the stage that moves every modality."""
        gs = self.model.gaussians
        canonical = {k: gs[k] for k in ("means", "quats", "log_scales", "dynamic") if k in gs}
        stage = self.model.motion_stage()
        dt = 1.0 / max(self.model.n_times - 1, 1)
        if self.cfg.priors.static > 0 and "dynamic_logit" in gs:
            gate = self.model.dynamic_gate().mean()
            loss_gate = self.cfg.priors.static * gate
            stats["prior_gate"] = float(gate.detach())
        else:
            loss_gate = 0.0

        def means_at(tt: float, idx: torch.Tensor) -> torch.Tensor:
            return gs["means"][idx] if stage is None else self.model.means_at(stage, tt, p, idx)
        loss, terms = self.priors(canonical, g, means_at, t, dt, self.gen)
        stats.update({f"prior_{k}": v for k, v in terms.items()})
        return loss + loss_gate

    def _stage(self, modality: str, t: float, p: float, noise, rgb_geometry, regularise: bool) -> dict:
        views = self.scene.views_at(modality, t)
        view = views[int(torch.randint(len(views), (1,), generator=self.gen))]
        target, valid = self.scene.target(view)
        mask, reg, stats = None, 0.0, {}
        if noise is not None:
            hard, soft = routing.assignment(self.model.gaussians["route_logits"], self.cfg.routing.tau, noise)
            mask = routing.masks(hard)[modality]
            if regularise:
                kl = routing.kl_to_prior(soft, routing.prior(self.cfg.routing, p))
                reg = reg + self.cfg.routing.kl_weight * kl
                stats["kl"] = float(kl.detach())
        elif self.cfg.model.routing and routing.phase(self.cfg.routing, p) == "frozen":
            mask = inference_masks(self.model)[modality]
        background = None
        if modality == "rgb" and float(torch.rand((), generator=self.gen)) < self.cfg.loss.random_background_rgb:
            background = torch.rand(self.model.backgrounds[modality].shape, generator=self.gen)
        image, out, g = render(self.model, modality, t, view.camera, p, sh_degree=self.active_sh_degree(modality, p),
                               mask=mask, rgb_geometry=rgb_geometry, background=background)
        if not self.window.contains(t):
            keep = self.cfg.curriculum.outside_keep
            rec = trimmed_l1(image, target, None, keep) if modality == "rgb" else \
                self.cfg.loss.thermal_l1 * trimmed_l1(image[..., 0], target, valid, keep)
        elif modality == "rgb":
            rec = rgb_loss(image, target, self.cfg.loss.rgb_dssim)
        else:
            rec = self.cfg.loss.thermal_l1 * thermal_loss(image[..., 0], target, valid)
        if regularise:
            reg = reg + self._regularisers(stats)
        if self.priors.enabled and self.model.stage_of(modality) == self.model.motion_stage():
            reg = reg + self._motion_priors(g, t, p, stats)
        loss = rec + reg
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.strategy.accumulate(modality, out.means2d.grad, out.radii, view.camera.width, view.camera.height)
        stats[f"loss_{modality}"] = float(rec.detach())
        return {"stats": stats, "geometry": {k: v.detach() for k, v in g["geometry_residuals"].items()}}

    def _regularisers(self, stats: dict):
        cfg, model = self.cfg.loss, self.model
        reg = 0.0
        keys = [k for k in model.gaussians if k.startswith("embedding")]
        if keys and cfg.embedding_smoothness > 0:
            e = self.smoothness(model.gaussians["means"], [model.gaussians[k] for k in keys], self.gen)
            reg = reg + cfg.embedding_smoothness * e
            stats["embed"] = float(e.detach())
        if model.motion is not None and self.cfg.priors.basis_smoothness > 0:
            acc = model.motion.smoothness(self.extent)
            reg = reg + self.cfg.priors.basis_smoothness * acc
            stats["basis_acc"] = float(acc.detach())
        if self.cfg.model.deformation != "none" and cfg.time_smoothness > 0:
            tv = model.time_embedding.temporal_smoothness()
            reg = reg + cfg.time_smoothness * tv
            stats["time"] = float(tv.detach())
        return reg

    def step(self) -> dict:
        """One iteration. Returns its statistics."""
        start = time.perf_counter()
        p = self.progress()
        self._update_lrs(p)
        # the window's clock: iterations, or the share of a --minutes budget when iterations are
        # slow (so the window is whole by `complete_by` of the time, whatever the pace)
        taken_in = self.window.update(max(self.iteration, int(p * self.cfg.iterations)))
        if taken_in:            # (all knots start at rest: nothing to carry on before)
            self._extrapolate(*self.window.span())
            if self.cfg.curriculum.search and self.model.motion is not None:
                for side, when in taken_in:
                    self._place(when, side)
        t = self.window.pick(self.train_times, self.gen)
        mods = [m for m in ("rgb", "thermal") if m in self.cfg.model.modalities and self.scene.views_at(m, t)]
        noise = self._routing_noise(p)
        stats, rgb_geometry = {}, None
        for i, m in enumerate(mods):
            res = self._stage(m, t, p, noise, rgb_geometry if m == "thermal" else None, regularise=(i == 0))
            stats.update(res["stats"])
            # The thermal stage reuses the RGB stage's (detached) geometry, unless the thermal loss
            # is to shape F_rgb too: then the model recomputes it with its graph.
            if (m == "rgb" and self.cfg.model.deformation == "progressive"
                    and not self.cfg.model.thermal_grad_to_rgb_deformation):
                rgb_geometry = res["geometry"]
        self.iteration += 1
        report = self.strategy.step(self.model.gaussians, self.optimizer, self.iteration, p)
        if report:
            stats.update(report)
        self.elapsed += time.perf_counter() - start
        if self.progress_fn is None:
            self.schedule.advance(self.iteration, self.elapsed)
            self._after_hold()
        return stats

    def _place(self, t: float, side: str) -> None:
        """Search where the motion bases are at a newly taken-in time step (recon/curriculum.py)."""
        frames = []
        for m in self.cfg.model.modalities:
            for view in self.scene.views_at(m, t):
                target, valid = self.scene.target(view)
                frames.append((m, view, target, valid))
        place_bases(self.model, frames, t, side)

    @torch.no_grad()
    def _extrapolate(self, lo: float, hi: float) -> None:
        """Time rows beyond the window continue its edges (recon/curriculum.py)."""
        if self.cfg.curriculum.grow_every <= 0 or self.cfg.model.deformation == "none":
            return
        g = self.model.gaussians
        if "trajectory" in g:
            extrapolate_rows(g["trajectory"].data, lo, hi, dim=1, velocity=True)
        if self.model.motion is not None:
            extrapolate_rows(self.model.motion.rotation.data, lo, hi, dim=1, velocity=True)
            extrapolate_rows(self.model.motion.translation.data, lo, hi, dim=1, velocity=True)
        te = self.model.time_embedding
        for table in (te.coarse, te.fine):
            extrapolate_rows(table.data, lo, hi, dim=0, velocity=False)

    def _after_hold(self) -> None:
        """Once the schedule's hold has ended: say why, and train on the held-out time steps too
        (with the automatic budget they stay out: it keeps deciding)."""
        if not self.schedule.released or self._hold_over:
            return
        self._hold_over = True
        self.log(f"iteration {self.iteration}: {self.schedule.stop_reason}")
        if self.schedule.stop_reason.startswith("converged") and self.strategy.growing:
            self.strategy.growing = False     # held-out error gains nothing more: model no more
            self.log(f"no more densification: {self.model.num_gaussians} Gaussians")
        if not self.cfg.densify.auto_stop:
            self.train_times = list(self.scene.times)

    # ------------------------------------------------------------------ evaluation
    @torch.no_grad()
    def holdout_psnr(self) -> dict[str, float]:
        from recon.render import render_frame
        out = {}
        for m, views in self.holdout.items():
            scores = []
            for view in views:
                pred = render_frame(self.model, m, view.time, view.camera)
                target, valid = self.scene.target(view)
                if m == "rgb":
                    scores.append(float(psnr(pred.clamp(0, 1), target)))
                else:
                    scores.append(float(psnr(pred[..., 0].clamp(0, 1), target, mask=valid)))
            if scores:
                out[m] = sum(scores) / len(scores)
        return out

    def _auto_budget(self, scores: dict[str, float]) -> None:
        if not self.cfg.densify.auto_stop or not self.strategy.growing or not scores:
            return
        score = sum(scores.values()) / len(scores)
        if score > self.best_holdout + self.cfg.densify.auto_min_gain_db:
            self.best_holdout, self.rounds_without_gain = score, 0
            return
        self.rounds_without_gain += 1
        if self.rounds_without_gain >= self.cfg.densify.auto_patience:
            self.strategy.growing = False
            self.log(f"automatic budget: held-out PSNR stopped improving at {self.model.num_gaussians} "
                     f"Gaussians; no more densification")

    def counts(self) -> dict[str, int]:
        g = self.model.gaussians
        if "route_logits" in g:
            return routing.role_counts(g["route_logits"].detach())
        return {"shared" if len(self.cfg.model.modalities) > 1 else self.cfg.model.modalities[0]: self.model.num_gaussians}

    # ------------------------------------------------------------------ loop
    def train(self, on_eval=None, on_step=None) -> list[dict]:
        """Run to the end of the budget with a progress line, periodic evaluation and checkpoints.
        on_step(trainer, stats) after every iteration (the live status feed)."""
        self.announce()
        while not self.done():
            stats = self.tick(on_eval)
            if on_step:
                on_step(self, stats)
        sys.stderr.write("\n")
        return self.history

    def announce(self) -> None:
        total = f"{self.cfg.minutes:g} min" if self.cfg.minutes else f"{self.cfg.iterations} it"
        self.log(f"training {self.cfg.method}: {self.model.num_gaussians} Gaussians, "
                 f"{len(self.scene.times)} time steps, budget {total}, scene extent {self.extent:.3f}")

    def tick(self, on_eval=None) -> dict:
        """One iteration plus, when due, held-out evaluation (on_eval(trainer, record) is called
        with each history record), the progress line and a checkpoint."""
        if self._snapshot is None:
            self._take_snapshot()            # the state to return to if the first steps blow up
        t0 = time.perf_counter()
        try:
            stats = self.step()
        except ValueError:                   # the rasterizer refuses non-finite Gaussians
            bad = nonfinite_parameter(self.model)
            if bad is None:
                raise
            self._rollback(f"parameter {bad} is not finite")
            return {}
        self._window = (getattr(self, "_window", []) + [time.perf_counter() - t0])[-50:]
        self._last = {**getattr(self, "_last", {}), **{k: v for k, v in stats.items() if k.startswith("loss_")}}
        it = self.iteration
        # While the time window grows, each new time step raises the loss by design: the loss
        # rule would read that as a blow-up (non-finite values are still caught).
        blow_up = self.guard.check_step(stats, ratio=self.window.complete)
        if blow_up is None and it % 25 == 0:
            bad = nonfinite_parameter(self.model)
            blow_up = f"parameter {bad} is not finite" if bad else None
        if blow_up:
            self._rollback(blow_up)
            return stats
        if it % self.cfg.eval_every == 0 or self.done():
            scores = self.holdout_psnr()
            blow_up = self.guard.check_holdout(scores) if self.validation_times else None
            blow_up = blow_up or self.guard.check_motion(self.median_motion())
            if blow_up:
                self._rollback(blow_up)
                return stats
            self._auto_budget(scores)
            if self.validation_times and not self.schedule.released:
                self.schedule.observe(it, sum(scores.values()) / len(scores) if scores else None)
                self._after_hold()
            if it - (self._snapshot or {}).get("iteration", -10**9) >= self.cfg.guard.snapshot_every:
                self._take_snapshot()
            record = {"iteration": it, "elapsed_s": round(self.elapsed, 3), "progress": self.progress(),
                      "gaussians": self.model.num_gaussians, "roles": self.counts(),
                      **{f"psnr_{m}": round(v, 3) for m, v in scores.items()},
                      **{k: round(v, 6) for k, v in self._last.items()}}
            self.history.append(record)
            if on_eval:
                on_eval(self, record)
        if it % self.cfg.log_every == 0 or self.done():
            self._print_progress(self._last, 1.0 / (sum(self._window) / len(self._window)))
        # not while a loss is above its limit: the state may be the start of a blow-up
        due = it % self.cfg.checkpoint_every == 0 and not self.guard.suspicious()
        if self.out_dir and (due or self.done()):
            self.save_checkpoint(self.out_dir / "checkpoints" / "latest.pt")
        return stats

    def _print_progress(self, losses: dict, its: float) -> None:
        p = self.progress()
        psnrs = self.history[-1] if self.history else {}
        ps = " ".join(f"{m} {psnrs[f'psnr_{m}']:.2f}" for m in self.cfg.model.modalities if f"psnr_{m}" in psnrs)
        ls = " ".join(f"{k[5:]} {v:.4f}" for k, v in losses.items())
        roles = " ".join(f"{k} {v}" for k, v in self.counts().items())
        if self.progress_fn is not None:      # live: the end depends on the capture
            eta = self.elapsed * (1 - p) / max(p, 1e-9)
        elif self.cfg.minutes:
            eta = max(60 * self.cfg.minutes - self.elapsed, 0)
        else:
            eta = (self.cfg.iterations - self.iteration) / max(its, 1e-9)
        line = (f"\r[{'#' * int(20 * p):<20}] {100 * p:5.1f}% it {self.iteration} | {its:5.1f} it/s | "
                f"loss {ls} | PSNR(held-out) {ps or '-'} | Gaussians {roles} | ETA {int(eta) // 60}:{int(eta) % 60:02d}")
        end = "" if sys.stderr.isatty() else "\n"
        sys.stderr.write(line + end)
        sys.stderr.flush()

    # ------------------------------------------------------------------ divergence
    @torch.no_grad()
    def median_motion(self, sample: int = 4096, times: int = 5) -> float | None:
        """The median over (a sample of) Gaussians of their largest displacement from the canonical
        position over time, in scene extents; None for a static model."""
        stage = self.model.motion_stage()
        n = self.model.num_gaussians
        if (stage is None and self.model.motion is None) or n == 0:
            return None
        idx = torch.randperm(n, generator=torch.Generator().manual_seed(self.iteration))[:sample]
        mu = self.model.gaussians["means"][idx]
        p = self.progress()
        moved = torch.stack([(self.model.means_at(stage, float(t), p, idx) - mu).norm(dim=1)
                             for t in torch.linspace(0, 1, times)])
        return float(moved.max(0).values.median()) / self.extent

    def _take_snapshot(self) -> None:
        """Keep the current (healthy) state in memory to roll back to."""
        self._snapshot = {"iteration": self.iteration, "model": copy.deepcopy(self.model.state_for_checkpoint()),
                          "optimizer": copy.deepcopy(self.optimizer.state_dict())}

    def _rollback(self, reason: str) -> None:
        """Return to the last good state with lower learning rates; fail after max_rollbacks."""
        rollbacks = sum(1 for e in self.events if e.get("rolled_back_to") is not None)
        snap = self._snapshot
        if snap is None or rollbacks >= self.cfg.guard.max_rollbacks:
            event = Event(self.iteration, reason)
            self.events.append(event.as_dict())
            why = "no good state to return to" if snap is None else f"{rollbacks} rollbacks already"
            raise TrainingDiverged(f"training diverged at iteration {self.iteration}: {reason} ({why}); "
                                   f"lower the learning rates (recon/config.py LearningRates) or check the data")
        self.lr_scale *= self.cfg.guard.lr_factor
        event = Event(self.iteration, reason, snap["iteration"], self.lr_scale)
        self.events.append(event.as_dict())
        self.log(f"divergence at iteration {self.iteration}: {reason}; rolled back to iteration "
                 f"{snap['iteration']} with learning rates x{self.lr_scale:g}")
        self.model = DTGModel.from_checkpoint(self.cfg.model, copy.deepcopy(snap["model"]))
        self.optimizer = self._build_optimizer()
        self.optimizer.load_state_dict(copy.deepcopy(snap["optimizer"]))
        self.strategy.stats = type(self.strategy.stats)()
        self.smoothness.load_state({"n": -1, "neighbours": None})
        self.priors.load_state({"n": -1, "neighbours": None})
        self.guard.reset()

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        state = {
            "config": config_to_dict(self.cfg), "model": self.model.state_for_checkpoint(),
            "optimizer": self.optimizer.state_dict(), "iteration": self.iteration, "elapsed": self.elapsed,
            "history": self.history, "generator": self.gen.get_state(), "torch_rng": torch.get_rng_state(),
            "strategy": {"grad": self.strategy.stats.grad, "count": self.strategy.stats.count,
                         "growing": self.strategy.growing},
            "auto": {"best": self.best_holdout, "rounds": self.rounds_without_gain},
            "neighbours": self.smoothness.state(),
            "prior_neighbours": self.priors.state(),
            "schedule": self.schedule.state(), "lr_scale": self.lr_scale, "events": self.events,
            "guard_best": self.guard.best_holdout,
            "extent": self.extent,
        }
        tmp = path.with_suffix(".tmp")
        torch.save(state, tmp)
        if path.exists():   # keep the one before: a file damaged later still leaves a good state
            path.replace(path.with_name(PREVIOUS_CHECKPOINT))
        tmp.replace(path)   # atomic: a crash never leaves a torn checkpoint

    @classmethod
    def resume(cls, path: Path, scene: Scene, out_dir: Path | None = None, log=None,
               **overrides) -> "Trainer":
        state, path = read_checkpoint(path, log or print)
        cfg = config_from_dict(state["config"])
        for k, v in overrides.items():
            setattr(cfg, k, v)
        model = DTGModel.from_checkpoint(cfg.model, state["model"])
        trainer = cls(cfg, scene, out_dir, model=model, log=log)
        trainer.optimizer.load_state_dict(state["optimizer"])
        trainer.iteration, trainer.elapsed = state["iteration"], state["elapsed"]
        trainer.history = state["history"]
        trainer.gen.set_state(state["generator"])
        torch.set_rng_state(state["torch_rng"])
        trainer.strategy.stats.grad = state["strategy"]["grad"]
        trainer.strategy.stats.count = state["strategy"]["count"]
        trainer.strategy.growing = state["strategy"]["growing"]
        trainer.best_holdout, trainer.rounds_without_gain = state["auto"]["best"], state["auto"]["rounds"]
        trainer.smoothness.load_state(state["neighbours"])
        if "prior_neighbours" in state:
            trainer.priors.load_state(state["prior_neighbours"])
        if "schedule" in state:
            trainer.schedule.load_state(state["schedule"])
            trainer.lr_scale, trainer.events = state["lr_scale"], state["events"]
            trainer.guard.best_holdout = state["guard_best"]
            trainer._hold_over = trainer.schedule.released
            if trainer.schedule.released and not cfg.densify.auto_stop:
                trainer.train_times = list(scene.times)
        trainer.extent = state["extent"]
        trainer.strategy.extent = state["extent"]
        return trainer
