"""ModelConfig.geometry_gate_init / PriorConfig.geometry_gate: a learned gate per Gaussian on the
thermal network's geometry residuals, and its price."""
import torch

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
    """ModelConfig.geometry_from: before it, F_th's geometry residuals are zero and its geometry
    outputs learn nothing (the temperature's change over time is learned first); after it they apply."""
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.geometry_from = 0.5
    tr = Trainer(cfg, scene, log=lambda _: None)
    p = {"now": 0.2}
    tr.progress_fn = lambda _: p["now"]
    net = tr.model.deformers["thermal"]
    rows = [i for i, (name, n) in enumerate(net.outputs.items()) for _ in range(n) if name in ("means", "quats", "log_scales")]
    for _ in range(20):
        tr.step()
    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    with torch.no_grad():
        held = tr.model.render_inputs("thermal", view.time, progress=0.2)
        assert "means" not in held["geometry_residuals"]
        # the geometry rows of the output layer never took a step (they start at zero)...
        assert float(net.out.weight[rows].abs().max()) == 0.0
        # ...while the temperature and opacity rows did
        assert float(net.out.weight.abs().max()) > 0
        idx = torch.arange(tr.model.num_gaussians)
        assert torch.equal(tr.model.means_at("thermal", view.time, 0.2, idx), held["means"])
    p["now"] = 0.6
    for _ in range(10):
        tr.step()
    with torch.no_grad():
        assert float(net.out.weight[rows].abs().max()) > 0
        moved = tr.model.render_inputs("thermal", view.time, progress=0.6)["geometry_residuals"]["means"]
        assert float(moved.abs().max()) > 0
