"""ModelConfig.geometry_gate_init / PriorConfig.geometry_gate: a learned gate per Gaussian on the
thermal network's geometry residuals, and its price."""
import torch

from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.scene import Scene
from recon.dtg.points import project
from recon.train.trainer import Trainer
from tests.test_train import small_cfg, tiny


def test_gate_scales_the_thermal_residuals_and_its_price_closes_idle_gates(tmp_path_factory):
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.geometry_gate_init = 2.0
    cfg.priors.geometry_gate = 1e-3
    tr = Trainer(cfg, scene, log=lambda _: None)
    for _ in range(60):
        tr.step()
    model = tr.model
    gate = torch.sigmoid(model.gaussians["geometry_logit"].detach())
    # Adam moves a logit that only the price pulls by ~its rate a step: the idle gates close...
    assert float(gate.median()) < 0.5 * float(torch.sigmoid(torch.tensor(2.0)))
    # ...while the thermal loss holds some open
    assert float(gate.max()) > 2 * float(gate.median())

    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    n = model.num_gaussians
    with torch.no_grad():
        logit = model.gaussians["geometry_logit"]
        logit.copy_(torch.where(torch.arange(n) % 2 == 0, torch.tensor(-40.0), torch.tensor(0.0)))
        free = model.stage_residuals("thermal", view.time, 1.0)["means"]
        geo = model.render_inputs("thermal", view.time)
        applied = geo["geometry_residuals"]["means"]
        assert applied[0::2].abs().max() < 1e-12
        assert torch.allclose(applied[1::2], 0.5 * free[1::2], atol=1e-9)
        assert free[1::2].abs().max() > 0
        idx = torch.arange(n)
        assert torch.allclose(model.means_at("thermal", view.time, 1.0, idx), geo["means"], atol=1e-6)
        # the RGB render never takes the thermal residuals (dtg has no F_rgb: it takes none)
        rgb = model.render_inputs("rgb", view.time)
        assert rgb["geometry_residuals"] == {}


def test_geometry_held_until_geometry_from(tmp_path_factory):
    """ModelConfig.geometry_from: before it, F_th's geometry residuals are zero for every Gaussian
    but the bodies' members (moving things found in the data move from the start), so the others'
    temperature change over time is learned first; after it they apply to all."""
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.geometry_from = 0.5
    tr = Trainer(cfg, scene, log=lambda _: None)
    p = {"now": 0.2}
    tr.progress_fn = lambda _: p["now"]
    for _ in range(20):
        tr.step()
    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    bodies = tr.model.gaussians["motion_basis"] > 0
    assert 0 < int(bodies.sum()) < len(bodies)
    with torch.no_grad():
        held = tr.model.render_inputs("thermal", view.time, progress=0.2)
        moved = held["geometry_residuals"]["means"]
        assert float(moved[~bodies].abs().max()) == 0.0 and float(moved[bodies].abs().max()) > 0
        idx = torch.arange(tr.model.num_gaussians)
        assert torch.allclose(tr.model.means_at("thermal", view.time, 0.2, idx), held["means"], atol=1e-6)
    p["now"] = 0.6
    for _ in range(10):
        tr.step()
    with torch.no_grad():
        bodies = tr.model.gaussians["motion_basis"] > 0
        moved = tr.model.render_inputs("thermal", view.time, progress=0.6)["geometry_residuals"]["means"]
        assert float(moved[~bodies].abs().max()) > 0


def test_gaussians_on_a_still_hot_blob_are_held_in_place(tmp_path_factory):
    """ModelConfig.hold_in_place on the default scene (a hot plate heating where it stands): the
    Gaussians the trainer flags lie on the plate, F_th moves none of them while it moves others,
    and densification's new Gaussians are flagged too."""
    out = tmp_path_factory.mktemp("plate")
    simulate_dataset(out, SimulateConfig(variant="default", frames=24, width=64, height=48, seed=3, points=800))
    scene = Scene(load_dataset(out))
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.hold_in_place = True
    cfg.paths.min_frames = 6           # 24 frames at 64x48: the plate's blob is whole in 6-9 of them
    tr = Trainer(cfg, scene, log=lambda _: None)
    g = tr.model.gaussians
    flags = g["in_place"] > 0
    assert tr.still and 10 <= int(flags.sum()) < 0.2 * len(flags)
    view = scene.train["thermal"][-1]                       # the plate at its hottest
    labels = torch.from_numpy(scene.dataset.mask(view.frame).copy())
    u, v, _, _ = project(view.camera, g["means"].detach())
    on_plate = labels[v.clamp(0, view.camera.height - 1), u.clamp(0, view.camera.width - 1)] == 1
    assert on_plate[flags].float().mean() > 0.8          # measured 30 of 32
    assert flags[on_plate].float().mean() > 0.6          # 30 of 35
    n = tr.model.num_gaussians
    while tr.model.num_gaussians == n:                 # until densification adds Gaussians
        tr.step()
    g = tr.model.gaussians
    flags = g["in_place"] > 0
    assert len(flags) == tr.model.num_gaussians and int(flags.sum()) >= 10
    with torch.no_grad():
        inputs = tr.model.render_inputs("thermal", view.time)
        moved = inputs["geometry_residuals"]["means"]
        assert float(moved[flags].abs().max()) == 0.0 and float(moved[~flags].abs().max()) > 0
        idx = torch.arange(tr.model.num_gaussians)        # (a body's members still move with it)
        assert torch.allclose(tr.model.means_at("thermal", view.time, 1.0, idx), inputs["means"], atol=1e-6)
