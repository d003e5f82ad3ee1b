"""Edge cases of the rasterizer: culling, extreme scales, odd cameras and image sizes, bad input."""
import pytest
import torch

from recon.splat import rasterization
from tests.splat_compare import forward_errors, gradient_errors
from tests.splat_scenes import Gaussians, default_camera, random_gaussians

TOL = 1e-4


def _near_plane_scene() -> Gaussians:
    """Gaussians behind the camera, straddling the near plane (z = 0.5) and just in front.

    Seeded: a random scene can put some pixel's alpha within float32 rounding of the 1/255
    cut-off (seen: 3e-7 relative), where float32 and the float64 reference rightly disagree."""
    g = random_gaussians(60, 3, seed=50, scale_range=(0.05, 0.6))
    gen = torch.Generator().manual_seed(0)
    cam_z = torch.tensor([0.4, -0.3, -4.0])  # default_camera's position; it looks along ~+z
    offsets = torch.linspace(-1.0, 1.5, 60)
    xy = 0.3 * torch.randn(60, 2, generator=gen)
    g.means = cam_z + torch.cat([xy, offsets[:, None]], 1)
    return g


def test_gaussians_behind_or_crossing_near_plane():
    g = _near_plane_scene()
    errors = forward_errors(g, default_camera(), near_plane=0.5)
    assert max(errors.values()) <= TOL, errors
    grad_errors = gradient_errors(g, default_camera(), near_plane=0.5)
    assert max(grad_errors.values()) <= 1e-3, grad_errors
    out = rasterization(*g.tensors(), *default_camera().args(), near_plane=0.5)
    view = default_camera().viewmat
    camera_z = g.means @ view[2, :3] + view[2, 3]
    assert (camera_z < 0).any() and ((camera_z > 0) & (camera_z < 0.5)).any()
    assert not out.visible[camera_z < 0.5].any()


def test_fully_off_screen_renders_background_with_zero_gradients():
    g = random_gaussians(40, 3, seed=51).requires_grad_()
    with torch.no_grad():
        g.means += torch.tensor([30.0, 0.0, 0.0])  # far to the side of the view
    background = torch.tensor([0.1, 0.2, 0.3])
    out = rasterization(*g.tensors(), *default_camera().args(), background=background)
    assert not out.visible.any()
    assert torch.equal(out.alpha, torch.zeros_like(out.alpha))
    assert torch.allclose(out.image, background.expand_as(out.image))
    out.image.sum().backward()
    for t in g.tensors():
        assert torch.equal(t.grad, torch.zeros_like(t))


@pytest.mark.parametrize("kind", ["huge", "flat", "needle", "point"])
def test_extreme_scales_match_reference(kind):
    g = random_gaussians(80, 3, seed=52)
    if kind == "huge":
        g.log_scales[:10] = 4.0  # ~55 world units: covers the whole image
        g.opacities[:10] = 0.05
    elif kind == "flat":
        g.log_scales[:, 2] = -18.0
    elif kind == "needle":
        g.log_scales[:, 1:] = -18.0
    else:
        g.log_scales[:] = -18.0  # smaller than the 0.3 px blur: a pixel-sized dot
    errors = forward_errors(g, default_camera())
    assert max(errors.values()) <= TOL, errors
    grad_errors = gradient_errors(g, default_camera())
    assert max(grad_errors.values()) <= 1e-3, grad_errors


def test_zero_gaussians():
    g = random_gaussians(0, 3, seed=0).requires_grad_()
    background = torch.tensor([0.3, 0.6, 0.9], requires_grad=True)
    out = rasterization(*g.tensors(), *default_camera().args(), background=background)
    assert out.image.shape == (48, 64, 3) and out.radii.shape == (0,) and out.means2d.shape == (0, 2)
    assert torch.allclose(out.image, background.detach().expand(48, 64, 3))
    out.image.sum().backward()
    assert g.means.grad.shape == (0, 3)
    assert torch.allclose(background.grad, torch.full((3,), 48.0 * 64.0))


@pytest.mark.parametrize("channels", [1, 2, 5])
def test_any_channel_count(channels):
    g = random_gaussians(100, channels, seed=53)
    errors = forward_errors(g, default_camera())
    assert max(errors.values()) <= TOL, errors
    grad_errors = gradient_errors(g, default_camera())
    assert max(grad_errors.values()) <= 1e-3, grad_errors


@pytest.mark.parametrize("width,height", [(1, 1), (17, 13), (1, 30), (33, 1), (50, 47)])
def test_odd_image_sizes(width, height):
    g = random_gaussians(120, 3, seed=54, scale_range=(0.05, 0.8))
    cam = default_camera(width=width, height=height, fx=0.9 * max(width, height), fy=max(width, height))
    errors = forward_errors(g, cam)
    assert max(errors.values()) <= TOL, errors
    grad_errors = gradient_errors(g, cam)
    assert max(grad_errors.values()) <= 1e-3, grad_errors


def test_off_centre_principal_point_and_unequal_focal_lengths():
    cam = default_camera(fx=40.0, fy=75.0, cx=9.0, cy=41.0)
    g = random_gaussians(200, 3, seed=55)
    errors = forward_errors(g, cam)
    assert max(errors.values()) <= TOL, errors
    grad_errors = gradient_errors(g, cam)
    assert max(grad_errors.values()) <= 1e-3, grad_errors


def test_zero_quaternion_does_not_crash():
    g = random_gaussians(10, 3, seed=56).requires_grad_()
    with torch.no_grad():
        g.quats[0] = 0.0
    out = rasterization(*g.tensors(), *default_camera().args())
    out.image.sum().backward()
    assert torch.isfinite(g.quats.grad).all() and torch.isfinite(out.image).all()


