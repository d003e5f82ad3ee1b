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
