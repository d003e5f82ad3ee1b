"""DTG training on a tiny simulated scene (48x36, 6 time steps, ~100 iterations)."""
import math

import pytest
import torch

from recon.dtg import routing
from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer


def tiny(tmp_path_factory, variant="default", seed=3):
    out = tmp_path_factory.mktemp(f"tiny_{variant}_{seed}")
    simulate_dataset(out, SimulateConfig(variant=variant, frames=6, width=48, height=36, seed=seed, points=600))
    return Scene(load_dataset(out))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return tiny(tmp_path_factory)


def small_cfg(method="dtg", **kw):
    cfg = make_config(method, iterations=kw.pop("iterations", 100), eval_every=50, log_every=1000,
                      checkpoint_every=10_000, **kw)
    cfg.densify.every = 20
    cfg.loss.embedding_knn_sample = 256
    return cfg


def test_dtg_loss_falls_and_heldout_psnr_rises(scene, tmp_path_factory):
    """On three seeds of the tiny scene, 240 iterations each. Measured (seeds 3-10, fixed threads):
    the last 10 iterations' loss 0.42-0.59 x the first 10's, held-out RGB +1.39-2.64 dB, thermal
    +6.8-10.9 dB. At 120 iterations on one seed the RGB gain (+1.19-2.00 dB over those seeds) sat at
    its margin, and an OpenCV release's other pixels turned seed 3's +1.48 into +1.07 dB."""
    gains = []
    for seed in (3, 4, 5):
        tr = Trainer(small_cfg(iterations=240), scene if seed == 3 else tiny(tmp_path_factory, seed=seed),
                     log=lambda _: None)
        before = tr.holdout_psnr()
        steps = []
        while not tr.done():
            steps.append(tr.step())
        after = tr.holdout_psnr()
        # means over 10 iterations: one iteration's loss depends on the view it drew
        early, late = (sum(s["loss_rgb"] + s["loss_thermal"] for s in part) / len(part)
                       for part in (steps[:10], steps[-10:]))
        assert late < 0.75 * early, (seed, early, late)
        assert after["thermal"] > before["thermal"] + 4.0, (seed, before, after)
        gains.append(after["rgb"] - before["rgb"])
    assert min(gains) > 0.5 and sorted(gains)[1] > 1.25, gains


def test_distortion_loss_gathers_each_ray_s_weight_in_depth(scene):
    """The same 150 iterations with the distortion loss at 1 and off: the weight spread in depth
    along the training views' rays (what the loss charges) falls for both modalities. Measured:
    RGB 0.188 -> 0.005, thermal 0.113 -> 0.007 (sums over every third view). Among the static
    Gaussians only (the tiny scene has one moving body, ~900 of ~5500 Gaussians), the static pairs'
    spread falls as well: measured RGB 0.183 -> 0.004, thermal 0.106 -> 0.003 (the body's own pairs
    are too few here for the mask to tell: tests/test_splat_distortion.py checks it)."""
    from recon.render import inference_masks, render

    def spread(weight: float, among: str = "all") -> dict[str, float]:
        cfg = small_cfg(iterations=150)
        cfg.loss.distortion = weight
        cfg.loss.distortion_among = among
        tr = Trainer(cfg, scene, log=lambda _: None)
        while not tr.done():
            tr.step()
        masks = inference_masks(tr.model)
        static = (tr.model.gaussians["motion_basis"] == 0).float()
        assert 0 < static.sum() < tr.model.num_gaussians, "the tiny scene must have a moving body"
        out = {}
        for modality in ("rgb", "thermal"):
            views = scene.train[modality][::3]
            with torch.no_grad():
                for key, s in (("all", None), ("static", static)):
                    out[modality, key] = sum(float(render(tr.model, modality, v.time, v.camera, mask=masks[modality],
                                                          distortion=True, distortion_among=s)[1].distortion.mean())
                                             for v in views)
        return out

    off, on, static = spread(0.0), spread(1.0), spread(1.0, "static")
    for modality in ("rgb", "thermal"):
        assert on[modality, "all"] < 0.3 * off[modality, "all"], (modality, off, on)
        assert static[modality, "static"] < 0.3 * off[modality, "static"], (modality, off, static)


def test_routing_stays_shared_until_the_schedule_allows(scene):
    cfg = small_cfg(iterations=90)
    tr = Trainer(cfg, scene, log=lambda _: None)
    logits0 = tr.model.gaussians["route_logits"].detach().clone()
    while tr.progress() < cfg.routing.all_shared_until:
        tr.step()
        assert torch.equal(tr.model.gaussians["route_logits"].detach(), logits0[: tr.model.num_gaussians]) \
            or tr.model.num_gaussians != logits0.shape[0]
    assert routing.role_counts(tr.model.gaussians["route_logits"].detach())["shared"] == tr.model.num_gaussians
    while tr.progress() < cfg.routing.freeze_at:
        tr.step()
    frozen = tr.model.gaussians["route_logits"].detach().clone()
    while not tr.done():
        tr.step()
    assert torch.equal(tr.model.gaussians["route_logits"].detach(), frozen)   # no change once frozen


