"""A thermal network that changes only opacity and temperature (dtg-mlp's F_th) runs on the
Gaussians in view only (recon.render.in_view): the render is the same bits as running it on every
Gaussian, and so are the gradients it gives."""
import torch

from recon import render as rendering
from recon.splat import rasterization
from recon.splat.cameras import PinholeCamera
from recon.train.trainer import Trainer
from tests.test_train import small_cfg, tiny


def narrow_and_wide(model, t, camera, monkeypatch):
    """[(thermal image, F_th embeddings' gradient, render inputs)] rendered with F_th on the rows
    in view, then on every Gaussian."""
    out = []
    for narrow in (True, False):
        g = model.gaussians["embedding_thermal"]
        g.grad = None
        if not narrow:
            monkeypatch.setattr(rendering, "in_view", lambda *args, **kwargs: None)
        image, _, geo = rendering.render(model, "thermal", t, camera)
        monkeypatch.undo()
        (image * torch.linspace(0, 1, image.numel()).view_as(image)).sum().backward()
        out.append((image.detach(), g.grad.clone(), geo))
    return out


def count_thermal_rows(model) -> list[int]:
    """Spy on the model's F_th: the list it returns gets, per call, the rows the network ran on."""
    ran, residuals = [], model.stage_residuals

    def spy(stage, t, progress, rows=None):
        if stage == "thermal":
            ran.append(model.num_gaussians if rows is None else rows.numel())
        return residuals(stage, t, progress, rows=rows)

    model.stage_residuals = spy
    return ran


def test_network_on_rows_in_view_renders_and_trains_as_on_all(tmp_path_factory, monkeypatch):
    scene = tiny(tmp_path_factory, "family-inside")
    tr = Trainer(small_cfg("dtg-mlp", iterations=100), scene, log=lambda _: None)
    for _ in range(40):
        tr.step()
    model = tr.model
    assert not model.moves_geometry("thermal") and "thermal" in model.deformers
    view = scene.train["thermal"][0]
    for camera in (view.camera, view.camera.crop(10, 6, 24, 18)):
        (a, ga, geo), (b, gb, _) = narrow_and_wide(model, view.time, camera, monkeypatch)
        assert torch.equal(a, b)
        assert torch.allclose(ga, gb, atol=1e-7), (ga - gb).abs().max()
        rows = rendering.in_view(camera)({k: geo[k].detach() for k in ("means", "quats", "log_scales")})
        assert 0 < rows.numel() < model.num_gaussians      # some Gaussians are out of view
        touched = ga.abs().sum(1).nonzero().view(-1)
        assert set(touched.tolist()) <= set(rows.tolist())


def test_thermal_geometry_on_bodies_moves_bodies_only_and_renders_as_on_all(tmp_path_factory, monkeypatch):
    """ModelConfig.geometry_on_bodies: F_th's geometry residuals move the bodies' Gaussians only
    (the static scene is where the RGB render puts it), and F_th runs on the bodies and the static
    Gaussians in view: the same render and gradients as running it on every Gaussian."""
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.geometry_on_bodies = True
    tr = Trainer(cfg, scene, log=lambda _: None)
    for _ in range(60):
        tr.step()
    model = tr.model
    static = model.gaussians["motion_basis"] == 0
    assert model.moves_geometry("thermal") and 0 < int((~static).sum()) < model.num_gaussians
    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    (a, ga, geo_a), (b, gb, geo_b) = narrow_and_wide(model, view.time, view.camera, monkeypatch)
    ra, rb = (geo["geometry_residuals"]["means"].detach() for geo in (geo_a, geo_b))
    assert torch.allclose(a, b, atol=1e-6), (a - b).abs().max()
    assert torch.allclose(ga, gb, atol=1e-7), (ga - gb).abs().max()
    assert torch.equal(ra, rb)
    assert ra[static].abs().max() == 0                      # the static scene takes no thermal residual
    assert ra[~static].abs().max() > 0                      # the bodies do
    moved = model.means_at("thermal", view.time, 1.0, torch.nonzero(static).view(-1))
    assert torch.equal(moved, model.gaussians["means"][static])


def test_bodies_only_geometry_renders_the_same_with_or_without_the_rgb_stage_residuals(tmp_path_factory):
    """With F_rgb moving geometry too, the thermal render builds on the RGB stage's residuals: the
    ones its render applied (training passes them) or recomputed (inference). Both must be the
    bodies-only ones: the static scene stays where training left it."""
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.geometry_on_bodies = True
    cfg.model.deform_geometry = ("rgb", "thermal")
    tr = Trainer(cfg, scene, log=lambda _: None)
    for _ in range(60):
        tr.step()
    model, view = tr.model, scene.train["thermal"][3]
    with torch.no_grad():
        passed = model.render_inputs("rgb", view.time)["geometry_residuals"]
        trained = model.render_inputs("thermal", view.time, rgb_geometry=passed)
        inferred = model.render_inputs("thermal", view.time)
    static = model.gaussians["motion_basis"] == 0
    for key in ("means", "quats", "log_scales"):
        assert torch.equal(trained[key], inferred[key]), key
    assert torch.equal(inferred["means"][static], model.gaussians["means"][static])


