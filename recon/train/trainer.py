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

import torch

from recon.alloc import retain_freed_memory
from recon.config import TrainConfig, config_from_dict, config_to_dict
from recon.dtg import routing
from recon.dtg.gaussians import embedding_key, sh_dc_to_value
from recon.dtg.losses import EmbeddingSmoothness, rgb_loss, thermal_loss, trimmed_l1
from recon.dtg.model import DTGModel, check_params, time_rows
from recon.dtg.priors import MotionPriors, body_warmth
from recon.dtg.strategy import Strategy
from recon.render import inference_masks, render
from recon.scene import Scene
from recon.train import timeline
from recon.train.checkpoint import read_checkpoint, write_checkpoint
from recon.train.cores import ThreadShare, sharing_allowed, threads_asked
from recon.train.resolution import downscale, factor_at, random_crop
from recon.train.curriculum import TimeWindow, continue_beyond, frames_at, place_bases
from recon.train.guard import DivergenceGuard, Event, TrainingDiverged, median_motion, nonfinite_parameter
from recon.train.holdout import holdout_psnr, holdout_views
from recon.train.anchors import anchor_loss
from recon.train.paths import on_still_blobs, tracked_paths
from recon.train.initial import body_gaussians, depth_anchors, held_points, initial_model, warm_up_iterations
from recon.train.discover import DiscoverSettings, group_bodies, on_moving_object
from recon.dtg.motion import MotionBases, body_radii
from recon.dtg.strategy import append
from recon.train.optim import build_optimizer, update_learning_rates
from recon.train.progress import progress_line
from recon.train.schedule import Schedule


