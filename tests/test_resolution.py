"""What of a view a step trains on (recon/train/resolution.py): a window's camera renders exactly
that window of the whole view, gradients included; a coarse copy averages blocks and keeps the
geometry; training through windows or coarse to fine learns."""
import pytest
import torch

from recon.splat import rasterization
from recon.train.resolution import coarse_to_fine, downscale, factor_at, random_crop, window
from recon.train.trainer import Trainer
from tests.splat_scenes import default_camera, random_gaussians
from tests.test_train import small_cfg, tiny


def render(g, camera):
    return rasterization(g.means, g.quats, g.log_scales, g.opacities, g.features, *camera.args(),
                         window=camera.window).image


@pytest.mark.parametrize("x0,y0,w,h", [(0, 0, 64, 48), (5, 3, 37, 29), (27, 19, 37, 29), (17, 0, 16, 48)])
def test_a_window_renders_that_window_of_the_view_and_has_its_gradients(x0, y0, w, h):
    cam = default_camera()
    g = random_gaussians(300, 3, seed=11).requires_grad_()
    weights = torch.rand(h, w, 3, generator=torch.Generator().manual_seed(1))
    full = render(g, cam)[y0:y0 + h, x0:x0 + w]
    grads_full = torch.autograd.grad((full * weights).sum(), g.tensors())
    part = render(g, cam.crop(x0, y0, w, h))
    assert part.shape == (h, w, 3)
    assert torch.allclose(part, full, atol=1e-5), (part - full).abs().max()
    grads_part = torch.autograd.grad((part * weights).sum(), g.tensors())
    for a, b in zip(grads_part, grads_full):
        assert torch.allclose(a, b, atol=1e-4, rtol=1e-3), (a - b).abs().max()


def test_a_window_outside_the_view_is_refused():
    with pytest.raises(ValueError, match="not inside a 64x48 view"):
        default_camera().crop(40, 0, 32, 24)


def test_windows_cover_every_pixel_and_keep_target_and_mask_aligned():
    gen = torch.Generator().manual_seed(0)
    seen = torch.zeros(36, 48)
    draws = 2000
    for _ in range(draws):
        x0, y0, w, h = window(48, 36, 0.5, gen)
        assert (w, h) == (24, 18) and 0 <= x0 <= 24 and 0 <= y0 <= 18
        seen[y0:y0 + h, x0:x0 + w] += 1
    # a corner is in a window when both centre coordinates fall in the outer quarter: 1/16
    # of the draws (a uniform top-left corner: 1/475)
    assert seen[0, 0] > draws / 16 * 0.7 and seen[-1, -1] > draws / 16 * 0.7, (seen[0, 0], seen[-1, -1])
    assert abs(seen.mean() / draws - 0.25) < 1e-6
    cam = default_camera(48, 36)
    target = torch.arange(36 * 48, dtype=torch.float32).view(36, 48)
    valid = target % 3 == 0
    crop_cam, t, v = random_crop(cam, target, valid, 0.5, gen)
    x0, y0 = round(cam.cx - crop_cam.cx), round(cam.cy - crop_cam.cy)
    assert torch.equal(t, target[y0:y0 + 18, x0:x0 + 24]) and torch.equal(v, valid[y0:y0 + 18, x0:x0 + 24])
    whole = random_crop(cam, target, None, 1.0, gen)
    assert whole[0] is cam and whole[1] is target and whole[2] is None


def test_a_coarse_view_averages_blocks_over_valid_pixels_and_projects_alike():
    cam = default_camera(64, 48)
    rgb = torch.rand(48, 64, 3, generator=torch.Generator().manual_seed(2))
    small_cam, small, none = downscale(cam, rgb, None, 4)
    assert (small_cam.width, small_cam.height) == (16, 12) and none is None
    assert torch.allclose(small[2, 3], rgb[8:12, 12:16].mean((0, 1)))
    u = torch.rand(48, 64, generator=torch.Generator().manual_seed(3))
    valid = torch.ones(48, 64, dtype=torch.bool)
    valid[0:4, 0:4] = False              # a block without any measurement
    valid[4:8, 0:4] = False
    valid[4, 0] = True                   # a block with one
    _, small_u, small_valid = downscale(cam, u, valid, 4)
    assert not small_valid[0, 0] and small_valid[1, 0] and torch.isclose(small_u[1, 0], u[4, 0])
    assert torch.isclose(small_u[2, 2], u[8:12, 8:12].mean())
    # a point lands at 1/4 of its pixel coordinates (pixel centres at i + 0.5)
    x = torch.tensor([0.3, -0.2, 0.5, 1.0])
    def pixel(c):
        p = (c.viewmat @ x)[:3]
        return torch.tensor([c.fx * p[0] / p[2] + c.cx, c.fy * p[1] / p[2] + c.cy])
    assert torch.allclose(pixel(small_cam), pixel(cam) / 4, atol=1e-5)


def test_coarse_to_fine_schedule_doubles_after_the_hold():
    s = coarse_to_fine(2, 1 / 3)
    assert [factor_at(s, p) for p in (0.0, 0.33, 0.34, 0.66, 0.67, 1.0)] == [4, 4, 2, 2, 1, 1]
    assert coarse_to_fine(0, 1 / 3) == ((0.0, 1),)


@pytest.mark.parametrize("how,rgb_gain,thermal_gain", [
    # each step sees a quarter (24x18) of a training frame: +0.7..1.4 dB RGB, +2.7..4.4 dB thermal
    # over seeds 0-3 (whole frames, seed 0: +2.1, +7.0)
    ("crop", 0.4, 1.8),
    # 24x18 for the first half, then 48x36: +1.0..2.0 dB RGB, +5.0..7.3 dB thermal over seeds 0-3
    ("coarse to fine", 0.6, 3.0),
])
def test_training_on_part_of_each_view_raises_heldout_psnr_of_whole_views(tmp_path_factory, how, rgb_gain,
                                                                         thermal_gain):
    scene = tiny(tmp_path_factory)
    cfg = small_cfg(iterations=200)
    if how == "crop":
        cfg.crop = 0.5
    else:
        cfg.resolution = coarse_to_fine(1, 0.5)
    tr = Trainer(cfg, scene, log=lambda _: None)
    before = tr.holdout_psnr()
    while not tr.done():
        tr.step()
    after = tr.holdout_psnr()
    assert after["rgb"] > before["rgb"] + rgb_gain, (before, after)
    assert after["thermal"] > before["thermal"] + thermal_gain, (before, after)