def test_geometry_network_near_the_view_renders_and_trains_as_on_all(tmp_path_factory, monkeypatch):
    """ModelConfig.view_margin: a network that moves geometry (dtg's F_th) runs on the Gaussians
    whose place before it lies in the view or window widened by the margin; once trained a little,
    no residual carries a Gaussian across that margin, so render and gradients are those of running
    it on every Gaussian, while it ran on fewer."""
    scene = tiny(tmp_path_factory, "family-inside")
    cfg = small_cfg("dtg", iterations=100)
    cfg.model.view_margin = 0.1
    tr = Trainer(cfg, scene, log=lambda _: None)
    for _ in range(60):
        tr.step()
    model = tr.model
    assert model.moves_geometry("thermal")
    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    ran = count_thermal_rows(model)
    for camera in (view.camera, view.camera.crop(10, 6, 24, 18)):
        ran.clear()
        (a, ga, _), (b, gb, _) = narrow_and_wide(model, view.time, camera, monkeypatch)
        assert torch.allclose(a, b, atol=1e-6), (a - b).abs().max()
        assert torch.allclose(ga, gb, atol=1e-7), (ga - gb).abs().max()
        assert ran[0] < ran[1] == model.num_gaussians        # near the view, then on every Gaussian


def test_network_skips_gaussians_the_frozen_routing_removes(tmp_path_factory):
    """Once routing is frozen, a Gaussian whose modality mask is 0 is not drawn and takes no
    gradient: F_th runs without it, and the render and gradients are those of running F_th on it
    too (the same mask with requires_grad set keeps every row)."""
    scene = tiny(tmp_path_factory, "family-inside")
    tr = Trainer(small_cfg("dtg", iterations=100), scene, log=lambda _: None)
    for _ in range(60):
        tr.step()
    model = tr.model
    with torch.no_grad():   # roles of every kind (the first 60 steps leave them all shared)
        logits = model.gaussians["route_logits"]
        logits.copy_(torch.randn(logits.shape, generator=torch.Generator().manual_seed(0)))
    mask = rendering.inference_masks(model)["thermal"]
    assert 0 < int((mask == 0).sum()) < model.num_gaussians
    view = scene.train["thermal"][len(scene.train["thermal"]) // 2]
    ran = count_thermal_rows(model)
    out = []
    for m in (mask, mask.clone().requires_grad_()):
        model.deformers.zero_grad(set_to_none=True)
        image, _, _ = rendering.render(model, "thermal", view.time, view.camera, mask=m)
        (image * torch.linspace(0, 1, image.numel()).view_as(image)).sum().backward()
        out.append((image.detach(), [p.grad.clone() for p in model.deformers.parameters()]))
    (a, ga), (b, gb) = out
    assert ran[0] < ran[1]
    assert torch.allclose(a, b, atol=1e-6), (a - b).abs().max()
    for x, y in zip(ga, gb):
        assert torch.allclose(x, y, atol=1e-6, rtol=1e-4), (x - y).abs().max()


def test_in_view_leaves_out_what_the_off_view_cull_drops():
    """A Gaussian whose centre lies far beside the view but whose footprint reaches into it: the
    render culls it (cull_beside), so in_view with the same cull leaves it out (its network would
    only run for nothing); without the cull it is listed, as the projection alone draws it."""
    camera = PinholeCamera(torch.eye(4), 50.0, 50.0, 20.0, 15.0, 40, 30)
    # at depth 2: x = 2.2 projects to 20 + 50 * 1.1 = 75 px, 35 px beyond the right edge (> 0.5 x 40)
    means = torch.tensor([[0.0, 0.0, 2.0], [2.2, 0.0, 2.0]])
    geo = {"means": means, "quats": torch.tensor([[1.0, 0, 0, 0]] * 2),
           "log_scales": torch.log(torch.tensor([[0.05] * 3, [1.0] * 3]))}
    assert rendering.in_view(camera)(geo).tolist() == [0, 1]
    assert rendering.in_view(camera, cull_beside=0.5)(geo).tolist() == [0]
    drawn = rasterization(geo["means"], geo["quats"], geo["log_scales"], torch.ones(2), torch.ones(2, 1),
                          camera.viewmat, camera.fx, camera.fy, camera.cx, camera.cy, camera.width,
                          camera.height, cull_beside=0.5).radii > 0
    assert drawn.tolist() == [True, False]
