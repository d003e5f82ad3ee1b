"""Moving bodies found after a static warm-up (recon/train/discover.py) are on the moving objects:
graded against the simulator's objects, and against the bodies the initial points alone give."""
import numpy as np
import pytest
import torch

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.scene import Scene
from recon.train.trainer import Trainer
from rig.sim.family import FamilyScene


pytestmark = pytest.mark.usefixtures("two_threads")

SEED = 1
SEEDS = (1, 2, 3, 4)


def family(tmp_path_factory, seed: int) -> Scene:
    out = tmp_path_factory.mktemp(f"family{seed}")
    simulate_dataset(out, SimulateConfig(variant="family-inside", frames=20, width=96, height=72, seed=seed,
                                         points=2000))
    return Scene(load_dataset(out))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return family(tmp_path_factory, SEED)


def on_objects(points: torch.Tensor, seed: int = SEED) -> np.ndarray:
    """(M,) whether each point lies on a moving object of the family-inside scene `seed` at one of
    the instants the simulator recorded points at (recon/data/simulate.py: 8)."""
    fam = FamilyScene.build("inside", seed)
    p, hit = points.numpy(), np.zeros(len(points), bool)
    for o in (o for o in fam.objects if o.moving):
        for t in np.linspace(0, fam.duration_s, 8):
            inst = o.instance(t, fam.duration_s)
            hit |= o.shape.contains((p - inst.position) @ inst.rotation, 0.012)
    return hit


def body_points(trainer: Trainer) -> torch.Tensor:
    g = trainer.model.gaussians
    return g["means"].detach()[g["motion_basis"] > 0]


def discovering(scene: Scene, log=lambda _: None) -> Trainer:
    """A dtg run that finds its bodies after a 120-iteration static warm-up, at the end of it."""
    cfg = make_config("dtg", iterations=1000, log_every=10**9, checkpoint_every=10**9, eval_every=10**9)
    cfg.curriculum.discover_after = 120
    tr = Trainer(cfg, scene, log=log)
    assert tr.held is not None and tr.model.motion.count == 0
    while tr.iteration < tr.warmup:
        tr.step()
    assert tr.warmup == 120 and tr.held is not None
    return tr


def test_discovery_builds_bodies_and_training_goes_on(scene):
    messages = []
    tr = discovering(scene, messages.append)
    start = tr.model.num_gaussians
    tr.discover_bodies()                # what the next step would do first
    assert tr.held is None and tr.model.motion.count >= 1, messages
    assert tr.model.num_gaussians == start + len(body_points(tr))
    assert any("moving bodies from" in m for m in messages)
    # the bodies are built where the window starts, and training goes on
    assert tr.cfg.curriculum.center in scene.times
    for _ in range(20):
        tr.step()
    assert all(torch.isfinite(v).all() for v in tr.model.gaussians.values())


def test_bodies_found_after_a_static_warm_up_are_on_the_moving_objects(scene, tmp_path_factory):
    """Pooled over four seeds, against the bodies the initial points alone give (paths off): one
    seed's few discovered points flip with last-bit changes of its input (an OpenCV release's
    other pixels turned seed 1's 3 of 6 into 0 of 6)."""
    hits = points = base_hits = base_points = with_bodies = 0
    for seed in SEEDS:
        s = scene if seed == SEED else family(tmp_path_factory, seed)
        tr = discovering(s)
        tr.discover_bodies()
        on = on_objects(body_points(tr), seed)
        hits, points, with_bodies = hits + on.sum(), points + len(on), with_bodies + (tr.model.motion.count > 0)
        cfg = make_config("dtg", iterations=1000, log_every=10**9)
        cfg.curriculum.tracked_paths = False
        base = on_objects(body_points(Trainer(cfg, s, log=lambda _: None)), seed)
        base_hits, base_points = base_hits + base.sum(), base_points + len(base)
    # measured (2 threads, deterministic): 26 of 30 discovered points on the moving objects, bodies
    # found on seeds 1 and 3 (none on 2 and 4: nothing stood out of the static warm-up); 20 of 214
    # of the points-only bodies' points (seeds 5-8, not tested: 25 of 34 against 23 of 228). On an
    # AVX-512 host (2026-12-07) 30 of 51 against the same 20 of 214: the bar is a majority
    assert with_bodies >= 2, with_bodies
    assert hits / points > 0.5 and hits / points > base_hits / base_points + 0.3, (hits, points, base_hits, base_points)