def test_tile_list_memory_is_bounded():
    g = random_gaussians(50, 3, seed=57)
    g.log_scales[:] = 4.0
    with pytest.raises(MemoryError, match="Gaussian-tile intersections"):
        rasterization(*g.tensors(), *default_camera().args(), max_tile_pairs=10)


def _valid():
    g = random_gaussians(5, 3, seed=58)
    return dict(means=g.means, quats=g.quats, log_scales=g.log_scales, opacities=g.opacities,
                features=g.features)


@pytest.mark.parametrize("name,value,match", [
    ("means", torch.zeros(5, 2), r"means must have shape \(N,3\), got \(5,2\)"),
    ("quats", torch.zeros(4, 4), r"quats must have shape \(5,4\), got \(4,4\)"),
    ("log_scales", torch.zeros(5, 3, dtype=torch.float64), r"log_scales must have dtype torch.float32"),
    ("opacities", torch.tensor([0.5, float("nan"), 0.5, 0.5, 0.5]), r"opacities with shape \(5\) contains non-finite"),
    ("features", torch.zeros(5), r"features must have shape \(5,N\), got \(5\)"),
    ("features", torch.zeros(5, 0), r"features must have at least 1 channel"),
    ("means", torch.zeros(5, 3, device="meta"), r"means is on meta"),
    ("means", [[0.0, 0.0, 0.0]], r"means must be a torch.Tensor"),
])
def test_bad_tensors_raise_value_error_naming_them(name, value, match):
    kwargs = _valid()
    kwargs[name] = value
    with pytest.raises(ValueError, match=match):
        rasterization(**kwargs, viewmat=torch.eye(4), fx=50.0, fy=50.0, cx=32.0, cy=24.0, width=64, height=48)


@pytest.mark.parametrize("override,match", [
    (dict(viewmat=torch.eye(3)), r"viewmat must have shape \(4,4\), got \(3,3\)"),
    (dict(viewmat=torch.full((4, 4), float("inf"))), r"viewmat .* non-finite"),
    (dict(width=0), r"width must be a positive int"),
    (dict(height=2.5), r"height must be a positive int"),
    (dict(fx=-1.0), r"fx and fy must be > 0"),
    (dict(cx=float("nan")), r"cx must be a finite number"),
    (dict(near_plane=0.0), r"near_plane must be > 0"),
    (dict(background=torch.zeros(4)), r"background must have shape \(3\), got \(4\)"),
    (dict(sh_degree=4), r"sh_degree must be None or an int in 0..3"),
    (dict(sh_degree=1), r"features as SH of degree 1 must have shape \(N,K>=4,C>=1\), got \(5,3\)"),
    (dict(threads=0), r"threads must be >= 1"),
])
def test_bad_camera_and_options_raise_value_error(override, match):
    kwargs = dict(_valid(), viewmat=torch.eye(4), fx=50.0, fy=50.0, cx=32.0, cy=24.0, width=64, height=48)
    kwargs.update(override)
    with pytest.raises(ValueError, match=match):
        rasterization(**kwargs)


def test_thread_count_does_not_change_the_result():
    """Tiles are composited by one thread each, so the image is bitwise identical; gradients are
    summed from per-thread buffers, so they agree to float rounding."""
    g = random_gaussians(300, 3, seed=59)
    results = []
    for threads in (1, 2, 3):
        params = g.to(torch.float32).requires_grad_()
        out = rasterization(*params.tensors(), *default_camera().args(), threads=threads)
        (out.image.sum() + out.depth.sum()).backward()
        results.append((out.image.detach(), [t.grad for t in params.tensors()]))
    for image, grads in results[1:]:
        assert torch.equal(image, results[0][0])
        for a, b in zip(grads, results[0][1]):
            assert torch.allclose(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("angle,length,width", [(0.0, 40.0, 1.5), (0.6, 40.0, 1.5), (2.3, 40.0, 1.5),
                                                (0.6, 600.0, 0.0)])
def test_tile_lists_hold_only_tiles_a_footprint_reaches(angle, length, width):
    """A long thin footprint's pixel box covers the whole 64x48 image (12 tiles); a tilted one is
    listed only in the tiles along its axis, an axis-aligned one in the row it lies in, and every
    pixel still gets exactly o exp(-q/2) of it (computed here in float64, without tiles). The last
    is a needle 2000 times longer than wide (its conic's determinant cancels to 1e-7 of ac)."""
    import numpy as np
    from recon.splat import _native

    w, h, o = 64, 48, 0.8
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    cov = rot @ np.diag([length ** 2, width ** 2]) @ rot.T + 0.3 * np.eye(2)
    conic = np.linalg.inv(cov).astype(np.float32).astype(np.float64)  # as the rasterizer gets it
    mean = np.array([31.3, 22.7])
    f = lambda *a: np.ascontiguousarray(np.array(a, dtype=np.float32))
    image, _, _, _, _, tx, ty, offsets, ids, _, _ = _native.rasterize_forward(
        f(mean), f([conic[0, 0], conic[0, 1], conic[1, 1]]), f([1.0]), f(o), f(1.0),
        np.array([40], dtype=np.int32), w, h, 1 << 20, 2)
    listed = np.diff(offsets).reshape(ty, tx)
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    d = np.stack([xs - mean[0], ys - mean[1]], -1)
    a = o * np.exp(-0.5 * np.einsum("hwi,ij,hwj->hw", d, conic, d))
    want = np.where(a >= 1 / 255, np.minimum(a, 0.99), 0.0)
    reached = (want > 0).reshape(ty, 16, tx, 16).any((1, 3))
    assert np.array_equal(listed > 0, reached), (listed, reached)
    assert listed.sum() < 12 if angle else listed.sum() == 4
    assert np.abs(image[..., 0] - want).max() < TOL
