"""Every hyper-parameter of training, in one place (nerfstudio style).

Schedules are written as *fractions of the run* (``progress`` p in [0, 1]) rather than
iteration numbers, so a 3-minute CPU run keeps the shape of the paper's 30k-iteration
schedule (DTG paper 4.1: shared for 1k of 30k iterations, specialise from 10k, freeze at 20k).
``progress`` is iteration / iterations, or elapsed / budget when a wall-clock budget is set.

The baselines and the ablation ladder of the paper's Table 3 are presets of the same code
(``METHODS``): they differ only in which modalities are trained, how deformation is shared,
and whether routing is on.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

MODALITIES = ("rgb", "thermal")
# `recon run`'s wall-clock cap when no --iterations are given; training usually ends earlier, when
# held-out error has converged (StopConfig).
DEFAULT_MINUTES = 15.0
# Routing roles, in the order of the routing logits.
ROLES = ("shared", "rgb", "thermal")


@dataclass
class ModelConfig:
    modalities: tuple[str, ...] = MODALITIES
    # "none": static Gaussians. "shared": one embedding and one network predicting the residuals
    # of every trained modality (E-D3DGS; "+ shared Gaussian"). "progressive": per-modality
    # embeddings and two stages, F_rgb then F_th on the geometry the first produced (DTG).
    deformation: str = "progressive"
    routing: bool = True
    rgb_sh_degree: int = 1          # SH degree of RGB colour (<= 3); the simulator is Lambertian
    thermal_sh_degree: int = 0      # thermal: one channel of normalised temperature (+ optional SH)
    gaussian_embedding_dim: int = 32
    time_embedding_dim: int = 128   # split in half: coarse rows | fine rows (E-D3DGS's two levels)
    time_rows_coarse: int = 0       # 0: about frames/10 (E-D3DGS rule), at least 4
    time_rows_fine: int = 0         # 0: about frames / steps_per_fine_row, at least 16 / it
    # E-D3DGS's fine level: a row per 2 time steps (at least 8 rows). Fewer rows would keep dtg's
    # F_th from flashing a static Gaussian hot while an object passes it in the one training view.
    # At 10 (4 rows over 40 steps): dev family, 3000 it, median thermal MAE 3.84 -> 3.22 K (6 of 8
    # runs better); never-tuned seeds at 3 min inside 3.81 -> 3.70 K, outside 2.17 -> 2.47 K
    # (9 of 16 better; bench/results/time-rows): within run-to-run chaos, so it stays at 2.
    steps_per_fine_row: float = 2.0
    time_rows_fine_start: float = 0.4   # fine rows grow from this fraction of their final count...
    time_c2f_until: float = 0.5         # ...to all rows at this progress (E-D3DGS coarse-to-fine)
    mlp_width: int = 64
    # Which residuals the deformation predicts besides geometry. The paper's F_m predict opacity
    # and features of their modality; E-D3DGS's monocular (HyperNeRF vrig) configs deform
    # geometry only, because with one view per instant colour residuals let a model paint each
    # training view instead of moving Gaussians. Default: opacity residuals for both modalities
    # (they let objects appear and leave), feature residuals for temperature only (it really
    # changes; RGB appearance here does not).
    deform_opacity: tuple[str, ...] = ("rgb", "thermal")
    deform_features: tuple[str, ...] = ("thermal",)
    # Progressive stages that predict geometry residuals. The paper's F_th moves geometry too, but
    # with one thermal view per instant that lets the thermal stage place Gaussians per training
    # view: on the simulator's test rig (dtg, 4000 it) thermal scored 25.0 dB / 3.57 K with it and
    # 31.4 dB / 1.29 K without. So F_th predicts thermal opacity and temperature residuals on the
    # geometry F_rgb produced; ("rgb", "thermal") restores the paper's variant.
    deform_geometry: tuple[str, ...] = ("rgb",)
    # Thermal stage reuses the first stage's residuals detached: thermal loss reaches the shared
    # canonical geometry through F_th but does not reshape F_rgb (paper 3.3).
    thermal_grad_to_rgb_deformation: bool = False
    # Per-Gaussian trajectories: a displacement knot per `trajectory_step` time steps, linearly
    # interpolated, added to the position in every modality's render (both losses train it). A
    # deformation network learns a motion through embeddings and time rows that every Gaussian
    # shares; a knot learns from its own Gaussian's gradient, so a moving object is followed
    # within a few hundred iterations. 0: off.
    trajectory_step: int = 0
    # A learned static/dynamic split: each Gaussian's geometry residuals (deformation and
    # trajectory) are multiplied by a gate sigmoid(dynamic_logit), which PriorConfig.static prices,
    # so the background cannot absorb motion. init_dynamic: the gates' starting logit.
    dynamic_gate: bool = False
    init_dynamic: float = -2.0
    # A static/dynamic split read from the data before training (recon/dtg/points.py): an initial
    # point may move only if what the training views see at it changes over time (RGB by more
    # than split_rgb, or temperature by more than split_kelvin, in more than split_fraction of
    # the views that see it): something moves there. Every other Gaussian keeps its place, so the
    # background cannot absorb motion; children of a densified Gaussian inherit its flag.
    motion_split: bool = False
    split_rgb: float = 0.2           # on 3 family scenes: 70 % of the points on moving objects
    split_kelvin: float = 12.0       # flagged, 20-43 % of the flagged ones on them (0.15/10/0.15:
    split_fraction: float = 0.2      # 84 % / 16 %; 0.25/15/0.25: 50 % / 50 %)
    # Rigid motion bases (recon/dtg/motion.py): up to this many SE(3) trajectories, one per cluster of
    # the initial points the static/dynamic test (split_* below) flags as seeing a changing scene;
    # every other Gaussian is static. 0: off.
    motion_bases: int = 0
    basis_points: int = 30           # a connected cluster of flagged points with fewer than
                                     # max(this / 5, 3) points is not a body (stays static)
    basis_gate_init: float = 3.0     # starting gate logit of a Gaussian in a basis (sigmoid: 0.95)
    # A body member whose own colour the RGB views show in at least basis_static_share of the views
    # that see it looks like the static scene (floor under an object's path: it changes only while
    # the object passes) and starts at gate logit basis_gate_static instead (None: off). At -1:
    # dev family median thermal MAE 3.84 -> 3.45 K (8 runs, bench/results/body-gates); held-out
    # seeds inside 3.81 -> 3.62 K, outside 2.17 -> 2.34 K (bench/results/family-motion2): off
    basis_gate_static: float | None = None
    basis_static_share: float = 0.6
    # With bodies, the geometry residuals of a network (F_th in `dtg`) move only the bodies'
    # Gaussians (times their gate): the static scene keeps one place in every modality (no drift),
    # and the network runs on the bodies and the static Gaussians in view only (-1.4 ms per
    # iteration). Off: thermal MAE worse on 4 of 6 development seeds inside, 5 of 6 outside
    # (bench/results/thermal-geometry-on-bodies/dev; docs/training.md).
    geometry_on_bodies: bool = False
    # A learned gate per Gaussian on the networks' geometry residuals (F_th's in `dtg`):
    # residuals x sigmoid(geometry_logit), the logit starting here (None: off; `dtg`: 2.0) and
    # priced by PriorConfig.geometry_gate, so a Gaussian the thermal loss gives no reason to move (a
    # uniform-temperature floor) closes its gate instead of drifting, while one the loss pulls
    # onto a moving object keeps it open.
    geometry_gate_init: float | None = None
    # The networks' geometry residuals are held at zero (no gradient) until this share of the run,
    # for every Gaussian but the bodies' members: first a network learns how each Gaussian's
    # temperature and opacity change over time, then it may move them. Moving from the start, dtg's
    # F_th explained a hot plate heating 25 -> ~115 C by moving its Gaussians (the std over time of its
    # temperature residuals 0.107 -> 0.011), which the other rig sees misplaced: plate thermal MAE 2.3
    # -> 10.5 K (default scene, 3000 it; with 0.3: 2.3 K). Off: at 0.3 the family's never-tuned seeds
    # lost (holding bodies too: inside moving region 13.5 -> 15.8 K; bodies free, with hold_in_place:
    # outside thermal MAE 1.85 -> 2.17 K, RGB -0.56 dB; docs/training.md "A heating hot plate" and
    # "Telling heating from moving per Gaussian").
    geometry_from: float = 0.0
    # The Gaussians on a still hot or cold blob of the thermal frames (a hot plate heating, a cup
    # cooling: recon/train/paths.py tracks it, and it stays in place) take no network geometry
    # residuals, and their initial points make no body: their temperature change is to be learned as
    # temperature, not as Gaussians moving. Off: alone it left the default scene's plate at 9.96 K
    # on seed 0 (dtg 10.5; 3.13 K on seed 1); with geometry_from 0.3, 2.71 / 3.96 K, but the family
    # failed outside (docs/training.md, "Telling heating from moving per Gaussian").
    hold_in_place: bool = False
    # A network that moves geometry (F_th in `dtg`) runs only on the Gaussians whose place before it
    # lies in the camera's view (or training window) widened by this fraction of the whole view's
    # size on each side; the others get no residual. Exact unless a residual carries a Gaussian
    # from beyond that margin into the render. None: on every Gaussian.
    view_margin: float | None = None
    # A Gaussian whose centre projects more than this x the view's width (height) beyond its edges
    # is not drawn (None: drawn). The projection clamps such a centre's Jacobian to the view's
    # edge but keeps its depth, so one 0.1-0.6 m in front of the camera and metres to its side
    # spreads a footprint of thousands of pixels over the view: on family-outside seed 106 a
    # far-floor Gaussian 19 m long filled a held-out view, on seed 102 dozens made a haze.
    # Held-out seeds, 3 min (docs/training.md "Gaussians far beside the view"): outside the sweep
    # RGB 17.26 -> 18.21 dB median, worst seed 12.38 -> 15.71, better on 7 of 8; inside within
    # +-0.3 dB per seed; 0.5-2 view widths graded alike without retraining.
    cull_off_view: float | None = 1.0
    body_reach: float = 0.0          # a body's Gaussians stay within this x its farthest initial point
                                     # of its pivot (MotionBases.keep_within); 0: unbounded
    # A bias on the deformation's geometry outputs moves every Gaussian alike. Adam moves it by
    # about the learning rate each step whatever its gradient, so on a room-scale scene of the
    # family (bench/family) the whole model drifted by up to 0.8 m in 150 iterations and training
    # never recovered (16 dB RGB); without it 22.5 dB at 600 iterations. Runs written before
    # this setting existed had the bias (and load with it).
    geometry_bias: bool = False
    init_opacity: float = 0.1
    init_embedding_std: float = 0.01    # breaks the symmetry E-D3DGS's zero init relies on time to break

    def __post_init__(self):
        self.modalities = tuple(self.modalities)
        self.deform_opacity = tuple(self.deform_opacity)
        self.deform_features = tuple(self.deform_features)
        self.deform_geometry = tuple(self.deform_geometry)
        bad = [m for m in self.modalities if m not in MODALITIES]
        if bad or not self.modalities:
            raise ValueError(f"modalities must be a non-empty subset of {MODALITIES}, got {self.modalities}")
        if self.deformation not in ("none", "shared", "progressive"):
            raise ValueError(f"deformation must be none|shared|progressive, got {self.deformation!r}")
        if self.routing and (len(self.modalities) < 2 or self.deformation == "none"):
            raise ValueError("routing needs both modalities and a deformation")
        if not 0 <= self.rgb_sh_degree <= 3 or not 0 <= self.thermal_sh_degree <= 3:
            raise ValueError("SH degrees must be in 0..3")


@dataclass
class RoutingConfig:
    all_shared_until: float = 1 / 30      # 1k of 30k iterations
    specialise_from: float = 1 / 3        # 10k of 30k
    freeze_at: float = 2 / 3              # 20k of 30k: routing fixed, densification stops
    prior_before: tuple[float, float, float] = (0.8, 0.1, 0.1)
    prior_start: tuple[float, float, float] = (0.5, 0.3, 0.2)
    prior_end: tuple[float, float, float] = (0.15, 0.7, 0.15)
    tau: float = 1.0
    kl_weight: float = 0.01
    lr: float = 1e-3
    # The paper's 1e-3 moves logits over 30k iterations; a shorter run scales it up by
    # reference / iterations so the logits can travel as far (1e-2 for a 3k-iteration run).
    lr_reference_iterations: int = 30_000


@dataclass
class LossConfig:
    rgb_dssim: float = 0.2           # (1-l) L1 + l (1-SSIM), as 3DGS
    # 2 on the never-tuned seeds: thermal MAE inside 3.16 -> 2.97 K (6 of 8 better, worst seed 4.23 ->
    # 4.81), outside 1.88 -> 1.81 K (3 of 8), moving regions outside 22 -> 31 K: mixed, so 1
    # (bench/results/thermal-weight; docs/training.md "The thermal loss's weight").
    thermal_l1: float = 1.0
    embedding_smoothness: float = 0.05   # E-D3DGS local smoothness of per-Gaussian embeddings
    embedding_knn: int = 8
    embedding_knn_sample: int = 1024     # Gaussians per step that pay the k-NN term
    embedding_knn_falloff: float = 2000.0  # w = exp(-falloff d^2) for a unit-size scene; scaled by extent^2
    time_smoothness: float = 1e-3    # second difference over time-embedding rows (a real one)
    # Composite this fraction of the RGB training renders over a random colour instead of the
    # learned background: a half-transparent surface then costs loss, so surfaces become opaque
    # instead of letting the background through in novel views (+1.7 dB RGB on the simulator's
    # test rig at 2000 it; on thermal the same trick cost 0.7 dB, so temperature keeps its own).
    random_background_rgb: float = 0.5
    # Depth anchors (recon/train/anchors.py): weights of the relative depth error of the RGB render
    # at the initial points each view sees with its own colour, static points and points of moving
    # objects (at the instant they were recorded) each a mean of their own; 0: off. Off because on
    # the held-out seeds (both 0.1) the thermal MAE went either way per seed by up to 1.8 K; outside
    # the sweep RGB rose on 7 of 8 (median +0.9 dB); docs/training.md "Depth anchors".
    point_depth_static: float = 0.0
    point_depth_moving: float = 0.0
    point_depth_tolerance: float = 0.0   # relative depth error that costs nothing
    # Distortion loss (Mip-NeRF 360, 2DGS; recon/splat/rasterization.py): weight of the mean over a
    # render's pixels of sum_{i<j} w_i w_j (z_i - z_j)^2 / extent^2, for the modalities listed. It
    # says that what a ray passes before its surface is empty: large faint Gaussians in free space
    # ("veils", docs/training.md) cost loss where they tint the surfaces behind them. 0: off.
    distortion: float = 0.0
    distortion_modalities: tuple[str, ...] = ("rgb", "thermal")
    # False: the loss may fade a Gaussian, not pull it along the ray (its depth is detached); on the
    # held-out seeds, thermal-only at weight 1 with depth in the gradient drifted on inside seed 101:
    # the deformation put the median Gaussian 0.29 extents from its canonical place (the thermal
    # loss reaches the canonical means), and the run failed after 3 rollbacks.
    distortion_moves: bool = True
    # "static": the pairs among the Gaussians of no moving body (motion_basis 0) only, so a moving
    # object may pass in front of the scene behind it without cost (one more composited channel).
    # At "all" on the development seeds the outside moving hot objects went 26.1 -> 39.4 K (fading
    # form) while the static cup's veils went; at "static" they went 26.1 -> 39.5 K all the same
    # (thermal only, weight 1; docs/training.md "The distortion loss"). "all": every pair.
    distortion_among: str = "all"

    def __post_init__(self):
        if self.distortion_among not in ("all", "static"):
            raise ValueError(f"loss.distortion_among must be 'all' or 'static', got {self.distortion_among!r}")


@dataclass
class PriorConfig:
    """Motion priors (recon/dtg/priors.py); a weight of 0 turns a term off."""
    rigidity: float = 0.0            # local rigidity over canonical k-NN (Luiten et al.: 4)
    isometry: float = 0.0            # neighbour distances kept (Luiten et al.: 2)
    rotation: float = 0.0            # neighbours rotate alike (Luiten et al.: 4)
    smoothness: float = 0.0          # squared acceleration of trajectories over one time step
    sparsity: float = 0.0            # L1 on displacement: the background stays put
    # L1 on the network's geometry residuals only (not the bodies' motion). At 0.1 no run drifts
    # (median displacement 0 against dtg's up to 0.12 E) but held-out thermal MAE rose on 13 of 16
    # runs (bench/results/residual-sparsity): off.
    residual_sparsity: float = 0.0
    # A price on the mean gate of ModelConfig.geometry_gate_init. Adam closes a gate that only the
    # price pulls at ~its rate a step whatever the weight, so the weight sets how strong a pull of the
    # loss keeps a gate open (too strong a weight closes every gate). `dtg`: 1e-4 (1e-3 on the
    # development seeds: thermal MAE 1.20 against 1.04 K median).
    geometry_gate: float = 0.0
    static: float = 0.0              # a price on each Gaussian's dynamic gate (ModelConfig.dynamic_gate)
    anisotropy: float = 0.0          # a price on Gaussians longer than max_aspect x their width
    basis_smoothness: float = 0.0    # squared acceleration of the motion bases, every knot
    # > 0: a knot's acceleration above this (scene extents per knot^2; radians for rotation) costs
    # linearly, not squared (MotionBases.smoothness): an object may start or stop at one knot
    # without the path giving up its depth for it. 0: squared everywhere. At 3e-4, never-tuned
    # seeds 100-103 (3 min, paired): thermal MAE fast 2.04 -> 1.92 K, inside 1.95 -> 1.88, outside
    # 1.52 -> 1.47; over seeds 100-107 fast 2.04 -> 2.18 K and inside's moving region 8.0 -> 9.0 K:
    # off (bench/results/basis-robust; docs/training.md, "A path may stop").
    basis_smoothness_scale: float = 0.0
    # squared vertical speed of the motion bases (MotionBases.climb; up from the cameras,
    # Scene.up): moving things keep their height, as on a table or a floor. With
    # curriculum.level at 1e3: thermal MAE on the development seeds 1.06 -> 0.58 K inside, 2.25 ->
    # 2.09 outside; on the never-tuned seeds inside 2.43 -> 3.06 K (7 of 8 worse), outside 1.93 ->
    # 1.76 K (bench/results/level; docs/training.md, "Moving bodies keep their height"): off.
    level_paths: float = 0.0
    # squared distance of the bodies on tracked paths (curriculum.tracked_paths) from those paths
    # (MotionBases.anchor_pull, in scene extents): training alone slides them along the rays
    # (development seeds: 9 of 17 bodies ended further off). At 100 they stay on their paths, but
    # on the never-tuned seeds thermal MAE went inside 1.91 -> 1.73 K, outside 1.85 -> 1.97 K, RGB
    # outside -0.46 dB (bench/results/path-anchor; docs/training.md, "Holding the bodies on their
    # paths"): off.
    path_anchor: float = 0.0
    # squared Mahalanobis distance of those knots from their paths under each path's own covariance
    # (MotionBases.hold_cost, paths.knot_covariance): a path measured to a few cm is held, one the
    # sweep left loose along the rays is not (path_anchor held both alike). At 0.1 the bodies on good
    # paths stayed on them (outside 42's ball 9.0 -> 1.7 cm at the end), but on the development
    # seeds the moving region's median rose, inside 7.5 -> 10.6 K, outside 16.3 -> 17.7 K (thermal
    # MAE 0.84 -> 0.84, 3.63 -> 3.61 K): it failed its rule before the held-out seeds
    # (bench/results/path-hold; docs/training.md, "Holding each path as firmly as it was measured"): off.
    path_hold: float = 0.0
    # path_hold only on the knots inside a path's rests (paths.rest_px), where the frames showed the
    # object still; elsewhere the bodies are free. Never-tuned fast 116-123: median thermal MAE 0.91
    # -> 0.62 K, but lower on only 3 of the 6 seeds it acts on, moving region +2.4 K; on 119 a false
    # rest moved the ball's path 0.09 -> 0.23 m and thermal MAE 1.3 -> 3.7-4.2 K (twice). It acts on
    # no inside/outside seed 108-115 (bench/results/rest-windows/hold-rests; docs/training.md, "A
    # hold on the rests only"): off.
    path_hold_rests: bool = False
    # weight of priors.body_warmth: a body's members more than body_band_k from their body's median
    # temperature pay for the excess (normalised units), so what a body's shape has too much of turns
    # transparent instead of taking the background's temperature. At 1: development seeds thermal
    # MAE inside 0.85 -> 0.81 K, outside 3.47 -> 3.10 K (moving 17.3 -> 13.4 K); the held-out seeds
    # that made it dtg's default are quoted at DTG_MOTION (bench/results/body-warmth;
    # docs/training.md, "One temperature per body"). Off here: it reads the bodies, which only dtg builds.
    body_temperature: float = 0.0
    body_band_k: float = 10.0
    max_aspect: float = 5.0
    knn: int = 8
    knn_falloff: float = 2000.0      # w = exp(-falloff d^2 / E^2), as the embedding smoothness
    sample: int = 2048               # Gaussians scored per step (rigidity, isometry, sparsity)
    smoothness_sample: int = 512     # of those, Gaussians whose geometry is evaluated at t +- dt


@dataclass
class PathConfig:
    """How recon/train/paths.py finds moving objects' paths in the thermal frames (with
    curriculum.tracked_paths). Chosen on the development seeds 40-43 by the path probe
    (bench/results/tracked-paths/probe_paths.txt), not by training."""
    contrast: tuple[float, ...] = (10.0, 20.0, 40.0)   # kelvin from the frame's median: one set of
                                  # blobs per level (two objects whose blobs touch at one level part at a hotter one)
    min_area: float = 2e-4        # smallest blob, as a fraction of the frame's pixels (4 px at 160x120)
    max_area: float = 0.15        # larger regions are background (sky, a wall in the sun)
    whole: tuple[float, float] = (0.6, 1.6)   # a frame counts where the blob's area is within these
                                  # multiples of the area typical there (not cut, not merged with another):
    # the median of this many of the track's blobs before and after it (0: the track's 25th
    # percentile), and within whole_track x that percentile. An object nearing the camera grows
    # (family-inside 42's ball 122 -> 282 px): against the percentile alone its frames looked merged
    # and it got no path, no body, 71 K off in its training views. Window 3, (0.6, 2.0) from
    # 2026-12-04: held-out seeds at 3 min, thermal MAE inside 1.78 -> 1.65 K (7 of 8), moving region
    # 13.19 -> 9.28 K; outside 2.05 -> 2.01 K, moving 18.24 -> 18.35 K, worst seed 7.64 -> 10.38 K
    # (bench/results/whole-window; docs/training.md).
    whole_window: int = 3
    whole_track: tuple[float, float] = (0.6, 2.0)
    min_frames: int = 12          # whole frames a track needs (fewer: too little parallax to trust)
    # True: frames where the blob is cut by one side of the image (an object entering, or near the
    # frame's edge) count too, as half a frame each, with only the centroid's coordinate along that
    # side; a track then needs min_frames in all and min_whole whole ones (its body's size is read
    # from a whole blob; 4 not tuned). Default from 2026-12-06: held-out seeds at 3 min, thermal
    # MAE inside 1.75 -> 1.52 K, outside 2.07 -> 1.68 K, moving region 9.89 -> 8.96 / 16.23 ->
    # 16.20 K, moving-hot outside 26.7 -> 20.1 K, RGB 25.88 -> 25.88 / 18.39 -> 19.18 dB; lower MAE
    # on 4 and 5 of 8 seeds (bench/results/border-frames; docs/training.md).
    border_frames: bool = True
    min_whole: int = 4
    knots: int = 11
    smoothness: float = 1.0       # weight of the knots' second differences (metres, per knot)
    level: float = 1e4            # weight of the knots' heights along up staying at their mean
    # > 0: pixel errors beyond robust_px (at 160 px wide) count as soft-L1; > 0: a blob continues a
    # track only within link_kelvin of its last blob's median temperature. Tried 2026-12-05, off: on
    # the development path probe robust_px 1 + smoothness 30 cut the paths' median error 0.045 ->
    # 0.034 m, and link_kelvin 3 on top left 5 of 29 paths more than 0.2 m off at their 90th
    # percentile over time (12 before: most followed one object, then another); on held-out
    # seeds (3 min) neither passed its rule: robust + smooth 30 thermal MAE inside 1.60 -> 1.43 K,
    # outside 1.95 -> 1.91 K but moving region outside +0.6 K (allowed 0.5); with link_kelvin 3
    # thermal MAE 1.73 / 1.99 K, though moving-hot outside 28.8 -> 19.5 K
    # (bench/results/path-smooth; docs/training.md).
    robust_px: float = 0.0
    link_kelvin: float = 0.0
    # > 0: spans of at least rest_frames consecutive fitted frames that one still point explains
    # within rest_px (at 160 px wide) may be rests (paths.rest_windows); one is kept where it raises
    # the track's RMS pixel error by at most rest_cost px, and the knots inside it then cost
    # rest_weight x their steps squared (metres): a path that stops stays put instead of sliding
    # along the rays at a pace its smoothness does not charge for. 0: off. On the development path
    # probe (bench/results/rest-windows/): fast seeds 40-49, the paths' median error 0.123 ->
    # 0.024 m; inside and outside 40-49 0.043 -> 0.046 m (inside 40's ball 3.6 -> 5.7 cm). On
    # never-tuned fast 100-107 (3 min) paths 0.115 -> 0.039 m, moving region 25.9 -> 23.0 K, lower
    # thermal MAE on 6 of 8, but the median 1.71 -> 1.73 K failed its rule; with priors.path_hold
    # 0.1, development fast 40-45 0.94 -> 0.65 K (6 of 6), never-tuned 108-115 1.39 -> 1.40 K
    # (lower on 6 of 8, worst seed 5.24 -> 2.87 K): failed its rule too. On fast 116-123 the
    # paths' median error fell 0.083 -> 0.059 m but the 75th percentile rose 0.096 -> 0.153 m:
    # false rests (119's ball still moved along the rays inside a kept span). Off
    # (docs/training.md, "A path that stops stays put").
    rest_px: float = 0.0
    rest_frames: int = 10
    rest_cost: float = 0.1
    rest_weight: float = 1e4
    max_reprojection: float = 2.0     # px (at 160 px wide): a worse fit is not one object's path
    # px (at 160 px wide): the least pixel noise a path's covariance (paths.knot_covariance) assumes;
    # a blob's centroid is not the projection of the object's centre (not chosen by measurement)
    floor_px: float = 0.5
    min_still_error: float = 3.0  # px (at 160 px wide): a still point explains a blob this well or better
    # > 0: still things are found first (paths.still_groups): a 3D point whose projection explains
    # a blob (min_still_error) in at least this share of the thermal instants, so a cup that a ball
    # passes is not fitted as a moving body. 0 (off): still only by the fitted track. 0.3 failed its
    # rule on held-out seeds at 3 min (bench/results/still-first): inside thermal MAE 2.16 -> 1.65 K,
    # moving 13.3 -> 8.9 K; outside 1.98 -> 1.99 K, moving 17.7 -> 18.2 K, RGB 19.14 -> 18.78 dB
    # (allowed -0.3).
    still_share: float = 0.0
    still_area: float = 1.25      # and the blobs' areas lie within this factor of their median
    min_travel: float = 0.05      # and its path's largest distance from its mean, in scene extents


@dataclass
class LearningRates:
    # 3DGS/E-D3DGS values; ``*_scene`` ones are multiplied by the scene extent E.
    means_scene: tuple[float, float] = (1.6e-4, 1.6e-6)   # exponential decay over the run
    # Deformation and time embedding: 10x E-D3DGS's 1.6e-4 E (its Technicolor value; a CPU run has
    # ~1/10 of its iterations), ramped up from 0 over the first 300 iterations. The output layer
    # starts at zero and Adam moves each of its 64 weights by ~lr per step, so early steps with a
    # consistent gradient sign move every Gaussian by ~64 lr E: at 50x (8e-3 E, chosen on the
    # table-top scene) and no ramp, 3 of 50 family runs drifted in their first 25 iterations
    # (median Gaussian moved 0.6-77 E, loss stuck at 0.2, e.g. family-dark-0: RGB 19.4 dB, 8.3 K).
    # dtg, 3000 it, family seeds 0-1 (RGB dB / thermal MAE K / moving-hot MAE K):
    #   8e-3 E:        dark-0 19.4/8.33/57.2  dark-1 25.3/5.08/48.6  inside-0 23.4/2.22/49.9  outside-0 17.8/8.41/63.9
    #   8e-3 E + ramp: dark-0 26.8/5.68/29.9  dark-1 25.1/6.34/45.0  inside-0 23.6/2.27/48.6  outside-0 18.5/10.5/73.9
    #   1.6e-3 E:      dark-0 26.3/3.97/23.0                         inside-0 23.7/2.55/46.6
    #   1.6e-3 E+ramp:                       dark-1 24.3/6.48/39.7                            outside-0 18.3/8.67/66.5
    # and the moving hot objects in the *training* views fit 2-3x better (10-18 K vs 20-51 K).
    deformation_scene: tuple[float, float] = (1.6e-3, 1.6e-4)
    time_embedding: tuple[float, float] = (1.6e-3, 1.6e-4)
    deformation_warmup: int = 300      # iterations of linear ramp from 0 for the two above (<= 10 % of a run)
    trajectory_scene: tuple[float, float] = (1.6e-3, 1.6e-5)   # per-Gaussian trajectory knots
    motion_translation_scene: tuple[float, float] = (1e-3, 1e-4)   # motion bases, x scene extent
    motion_rotation: tuple[float, float] = (5e-3, 5e-4)            # radians (axis-angle)
    dynamic: float = 0.05              # static/dynamic gate logits (as opacity logits)
    rgb_dc: float = 2.5e-3
    rgb_rest: float = 2.5e-3 / 20
    thermal: float = 5e-3
    opacity: float = 0.05
    scales: float = 5e-3
    quats: float = 1e-3
    embedding: float = 2.5e-3
    thermal_background: float = 1e-2


@dataclass
class DensifyConfig:
    every: int = 100                  # iterations
    start: float = 0.03               # progress
    stop: float = 2 / 3               # DTG: densification stops when routing freezes
    grad_threshold: float = 2e-4      # mean NDC-scaled screen-space gradient (3DGS)
    percent_dense: float = 0.01       # clone if max scale <= percent_dense * E, else split
    prune_opacity: float = 0.005
    max_gaussians: int = 0            # a budget: never grow beyond it. 0: 0.5 per pixel of a
                                      # training image, within [5k, 100k] (9.6k at 160x120)
    # Gaussians in motion bases, as a fraction of max_gaussians. 0.1: dev family median thermal MAE
    # 3.84 -> 3.50 K; held-out seeds inside 3.81 -> 3.69 K, outside 2.17 -> 2.33 K
    # (bench/results/moving-budget): not confirmed, stays.
    moving_budget: float = 0.25
    # Every this fraction of the run, while densifying, every opacity above reset_opacity is set
    # to it (3DGS: every 3000 of 30k iterations, to 0.01): Gaussians that only one training view
    # needs (floaters in front of the training rig, seen from any other) must earn their opacity
    # back or be pruned. 0: off. Dev family, dtg, 3000 it, every 0.1 (bench/results/opacity-reset):
    # median thermal MAE 3.84 -> 3.84 K, static region 1.89 -> 2.03 K, worst 8.79 -> 7.63 K: off.
    opacity_reset_every: float = 0.0
    reset_opacity: float = 0.01
    # No Gaussian longer than this many scene extents (largest scale, held after every optimizer
    # step; 0: unbounded). A family run ends with 40-120 Gaussians longer than the whole scene
    # (up to 59 m against E = 1.2 m): needles along a training ray, invisible from the training
    # rig and streaks or a veil from any other (family-outside seed 106, held-out RGB at frame 10:
    # its three longest Gaussians, two of them 23 and 29 m, fill the view; 8.8 dB, 16.1 without them).
    max_scale: float = 0.0
    # 3DGS's world-space pruning: while densifying, remove Gaussians whose largest scale exceeds
    # this many scene extents (3DGS and gsplat: 0.1). 0: off.
    prune_scale: float = 0.0
    auto_stop: bool = False           # stop adding Gaussians when held-out error stops improving
    auto_patience: int = 3            # densification rounds without improvement
    auto_min_gain_db: float = 0.05


@dataclass
class StopConfig:
    """When a run ends (recon/train/schedule.py). ``converge``: the scene chooses the length: the
    schedule holds at ``hold_at`` while held-out PSNR (every 8th training time step, kept out of
    training until then) still gains ``min_gain_db`` within ``patience`` evaluations, then runs
    its remaining (1 - hold_at) * iterations. Off: exactly ``iterations`` (or ``minutes``)."""
    converge: bool = False            # the library default; `recon run` turns it on
    hold_at: float = 1 / 3            # routing specialises and densification winds down after it
    patience: int = 4                 # evaluations (eval_every iterations apart)
    min_gain_db: float = 0.1
    validation_every: int = 8         # every 8th training time step is held out (offset 4)


@dataclass
class GuardConfig:
    """Divergence detection and rollback (recon/train/guard.py)."""
    enabled: bool = True
    # A loss's lower quartile and median over the last `patience` iterations may not both exceed
    # `factor` x those over the `window` before them. Per-view losses are noisy (thermal ones
    # bimodal: a hot object in view or not): on a healthy family run the 50-iteration thermal
    # median moved between 0.016 and 0.025, and 2x over 20 iterations fired falsely (rolled back
    # at iteration 993); with --crop 0.5 the median alone flips between the modes, and the lower
    # quartile alone tripled on a healthy held-out run (guard.rising_quartiles).
    window: int = 200
    factor: float = 3.0
    patience: int = 50
    holdout_drop_db: float = 5.0      # held-out PSNR this far below its best is a collapse
    # The deformation moving the median Gaussian further than this (scene extents, largest over
    # time) is a drift, not a scene: in a family scene ~2/3 of the Gaussians are static (median
    # 0.008-0.016 E), while runs that went wrong early (deformation LR 8e-3 E, no warm-up) had
    # moved it 0.6-77 E with the loss stuck at 0.2 and never recovered.
    max_median_motion: float = 0.25
    # Such a drift is a blow-up only when the held-out time steps also say the model got worse:
    # their PSNR at least drift_drop_db below its best in some modality (without held-out time
    # steps: always). A thermal-only model can slide a uniform-temperature floor without changing a
    # pixel: `ed3dgs-thermal` on family-fast seed 100 (bench/results/body-warmth/dark-fast) was
    # stopped at 0.26-0.31 E while its test view held 31.8-32.4 dB, the level of two reruns that
    # ended at 1.12 K (bench/results/drift-watch); on family-inside seed 103 its drift came with
    # held-out PSNR 3-4 dB below its best, and the run ended at 5.2 K. Beyond
    # max_median_motion_alone a drift is a blow-up whatever held-out error says (the runs that went
    # wrong early had moved it 0.6-77 E). A drift that is not a blow-up is logged as a warning.
    drift_drop_db: float = 1.0
    max_median_motion_alone: float = 0.5
    snapshot_every: int = 250         # the last good state is kept (in memory) this often
    lr_factor: float = 0.5            # every learning rate after a rollback
    max_rollbacks: int = 3            # then the run stops with an error


@dataclass
class CurriculumConfig:
    """A training window that grows in time from ``center`` (recon/train/curriculum.py). 0: off."""
    grow_every: int = 0               # iterations per time step the window grows on each side
    center: float = -1.0              # where it starts (fraction of the sequence); < 0: where the
                                      # moving initial points match the views best (recon/dtg/points.py)
    start_steps: int = 1              # half-width it starts with, in time steps...
    hold: int = 0                     # ...for this many iterations (at most 10 % of a run)
    complete_by: float = 0.4          # a short run grows faster: whole by this fraction of it
    edge_weight: float = 0.5          # probability of training on one of the window's new edges
    search: bool = False              # search where each motion basis is at a new step
    bodies_only: bool = False         # steps inside the growing window train the bodies only
    bodies_only_hold: bool = False    # bodies_only only until the window first grows
    # Bodies found after a static warm-up of this many iterations (at most 15 % of a run;
    # recon/train/discover.py) instead of from the initial points alone. 0: from the points.
    discover_after: int = 0
    # A step taken in keeps each body at the previous step's depth from the new view (its image
    # position from constant velocity): the one direction a view cannot pin is not extrapolated.
    # Off: on the never-tuned seeds thermal MAE fell (inside 3.90 -> 3.62 K, outside 2.24 -> 2.03)
    # but the moving region inside rose 33.7 -> 41.1 K and RGB outside fell 1.3 dB
    # (bench/results/hold-depth; docs/training.md, "Holding depth at intake").
    hold_depth: bool = False
    # A step taken in keeps each body at the previous step's height (along the new view's ray
    # through its constant-velocity guess) and the image-plane search moves it at that height:
    # the direction one view cannot pin is set by the height, as PriorConfig.level_paths holds it
    # (measured together there: off).
    level: bool = False
    # Bodies on the paths of the hot and cold objects the thermal frames track and triangulate
    # (recon/train/paths.py), built at the start, with every time step trained from the start,
    # instead of from the changing initial points with a growing window (dtg: on).
    tracked_paths: bool = False
    outside: float = 0.0              # probability of a time step outside the window, with a loss
    outside_keep: float = 0.9         # over the best-fitting fraction of its pixels only


@dataclass
class TrainConfig:
    method: str = "dtg"
    model: ModelConfig = field(default_factory=ModelConfig)
    routing: RoutingConfig = field(default_factory=RoutingConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    priors: PriorConfig = field(default_factory=PriorConfig)
    lr: LearningRates = field(default_factory=LearningRates)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    stop: StopConfig = field(default_factory=StopConfig)
    guard: GuardConfig = field(default_factory=GuardConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    paths: PathConfig = field(default_factory=PathConfig)
    iterations: int = 3000            # the schedule's nominal length
    minutes: float | None = None      # wall-clock budget (progress = elapsed / budget), or with
                                      # stop.converge the cap
    sh_increase_every: float = 0.1    # raise the active RGB SH degree every 10 % of the run
    seed: int = 0
    checkpoint_every: int = 500
    log_every: int = 25
    eval_every: int = 250             # held-out PSNR for the progress bar and the auto budget
    max_points: int = 20_000          # initial points kept (random subset of points3d.ply)
    # Each stage trains on a random window of its view with sides this fraction of the view's
    # (recon/train/resolution.py); 1: whole frames. For native resolution: see docs/training.md.
    crop: float = 1.0
    # ((from progress p, downscale factor), ...): training views are averaged over factor x
    # factor blocks from p on (coarse to fine; resolution.coarse_to_fine builds one). Full size: 1.
    resolution: tuple = ((0.0, 1),)
    threads: int = 0                  # 0: torch's default
    # Train on one thread while other processes keep more than 0.4 of a core busy, on `threads`
    # again below 0.2 (recon/train/cores.py): on 2 cores with one taken, a 160x120 step took 29 ms
    # on one thread against 44 on two (bench/results/wait-policy/). Results then depend on the
    # machine's load (torch's sums depend on the thread count); RECON_FIXED_THREADS=1 turns it off.
    share_cores: bool = True


def _preset(**model) -> dict:
    return {"model": model}


# What dtg adds to the paper's E-D3DGS deformation: moving things move as rigid bodies
# (recon/dtg/motion.py), learned outwards in time from the instant the initial points saw them
# (recon/train/curriculum.py). The deformation networks keep what they are good at: F_th the change of
# temperature (and thermal opacity) over time; geometry is the bases' alone, so F_rgb has nothing
# left to predict. Chosen on family seeds 0-2 and 19 (never on the benchmark seeds 100-107), 3000
# iterations, dtg with the E-D3DGS deformation ("dtg-mlp") -> this, median over inside-0/1/2,
# dark-0/1, fast-0 (bench results in docs/training.md): RGB 23.5 -> 24.2 dB, thermal 20.7 ->
# 21.7 dB, thermal MAE 3.52 -> 3.17 K, moving-object MAE 29.5 -> 25.6 K, and in the *training*
# views' moving objects 11.5 -> 9.4 K (seed 19: 19.3 -> 5.5 K).
#
# F_th also moves geometry, for the thermal render only (the paper's F_th, here on top of the
# bodies; the RGB render never sees it): a body that lost its object, or an object with no body,
# is then still followed in the thermal frames, as ed3dgs-thermal follows it. Family-inside, new
# development seeds 40-45, 3 min a run, median (worst) thermal MAE 1.33 (3.42) -> 1.08 (3.31) K,
# moving region 16.8 -> 9.9 K, RGB 25.30 -> 25.25 dB. A step costs +21 % (bench/train_step.py at
# 160x120: F_th runs on every Gaussian, not only on those in view). On the held-out seeds a second
# run of the same method moved by as much as the gain (docs/training.md): a gain within run-to-run
# chaos inside the sweep, never a loss of more than 0.52 K on a seed.
DTG_MOTION = {
    # F_th's geometry residuals pass a priced gate per Gaussian (geometry_gate_init, priors'
    # geometry_gate): the median Gaussian's end displacement fell from up to 0.19 scene extents (the
    # guard stops at 0.25) to at most 0.01 on 16 held-out runs; thermal MAE inside 3.09 -> 3.22 K
    # (better on 5 of 8), outside 1.90 -> 1.82 K (4 of 8), worst seed 4.76 -> 4.01 and 15.03 -> 14.68 K
    # (bench/results/geometry-gate; docs/training.md).
    # view_margin: F_th runs on the Gaussians near the view or window, not on every one:
    # bench/train_step.py 640x480/90k with windows 135.5 -> 85.4 and 164.5 -> 85.1 ms per
    # iteration (bench/results/train_step-view-margin; 160x120 within noise); never-tuned seeds
    # 100-107 at 3 min, 160x120: 45.7 -> 42.0 ms/it inside, 48.0 -> 44.8 outside, thermal MAE 3.22
    # -> 3.09 K and 1.97 -> 2.00 K, RGB +0.2 / +0.9 dB (bench/results/view-margin; docs/training.md).
    "model": {"motion_bases": 32, "deform_geometry": ("thermal",), "deform_opacity": ("thermal",),
              "geometry_gate_init": 2.0, "view_margin": 0.1},
    # hold: the static scene and the objects' shapes first settle on 7 time steps; grow_every: a
    # new step every 40 iterations on each side (one step = a fraction of a moving object's size);
    # search: where each body is at a new step (constant velocity missed the ball on seed 19 from
    # t < 0.3: 22-33 K; with the search 1.4-8 K at every time step); outside: 30 % of iterations
    # on the steps beyond the window with a trimmed loss, so the static scene learns from every
    # view from the start (inside-0 static-region MAE 1.67 -> 1.09 K; dtg-mlp 0.82 K).
    # tracked_paths: the bodies are built on the paths the thermal frames triangulate
    # (recon/train/paths.py) and the window above is whole from the start; where no path is found
    # the window, search and outside steps above train point bodies as before. Never-tuned seeds
    # 100-107, 3 min a run, against dtg in the same session: thermal MAE inside 3.25 -> 1.89 K,
    # outside 2.02 -> 1.93 K (better on 7 of 8 seeds in each), moving region 28.6 -> 12.5 K and
    # 26.4 -> 18.4 K, RGB +0.66 / -0.24 dB (bench/results/tracked-paths; docs/training.md).
    "curriculum": {"grow_every": 40, "hold": 400, "start_steps": 3, "search": True, "outside": 0.3,
                   "tracked_paths": True},
    # body_temperature: a body's members far colder or hotter than their body turn transparent
    # instead of taking the background's temperature (PriorConfig.body_temperature). Never-tuned
    # seeds 100-107, 3 min, paired: thermal MAE inside 1.49 -> 1.33 K, outside 1.60 -> 1.54 K
    # (lower on 5 and 6 of 8), moving-hot 11.8 -> 10.4 K and 20.9 -> 17.3 K, RGB -0.02 / -0.22 dB
    # (bench/results/body-warmth; docs/training.md, "One temperature per body").
    "priors": {"basis_smoothness": 1e4, "geometry_gate": 1e-4, "body_temperature": 1.0},
    "lr": {"motion_rotation": (1e-3, 1e-4)},    # at 5e-3 rotation about a pivot slid bodies off
}


def _with(preset: dict, extra: dict) -> dict:
    out = {k: dict(v) for k, v in preset.items()}
    for key, values in extra.items():
        out[key] = {**out.get(key, {}), **values}
    return out


_DTG_MLP = _preset(modalities=MODALITIES, deformation="progressive", routing=True)
METHODS: dict[str, dict] = {
    "ed3dgs-rgb": _preset(modalities=("rgb",), deformation="shared", routing=False),
    "ed3dgs-thermal": _preset(modalities=("thermal",), deformation="shared", routing=False),
    "static-rgbt": _preset(modalities=MODALITIES, deformation="none", routing=False),
    "dtg-shared": _preset(modalities=MODALITIES, deformation="shared", routing=False),
    "dtg-embed": _preset(modalities=MODALITIES, deformation="progressive", routing=False),
    "dtg-mlp": _DTG_MLP,                  # the paper's dtg: geometry moved by F_rgb (E-D3DGS)
    "dtg": _with(_DTG_MLP, DTG_MOTION),
}
_SECTIONS = {"model": ModelConfig, "curriculum": CurriculumConfig, "priors": PriorConfig, "lr": LearningRates}


def make_config(method: str = "dtg", **overrides) -> TrainConfig:
    """The TrainConfig of a method preset, with top-level field overrides."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    preset = METHODS[method]
    cfg = TrainConfig(method=method, **{key: cls(**preset[key]) for key, cls in _SECTIONS.items() if key in preset})
    return dataclasses.replace(cfg, **overrides) if overrides else cfg