def test_frozen_routing_masks_are_recomputed_when_the_logits_change(scene):
    """Once routing is frozen the trainer reuses its inference masks between iterations: they must
    still equal fresh ones after the logits are changed in place or replaced (densification, a
    rollback), and before that stay the same tensors."""
    from recon.render import inference_masks
    tr = Trainer(small_cfg(iterations=90), scene, log=lambda _: None)
    tr.progress_fn = lambda _: 0.99
    assert routing.phase(tr.cfg.routing, tr.progress()) == "frozen"
    tr.step()
    first = tr._frozen_masks()
    tr.step()
    assert tr._frozen_masks() is first
    def same(a, b):
        return all(torch.equal(a[m], b[m]) for m in a)
    assert same(first, inference_masks(tr.model))
    logits = tr.model.gaussians["route_logits"]
    with torch.no_grad():
        logits[: logits.shape[0] // 2] = logits[: logits.shape[0] // 2].flip(1)   # roles swap in place
    assert not same(first, inference_masks(tr.model))
    flipped = tr._frozen_masks()
    assert same(flipped, inference_masks(tr.model))
    tr.model.gaussians["route_logits"] = torch.nn.Parameter(logits.detach().roll(1, 1))   # replaced
    assert not same(flipped, inference_masks(tr.model))
    assert same(tr._frozen_masks(), inference_masks(tr.model))


def test_every_per_gaussian_tensor_stays_aligned_after_densify(scene):
    tr = Trainer(small_cfg(iterations=60), scene, log=lambda _: None)
    start = tr.model.num_gaussians
    while not tr.done():
        tr.step()
    n = tr.model.num_gaussians
    assert n != start          # densification and pruning happened
    for name, p in tr.model.gaussians.items():
        assert p.shape[0] == n, name
        st = tr.optimizer.state.get(p)
        if st:
            assert st["exp_avg"].shape == p.shape, name


def test_scale_bound_holds_through_training(scene):
    probe = Trainer(small_cfg(iterations=10), scene, log=lambda _: None)
    largest = probe.model.gaussians["log_scales"].detach().max(1).values.exp()
    cfg = small_cfg(iterations=30)
    cfg.densify.max_scale = float(largest.median()) / scene.extent()    # half start above it
    tr = Trainer(cfg, scene, log=lambda _: None)
    bound = math.log(cfg.densify.max_scale * scene.extent())
    while not tr.done():
        tr.step()
        assert float(tr.model.gaussians["log_scales"].detach().max()) <= bound + 1e-6


def test_resume_continues_bit_for_bit(scene, tmp_path):
    """Same generators, optimizer moments and k-NN graph after resume, and every kernel sums in a
    fixed order whatever the threads (the rasterizer's backward, index_select for neighbour rows):
    on the appliance's 2 threads, with the neighbour priors on, the resumed run is bit-for-bit the
    uninterrupted one. Before, this held on one thread only."""
    threads = torch.get_num_threads()
    cfg = small_cfg(iterations=60, threads=2)
    cfg.priors.rigidity = cfg.priors.isometry = cfg.priors.rotation = 1.0
    a = Trainer(cfg, scene, tmp_path, log=lambda _: None)
    for _ in range(30):
        a.step()
    a.save_checkpoint(tmp_path / "ck.pt")
    for _ in range(30):
        a.step()
    b = Trainer.resume(tmp_path / "ck.pt", scene, tmp_path, log=lambda _: None)
    assert b.iteration == 30
    for _ in range(30):
        b.step()
    torch.set_num_threads(threads)
    for k, p in a.model.gaussians.items():
        assert torch.equal(p, b.model.gaussians[k]), k


def test_checkpoint_from_before_deform_geometry_still_loads(scene, tmp_path):
    """Runs written before ModelConfig.deform_geometry existed moved geometry in both stages; their
    config lacks the key and must load as that, not as today's default."""
    cfg = small_cfg(iterations=10)
    cfg.model.deform_geometry = ("rgb", "thermal")
    a = Trainer(cfg, scene, log=lambda _: None)
    for _ in range(3):
        a.step()
    a.save_checkpoint(tmp_path / "old.pt")
    state = torch.load(tmp_path / "old.pt", weights_only=False)
    del state["config"]["model"]["deform_geometry"]
    torch.save(state, tmp_path / "old.pt")
    b = Trainer.resume(tmp_path / "old.pt", scene, log=lambda _: None)
    assert b.cfg.model.deform_geometry == ("rgb", "thermal")
    from recon.render import render_frame
    cam = scene.test["thermal"][0].camera
    assert torch.equal(render_frame(a.model, "thermal", 0.5, cam), render_frame(b.model, "thermal", 0.5, cam))


@pytest.mark.parametrize("method", ["ed3dgs-rgb", "ed3dgs-thermal", "static-rgbt", "dtg-shared", "dtg-embed"])
def test_every_method_trains(scene, method):
    tr = Trainer(small_cfg(method, iterations=25), scene, log=lambda _: None)
    while not tr.done():
        tr.step()
    scores = tr.holdout_psnr()
    assert set(scores) == set(tr.cfg.model.modalities)
    assert all(math.isfinite(v) for v in scores.values())


@pytest.mark.parametrize("variant", ["dark", "fast", "occlusion", "flat-thermal", "rapid"])
def test_no_nan_on_any_variant(tmp_path_factory, variant):
    sc = tiny(tmp_path_factory, variant)
    tr = Trainer(small_cfg(iterations=40), sc, log=lambda _: None)
    while not tr.done():
        tr.step()
    for k, p in tr.model.gaussians.items():
        assert torch.isfinite(p).all(), k