@pytest.mark.parametrize("stop_at", [20, 45])      # in the warm-up, and after discovery (at 30)
def test_a_run_with_discovery_resumes_bit_for_bit(scene, tmp_path, stop_at):
    cfg = make_config("dtg", iterations=200, log_every=10**9, checkpoint_every=10**9, eval_every=10**9, threads=1)
    cfg.curriculum.discover_after = 30
    a = Trainer(cfg, scene, tmp_path, log=lambda _: None)
    while a.iteration < stop_at:
        a.step()
    a.save_checkpoint(tmp_path / "ck.pt")
    while a.iteration < 60:
        a.step()
    b = Trainer.resume(tmp_path / "ck.pt", scene, tmp_path, log=lambda _: None)
    assert (b.held is not None) == (stop_at < 30) and b.window_start == 30
    while b.iteration < 60:
        b.step()
    torch.set_num_threads(2)
    assert a.model.motion.count == b.model.motion.count >= 1
    for k, p in a.model.gaussians.items():
        assert torch.equal(p, b.model.gaussians[k]), k
    assert torch.equal(a.model.motion.translation, b.model.motion.translation)


def test_a_body_keeps_within_its_reach():
    """MotionBases.keep_within: a body's Gaussians are pulled back onto the sphere of its radius
    about its pivot and their scales capped at half of it; static Gaussians and unbounded bodies
    (radius 0, runs written before) are left alone."""
    from recon.dtg.motion import MotionBases, body_radii
    pivots = torch.tensor([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    points = torch.tensor([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [5.3, 0.0, 0.0], [9.0, 9.0, 9.0]])
    basis = torch.tensor([1.0, 1.0, 2.0, 0.0])
    radii = body_radii(points, basis, pivots, 1.5)
    assert torch.allclose(radii, torch.tensor([0.3, 0.45]))
    bases = MotionBases(pivots, 4, radii)
    means = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.1, 0.0], [5.0, 3.0, 0.0], [20.0, 0.0, 0.0]])
    log_scales = torch.zeros(4, 3)
    bases.keep_within(means, log_scales, basis)
    assert torch.allclose(means[0], torch.tensor([0.3, 0.0, 0.0]))          # pulled back
    assert torch.allclose(means[1], torch.tensor([0.0, 0.1, 0.0]))          # inside: untouched
    assert torch.allclose(means[2], torch.tensor([5.0, 0.45, 0.0]))
    assert torch.equal(means[3], torch.tensor([20.0, 0.0, 0.0]))            # static
    assert torch.allclose(log_scales[:3].exp(), torch.tensor([[0.15] * 3, [0.15] * 3, [0.225] * 3]))
    assert torch.equal(log_scales[3], torch.zeros(3))
    far = means * 10
    MotionBases(pivots, 4).keep_within(far, log_scales, basis)               # radius 0: unbounded
    assert torch.equal(far, means * 10)


def test_a_checkpoint_from_before_body_reach_loads(scene):
    from recon.dtg.model import DTGModel
    cfg = make_config("dtg", iterations=100, log_every=10**9)
    state = Trainer(cfg, scene, log=lambda _: None).model.state_for_checkpoint()
    del state["state_dict"]["motion.radii"]
    model = DTGModel.from_checkpoint(cfg.model, state)
    assert model.motion.count >= 1 and not model.motion.radii.any()



def test_body_members_that_look_static_start_with_a_closed_gate(tmp_path):
    """ModelConfig.basis_gate_static: a body member whose own colour most views show where it projects
    is floor under an object's path, not the object; it starts nearly static. Graded against the
    simulator (family-inside seed 0, 96x72): measured 44 of 51 members start closed, 3 of them on a
    moving object; the 7 left open are all on moving objects."""
    simulate_dataset(tmp_path, SimulateConfig(variant="family-inside", frames=20, width=96, height=72, seed=0,
                                              points=2000))
    scene = Scene(load_dataset(tmp_path))
    cfg = make_config("dtg", iterations=1000, log_every=10**9)
    cfg.model.basis_gate_static = -1.0
    g = Trainer(cfg, scene, log=lambda _: None).model.gaussians
    members = g["motion_basis"] > 0
    gates = g["dynamic_logit"].detach()[members]
    assert set(gates.unique().tolist()) == {-1.0, cfg.model.basis_gate_init}
    closed = (gates == -1.0).numpy()
    on = on_objects(g["means"].detach()[members], seed=0)
    assert on[~closed].mean() >= 0.8 and on[closed].mean() <= 0.2, (on[~closed].mean(), on[closed].mean())
    default = Trainer(make_config("dtg", iterations=1000, log_every=10**9), scene, log=lambda _: None).model.gaussians
    assert bool((default["dynamic_logit"] == cfg.model.basis_gate_init).all())