def config_to_dict(cfg: TrainConfig) -> dict:
    return dataclasses.asdict(cfg)


# Defaults that changed since runs were first written: a config without the key meant this.
_PAST_DEFAULTS = {"model": {"deform_geometry": ("rgb", "thermal"), "geometry_bias": True},
                  "paths": {"whole_window": 0, "whole_track": (0.6, 1.6)},
                  "priors": dict.fromkeys(("rigidity", "isometry", "rotation", "smoothness", "sparsity",
                                           "static", "anisotropy"), 0.0)}


def config_from_dict(d: dict) -> TrainConfig:
    d = dict(d)
    for key, past in _PAST_DEFAULTS.items():
        d[key] = {**past, **d.get(key, {})}
    sub = {"model": ModelConfig, "routing": RoutingConfig, "loss": LossConfig, "priors": PriorConfig,
           "lr": LearningRates, "densify": DensifyConfig, "stop": StopConfig, "guard": GuardConfig,
           "curriculum": CurriculumConfig, "paths": PathConfig}
    for key, cls in sub.items():
        fields = {f.name for f in dataclasses.fields(cls)}
        d[key] = cls(**{k: _tuples(v) for k, v in d.get(key, {}).items() if k in fields})
    return TrainConfig(**{k: v if k in sub else _tuples(v) for k, v in d.items()})


def _tuples(value):
    """JSON lists back to the tuples the configs hold (nested: TrainConfig.resolution)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value