class Trainer:
    """A run: its model, optimizer, schedule and statistics, and the loop that steps them.

    Each job lives in its own module and Trainer only wires them: the starting model
    (initial.py), learning rates (optim.py), when the run ends (schedule.py), the growing time
    window (curriculum.py), held-out views (holdout.py), divergence and rollback (guard.py),
    checkpoint files (checkpoint.py), growing the time axis live (timeline.py), the progress line
    (progress.py). ``step`` is one iteration; ``tick`` adds evaluation, guard and checkpoint."""

    def __init__(self, cfg: TrainConfig, scene: Scene, out_dir: Path | None = None,
                 model: DTGModel | None = None, log=None):
        self.cfg = cfg
        self.scene = scene
        self.out_dir = Path(out_dir) if out_dir else None
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        missing = [m for m in cfg.model.modalities if not scene.train[m]]
        if missing:
            raise ValueError(f"method {cfg.method} trains {missing} but the dataset has no such training frames")
        torch.set_num_threads(cfg.threads or threads_asked())
        self.cores = ThreadShare(torch.get_num_threads()) if cfg.share_cores and sharing_allowed() else None
        retain_freed_memory()       # a step's large tensors are reused, not page-faulted in again
        torch.manual_seed(cfg.seed)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.extent = scene.extent()
        self.up = scene.up()
        self.held = None          # initial points held out of a static warm-up, for body discovery
        if model is None:
            model, self.held = initial_model(cfg, scene, self.gen, self.log)
        self.model = model
        self.anchors = depth_anchors(cfg, scene)
        if self.anchors is not None:
            static, moving = self.anchors.count()
            self.log(f"depth anchors: {static} of static points and {moving} of moving ones over "
                     f"{len(self.anchors.by_view)} RGB views")
        check_params(cfg.model, dict(self.model.gaussians))
        self.still = self._still_paths()
        self._hold_in_place()
        self.optimizer = build_optimizer(self.cfg, self.model, self.extent)
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
        self.events: list[dict] = []   # divergences, rollbacks and drift warnings, for the log, history and status
        self._drifting = False         # the deformation is beyond the guard's drift limit (_watch_drift)
        self._snapshot: dict | None = None
        self._masks: tuple | None = None   # (route_logits, its version, their inference_masks)
        self._hold_over = False
        self.progress_fn = None    # live training (recon.live.follow) drives the schedule itself
        self.holdout = self._holdout_views()
        # with body discovery the window's clock starts after the static warm-up
        self.warmup = warm_up_iterations(cfg) if self.held is not None else 0
        self.window_start = self.warmup
        self.window = TimeWindow(cfg.curriculum, scene.times, cfg.iterations - self.warmup)
        if self.cfg.stop.converge and not self.validation_times:
            self.schedule.release("no held-out time steps to judge convergence (fewer than "
                                  f"{cfg.stop.validation_every // 2 + 1}): the nominal schedule")

    def uses_validation(self) -> bool:
        """Whether held-out training time steps decide anything (when to stop, how many Gaussians)."""
        return (self.cfg.stop.converge or self.cfg.densify.auto_stop) and self.progress_fn is None

    def _holdout_views(self):
        views, self.validation_times = holdout_views(self.cfg, self.scene, self.uses_validation())
        self.train_times = [t for t in self.scene.times if t not in self.validation_times]
        return views

    def replace_scene(self, scene: Scene) -> None:
        """Continue on a grown scene (live training): same model, optimizer and statistics; new
        frames and time steps. The scene extent, hence step sizes, stays that of the first scene.
        When the time steps grew at least twice as dense, the time embedding is refined to match."""
        self.scene = scene
        self.holdout = self._holdout_views()
        self.still = self._still_paths()
        self.window = TimeWindow(self.cfg.curriculum, scene.times, self.cfg.iterations)
        if self.cfg.model.deformation != "none":
            want = time_rows(self.cfg.model, scene.steps_per_unit_time())[1]
            have = self.model.time_embedding.fine.shape[0]
            factor = (want - 1) // max(have - 1, 1)
            if factor >= 2:
                self.refine_time(factor)
                self.model.n_times = scene.steps_per_unit_time()

    def _still_paths(self) -> list:
        """The still hot or cold things of the thermal frames, when Gaussians on them are held in
        place (ModelConfig.hold_in_place)."""
        if "in_place" not in self.model.gaussians:
            return []
        return tracked_paths(self.scene, self.cfg.paths).still

    @torch.no_grad()
    def _hold_in_place(self) -> None:
        """Flag the Gaussians whose canonical place lies on a still blob, bodies' members apart: no
        network moves them. Run whenever densification changed the Gaussians."""
        g = self.model.gaussians
        if "in_place" not in g:
            return
        flags = on_still_blobs(self.scene, self.still, g["means"])
        if "motion_basis" in g:
            flags &= g["motion_basis"] == 0
        g["in_place"].copy_(flags.float())

    def extend_time(self, factor: int) -> None:
        """The time axis covers a `factor` times longer span (recon/train/timeline.py)."""
        timeline.extend_time(self.model, self.optimizer, factor)

    def refine_time(self, factor: int) -> None:
        """`factor` times more time rows over the same span (recon/train/timeline.py)."""
        timeline.refine_time(self.model, self.optimizer, factor)

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
        whole, target, valid = downscale(view.camera, target, valid, factor_at(self.cfg.resolution, p))
        camera, target, valid = random_crop(whole, target, valid, self.cfg.crop, self.gen)
        mask, reg, stats = None, 0.0, {}
        if noise is not None:
            hard, soft = routing.assignment(self.model.gaussians["route_logits"], self.cfg.routing.tau, noise)
            mask = routing.masks(hard)[modality]
            if regularise:
                kl = routing.kl_to_prior(soft, routing.prior(self.cfg.routing, p))
                reg = reg + self.cfg.routing.kl_weight * kl
                stats["kl"] = float(kl.detach())
        elif self.cfg.model.routing and routing.phase(self.cfg.routing, p) == "frozen":
            mask = self._frozen_masks()[modality]
        background = None
        if modality == "rgb" and float(torch.rand((), generator=self.gen)) < self.cfg.loss.random_background_rgb:
            background = torch.rand(self.model.backgrounds[modality].shape, generator=self.gen)
        frozen = None
        if (self.cfg.curriculum.bodies_only and self.held is None and not self.window.complete
                and self.window.contains(t) and "motion_basis" in self.model.gaussians
                and (not self.cfg.curriculum.bodies_only_hold or not self.window.grown)):
            # while the window grows, the static scene learns from the (trimmed) steps outside it
            # only: at the window's few steps it would paint the moving objects where they are then
            frozen = self.model.gaussians["motion_basis"] == 0
        distortion_weight = self.cfg.loss.distortion if modality in self.cfg.loss.distortion_modalities else 0.0
        among = None
        if distortion_weight > 0 and self.cfg.loss.distortion_among == "static" and "motion_basis" in self.model.gaussians:
            among = (self.model.gaussians["motion_basis"] == 0).float()
        image, out, g = render(self.model, modality, t, camera, p, sh_degree=self.active_sh_degree(modality, p),
                               mask=mask, rgb_geometry=rgb_geometry, background=background, frozen=frozen,
                               distortion=distortion_weight > 0, distortion_moves=self.cfg.loss.distortion_moves,
                               distortion_among=among)
        if distortion_weight > 0:
            d = out.distortion.mean() / self.extent ** 2
            reg = reg + distortion_weight * d
            stats[f"distortion_{modality}"] = float(d.detach())
        if self.held is not None or not self.window.contains(t):
            # before discovery every step, then the steps outside the window: a trimmed loss, so
            # the static scene learns from them while what moves (the worst pixels) is left out
            keep = self.cfg.curriculum.outside_keep
            rec = trimmed_l1(image, target, None, keep) if modality == "rgb" else \
                self.cfg.loss.thermal_l1 * trimmed_l1(image[..., 0], target, valid, keep)
        elif modality == "rgb":
            rec = rgb_loss(image, target, self.cfg.loss.rgb_dssim)
        else:
            rec = self.cfg.loss.thermal_l1 * thermal_loss(image[..., 0], target, valid)
        if regularise:
            reg = reg + self._regularisers(stats)
        reg = reg + self._embedding_smoothness(modality, regularise, stats)
        if modality == "rgb" and self.anchors is not None:
            # a moving point anchors only where its body has been placed: inside the window
            placed = self.held is None and self.window.contains(t)
            weights = {"static": self.cfg.loss.point_depth_static, "moving": self.cfg.loss.point_depth_moving}
            for group, err in anchor_loss(self.anchors, str(view.frame.file_path), camera, out.depth, out.alpha,
                                          moving=placed and weights["moving"] > 0,
                                          tolerance=self.cfg.loss.point_depth_tolerance).items():
                if weights[group] > 0:
                    reg = reg + weights[group] * err
                    stats[f"anchor_{group}"] = float(err.detach())
        gs = self.model.gaussians
        if self.cfg.priors.geometry_gate > 0 and "geometry_logit" in gs \
                and self.model.moves_geometry(self.model.stage_of(modality)):
            gate = torch.sigmoid(gs["geometry_logit"]).mean()
            reg = reg + self.cfg.priors.geometry_gate * gate
            stats["geometry_gate"] = float(gate.detach())
        if self.priors.enabled and self.model.stage_of(modality) == self.model.motion_stage():
            reg = reg + self._motion_priors(g, t, p, stats)
        loss = rec + reg
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.strategy.bound_scales(gs["log_scales"].data)
        if self.model.motion is not None:
            self.model.motion.keep_within(gs["means"].data, gs["log_scales"].data, gs["motion_basis"])
        # a window's loss is a mean over its pixels only: scaled back to a whole frame's, the
        # densification criterion means the same whatever the window
        share = camera.width * camera.height / (whole.width * whole.height)
        self.strategy.accumulate(modality, out.means2d.grad * share, out.radii, whole.width, whole.height)
        stats[f"loss_{modality}"] = float(rec.detach())
        return {"stats": stats, "geometry": {k: v.detach() for k, v in g["geometry_residuals"].items()}}

    def _frozen_masks(self) -> dict[str, torch.Tensor]:
        """inference_masks, recomputed only when the routing logits change: frozen routing gives
        them no gradient, so they change only when densification or a rollback replaces them
        (an argmax and a one-hot over every Gaussian, twice per iteration: ~1.3 ms at 80k)."""
        logits = self.model.gaussians["route_logits"]
        cached = self._masks
        if cached is None or cached[0] is not logits or cached[1] != logits._version:
            cached = self._masks = (logits, logits._version, inference_masks(self.model))
        return cached[2]

    def _embedding_smoothness(self, modality: str, first: bool, stats: dict):
        """The k-NN smoothness of the Gaussian embeddings that this stage's network reads (a shared
        network's: in the first stage only). There its gradient joins the network's before the
        stage's optimizer step, so Adam updates the (N, D) embedding once per iteration, not once
        per stage (~1 ms at 80k Gaussians, D = 32)."""
        stage = self.model.stage_of(modality)
        key = embedding_key(stage)
        if (stage is None or key not in self.model.gaussians or self.cfg.loss.embedding_smoothness <= 0
                or (stage == "shared" and not first)):
            return 0.0
        e = self.smoothness(self.model.gaussians["means"], [self.model.gaussians[key]], self.gen)
        stats[f"embed_{modality}" if stage != "shared" else "embed"] = float(e.detach())
        return self.cfg.loss.embedding_smoothness * e

    def _regularisers(self, stats: dict):
        cfg, model = self.cfg.loss, self.model
        reg = 0.0
        if model.motion is not None and self.cfg.priors.basis_smoothness > 0:
            acc = model.motion.smoothness(self.extent, self.cfg.priors.basis_smoothness_scale)
            reg = reg + self.cfg.priors.basis_smoothness * acc
            stats["basis_acc"] = float(acc.detach())
        if model.motion is not None and self.cfg.priors.path_anchor > 0:
            pull = model.motion.anchor_pull(self.extent)
            reg = reg + self.cfg.priors.path_anchor * pull
            stats["basis_anchor"] = float(pull.detach())
        if model.motion is not None and self.cfg.priors.path_hold > 0:
            hold = model.motion.hold_cost()
            reg = reg + self.cfg.priors.path_hold * hold
            stats["basis_hold"] = float(hold.detach())
        if model.motion is not None and self.cfg.priors.body_temperature > 0 and "features_thermal" in model.gaussians:
            g = model.gaussians
            warmth = body_warmth(sh_dc_to_value(g["features_thermal"][:, 0, 0]), g["motion_basis"],
                                 model.dynamic_gate().detach() > 0.5,
                                 self.cfg.priors.body_band_k / float(self.scene.k_max - self.scene.k_min))
            reg = reg + self.cfg.priors.body_temperature * warmth
            stats["body_warmth"] = float(warmth.detach())
        if model.motion is not None and self.cfg.priors.level_paths > 0:
            climb = model.motion.climb(self.up, self.extent)
            reg = reg + self.cfg.priors.level_paths * climb
            stats["basis_climb"] = float(climb.detach())
        if self.cfg.model.deformation != "none" and cfg.time_smoothness > 0:
            tv = model.time_embedding.temporal_smoothness()
            reg = reg + cfg.time_smoothness * tv
            stats["time"] = float(tv.detach())
        return reg

    def step(self) -> dict:
        """One iteration. Returns its statistics."""
        start = time.perf_counter()
        p = self.progress()
        update_learning_rates(self.optimizer, self.cfg, p, self.iteration, self.expected_iterations(),
                              self.extent, self.lr_scale)
        # the window's clock: iterations, or the share of a --minutes budget when iterations are
        # slow (so the window is whole by `complete_by` of the time, whatever the pace)
        if self.held is not None and self.iteration >= self.warmup:
            self.discover_bodies()
        clock = max(self.iteration, int(p * self.cfg.iterations)) - self.window_start
        taken_in = self.window.update(clock) if self.held is None else []
        if taken_in:            # (all knots start at rest: nothing to carry on before)
            continue_beyond(self.model, *self.window.span())
            if self.cfg.curriculum.search and self.model.motion is not None:
                for side, when in taken_in:
                    place_bases(self.model, frames_at(self.scene, self.cfg.model.modalities, when), when, side,
                                hold_depth=self.cfg.curriculum.hold_depth,
                                up=self.up if self.cfg.curriculum.level else None)
        if self.held is not None:
            t = self.train_times[int(torch.randint(len(self.train_times), (1,), generator=self.gen))]
        else:
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
            self._hold_in_place()
        if self.strategy.reset_opacities(self.model.gaussians, self.optimizer, p):
            stats["opacity_reset"] = 1
            self.guard.reset(holdout=True)     # the loss and held-out error jump by design
        self.elapsed += time.perf_counter() - start
        if self.progress_fn is None:
            self.schedule.advance(self.iteration, self.elapsed)
            self._after_hold()
        return stats

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

    @torch.no_grad()
    def discover_bodies(self) -> None:
        """After the static warm-up: the held-out points on moving objects become rigid bodies at
        the time step where most of them are seen (recon/train/discover.py); the window grows
        from there. The rest of the held-out points are dropped (the static scene has its own)."""
        pts, rgb = self.held
        self.held = None
        settings = DiscoverSettings(max_bodies=self.cfg.model.motion_bases)
        found = group_bodies(pts, on_moving_object(self.model, self.scene, pts, rgb, settings), self.scene.times,
                             settings) if len(pts) else None
        if found is None:
            self.log(f"iteration {self.iteration}: no moving bodies found; the scene is trained static")
            self.cfg.curriculum.grow_every = 0          # no window (a resumed run reads it from the config)
            self.window = TimeWindow(self.cfg.curriculum, self.scene.times)
            return
        index = torch.cat(found.members)
        basis = torch.cat([torch.full((len(mem),), b + 1) for b, mem in enumerate(found.members)])
        rows = body_gaussians(self.cfg, self.scene, pts[index], rgb[index], basis, found.center, self.gen)
        append(self.model.gaussians, self.optimizer, rows)
        pivots = torch.stack([pts[mem].mean(0) for mem in found.members])
        radii = body_radii(pts[index], basis, pivots, self.cfg.model.body_reach)
        self._set_motion(MotionBases(pivots, self.model.n_times, radii))
        self.cfg.curriculum.center = found.center
        self.window_start = self.iteration
        self.window = TimeWindow(self.cfg.curriculum, self.scene.times, self.cfg.iterations - self.iteration)
        self._take_snapshot()            # a rollback must not return to a model without its bodies
        self.log(f"iteration {self.iteration}: {len(found.members)} moving bodies from {len(index)} points "
                 f"({', '.join(str(len(mm)) for mm in found.members)}), seen at t = {found.center:.3f}: "
                 f"motion is learned outwards from there")

    def _set_motion(self, motion: MotionBases) -> None:
        self.model.motion = motion
        params = {"motion_rotation": motion.rotation, "motion_translation": motion.translation}
        for group in self.optimizer.param_groups:
            if group["name"] in params:
                self.optimizer.state.pop(group["params"][0], None)
                group["params"][0] = params[group["name"]]

    # ------------------------------------------------------------------ evaluation
    def holdout_psnr(self) -> dict[str, float]:
        return holdout_psnr(self.model, self.scene, self.holdout)

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
        if self.cfg.curriculum.level or self.cfg.priors.level_paths > 0:
            self.log("moving bodies keep their height along up = (" + ", ".join(f"{v:.2f}" for v in self.up) + ")"
                     if float(self.up.abs().sum()) > 0 else
                     "the cameras do not show which way is up (held on their side?): bodies may change height")

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
        if self.cores is not None and self.cores.update() is not None and self.cores.switches <= 4:
            self.log(f"threads: {self.cores.current} of {self.cores.most} (other processes keep "
                     f"{self.cores.others:.1f} cores busy)" + ("; further changes not logged" if self.cores.switches == 4 else ""))
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
            motion = self.median_motion()
            drop = self.guard.holdout_drop(scores) if self.validation_times else None
            blow_up = blow_up or self.guard.check_motion(motion, drop)
            if blow_up:
                self._rollback(blow_up)
                return stats
            self._watch_drift(motion, drop)
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
        if self.progress_fn is not None:      # live: the end depends on the capture
            eta = self.elapsed * (1 - p) / max(p, 1e-9)
        elif self.cfg.minutes:
            eta = max(60 * self.cfg.minutes - self.elapsed, 0)
        else:
            eta = (self.cfg.iterations - self.iteration) / max(its, 1e-9)
        psnrs = {m: v for m in self.cfg.model.modalities
                 if (v := (self.history[-1] if self.history else {}).get(f"psnr_{m}")) is not None}
        line = progress_line(p, self.iteration, its, losses, psnrs, self.counts(), eta)
        sys.stderr.write("\r" + line + ("" if sys.stderr.isatty() else "\n"))
        sys.stderr.flush()

    # ------------------------------------------------------------------ divergence
    def median_motion(self) -> float | None:
        return median_motion(self.model, self.progress(), self.extent, seed=self.iteration)

    def _watch_drift(self, motion: float | None, drop: float | None) -> None:
        """Log a drift the guard let pass (held-out PSNR holds) once each time it begins."""
        drifting = self.guard.drifting(motion)
        if drifting and not self._drifting:
            reason = self.guard.drift_warning(motion, drop)
            self.events.append(Event(self.iteration, reason, warning=True).as_dict())
            self.log(f"warning at iteration {self.iteration}: {reason}")
        self._drifting = drifting

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
        self.optimizer = build_optimizer(self.cfg, self.model, self.extent)
        self.optimizer.load_state_dict(copy.deepcopy(snap["optimizer"]))
        self.strategy.stats = type(self.strategy.stats)()
        self.smoothness.load_state({"n": -1, "neighbours": None})
        self.priors.load_state({"n": -1, "neighbours": None})
        self.guard.reset()

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self, path: Path) -> None:
        """Everything needed to continue bit-for-bit (recon/train/checkpoint.py writes it)."""
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
            "window_start": self.window_start,
        }
        write_checkpoint(state, path)

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
        warmup = warm_up_iterations(cfg)
        if warmup and trainer.iteration < warmup:          # still in the static warm-up
            trainer.held, trainer.warmup = held_points(cfg, scene), warmup
        trainer.window_start = state.get("window_start", 0)
        trainer.window = TimeWindow(cfg.curriculum, scene.times, cfg.iterations - trainer.window_start)
        trainer.strategy.extent = state["extent"]
        return trainer
