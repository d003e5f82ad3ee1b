"""Rigid motion bases (recon/dtg/motion.py) and the growing time window (recon/train/curriculum.py)."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from recon.train.curriculum import extrapolate_rows, window_bounds
from recon.dtg.gaussians import quat_to_rotmat
from recon.dtg.time_embedding import lerp_rows
from recon.dtg.motion import (_LEFT, MotionBases, apply_motion, axis_angle_to_quat, body_transforms,
                              connected_clusters, quat_matrix)


def rodrigues_reference(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector from the axis and angle (float64)."""
    angle = np.linalg.norm(v)
    if angle == 0:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def test_axis_angle_matches_reference_and_body_rotation():
    gen = torch.Generator().manual_seed(0)
    v = torch.randn(64, 3, generator=gen) * 1.5
    v[0] = 0.0
    v[1] = torch.tensor([1e-6, -2e-6, 0.5e-6])
    bases = MotionBases(torch.zeros(64, 3), knots=2).double()
    bases.rotation.data = v.double()[:, None].expand(64, 2, 3).clone()
    r_body = body_transforms(bases, 0.5)[:, :9].view(64, 3, 3)
    r_quat = quat_to_rotmat(axis_angle_to_quat(v.double()))
    for i in range(len(v)):
        reference = rodrigues_reference(v[i].double().numpy())
        np.testing.assert_allclose(r_quat[i].numpy(), reference, atol=1e-10)
        np.testing.assert_allclose(r_body[i].detach().numpy(), reference, atol=1e-10)


def test_motion_gradient_is_finite_at_zero_and_matches_finite_differences():
    v = torch.zeros(2, 3, dtype=torch.double, requires_grad=True)
    axis_angle_to_quat(v).sum().backward()
    assert torch.isfinite(v.grad).all()
    gen = torch.Generator().manual_seed(3)
    pivots = torch.randn(2, 3, generator=gen, dtype=torch.double)
    rotation = torch.randn(2, 3, 3, generator=gen, dtype=torch.double)
    rotation[0, 1] = 0.0                                  # a body at rest at t = 0.5
    means = torch.randn(12, 3, generator=gen, dtype=torch.double, requires_grad=True)
    quats = torch.randn(12, 4, generator=gen, dtype=torch.double, requires_grad=True)
    basis = torch.tensor([0.0, 1, 2] * 4, dtype=torch.double)
    gate = torch.rand(12, generator=gen, dtype=torch.double, requires_grad=True)

    def moved(means, quats, gate, rotation, translation):
        bases = SimpleNamespace(pivots=pivots, at=lambda t: (lerp_rows(rotation, t, dim=1), lerp_rows(translation, t, dim=1)))
        return apply_motion(means, quats, basis, gate, bases, 0.5)
    inputs = (means, quats, gate, rotation.requires_grad_(),
              torch.randn(2, 3, 3, generator=gen, dtype=torch.double, requires_grad=True))
    assert torch.autograd.gradcheck(moved, inputs)


def test_quat_left_matrix_composes_rotations():
    gen = torch.Generator().manual_seed(1)
    a, b = axis_angle_to_quat(torch.randn(5, 3, generator=gen)), axis_angle_to_quat(torch.randn(5, 3, generator=gen))
    ab = (quat_matrix(a, _LEFT) @ b[:, :, None])[:, :, 0]
    torch.testing.assert_close(quat_to_rotmat(ab), quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-5, rtol=1e-5)


def test_basis_motion_is_rigid_and_static_gaussians_stay():
    gen = torch.Generator().manual_seed(2)
    means = torch.randn(30, 3, generator=gen)
    quats = torch.nn.functional.normalize(torch.randn(30, 4, generator=gen), dim=1)
    basis = torch.tensor([0.0] * 10 + [1.0] * 10 + [2.0] * 10)
    bases = MotionBases(torch.tensor([[0.0, 0, 0], [1.0, 2, 3]]), knots=5)
    with torch.no_grad():
        bases.rotation[:, 2] = torch.tensor([[0.3, -0.2, 0.9], [0.0, 0.0, 1.2]])
        bases.translation[:, 2] = torch.tensor([[1.0, 0, 0], [0, -2.0, 0.5]])
    moved, mq = apply_motion(means, quats, basis, torch.ones(30), bases, t=0.5)
    torch.testing.assert_close(moved[:10], means[:10])
    torch.testing.assert_close(mq[:10], quats[:10])
    for sl, b in ((slice(10, 20), 0), (slice(20, 30), 1)):
        d0 = torch.cdist(means[sl], means[sl])
        torch.testing.assert_close(torch.cdist(moved[sl], moved[sl]), d0, atol=1e-5, rtol=1e-5)
        r = torch.from_numpy(rodrigues_reference(bases.rotation[b, 2].detach().double().numpy())).float()
        expect = (means[sl] - bases.pivots[b]) @ r.T + bases.pivots[b] + bases.translation[b, 2]
        torch.testing.assert_close(moved[sl], expect.detach(), atol=1e-5, rtol=1e-5)
        # the Gaussian's own rotation turns with its body
        torch.testing.assert_close(quat_to_rotmat(mq[sl]), r.detach() @ quat_to_rotmat(quats[sl]), atol=1e-5, rtol=1e-5)
    # gate 0: stays; between knots: linear in the knots
    still, _ = apply_motion(means, quats, basis, torch.zeros(30), bases, t=0.5)
    torch.testing.assert_close(still, means)
    half, _ = apply_motion(means, quats, basis, torch.ones(30), bases, t=0.375)
    torch.testing.assert_close(half[10:20] - means[10:20],
                               0.5 * (moved[10:20] - means[10:20]) + 0 * half[10:20], atol=0.25, rtol=0)


def test_smoothness_is_zero_for_constant_velocity():
    bases = MotionBases(torch.zeros(1, 3), knots=6)
    with torch.no_grad():
        bases.translation[0] = torch.arange(6.0)[:, None] * torch.tensor([0.1, 0.2, -0.3])
        bases.rotation[0] = torch.arange(6.0)[:, None] * torch.tensor([0.0, 0.05, 0.0])
    assert float(bases.smoothness(extent=2.0).detach()) < 1e-12
    with torch.no_grad():
        bases.translation[0, 3] += 0.5
    assert float(bases.smoothness(extent=2.0).detach()) > 1e-3


def _rolls_then_stops(knots: int = 40, stop: int = 16, speed: float = 0.02) -> torch.Tensor:
    """(knots, 3) a path at constant speed along x that stops dead at knot `stop`."""
    x = speed * torch.arange(knots, dtype=torch.float32).clamp(max=stop)
    return torch.stack([x, torch.zeros(knots), torch.zeros(knots)], 1)


def test_robust_smoothness_prefers_a_stop_to_a_depth_error():
    """A path scaled about a moving camera, X' = s X + (1 - s) C, fits the training views as well as
    X. Squared, one stop's kink costs about half a 10 % depth error; robust, far less."""
    gen = torch.Generator().manual_seed(0)
    camera = torch.cumsum(torch.cumsum(0.02 * torch.randn(40, 3, generator=gen), 0), 0)   # a jerky sweep
    path = _rolls_then_stops() + torch.tensor([0.0, 1.5, 0.0])
    scaled = 0.9 * path + 0.1 * camera

    def cost(p, scale):
        bases = MotionBases(torch.zeros(1, 3), knots=40)
        with torch.no_grad():
            bases.translation[0] = p
        return float(bases.smoothness(extent=1.0, scale=scale).detach())
    squared, robust = cost(path, 0.0) / cost(scaled, 0.0), cost(path, 1e-3) / cost(scaled, 1e-3)
    assert squared > 0.3          # squared: the stop costs about as much as the depth error
    assert robust < squared / 2   # robust: the depth error costs several times the stop
    # below the scale it is the squared prior; above it, linear (the pull on a kink is bounded)
    small = 1e-5 * torch.randn(40, 3, generator=gen)
    assert abs(cost(small, 1e-3) - cost(small, 0.0)) < 1e-3 * cost(small, 0.0)
    assert cost(path, 1e-3) < 0.2 * cost(path, 0.0)


def test_connected_clusters_are_objects():
    gen = torch.Generator().manual_seed(3)
    centres = torch.tensor([[0.0, 0, 0], [5.0, 0, 0], [0, 5.0, 0]])
    sizes = (50, 30, 10)
    pts = torch.cat([c + 0.2 * torch.rand(n, 3, generator=gen) for c, n in zip(centres, sizes)])
    labels = connected_clusters(pts, radius=0.5)
    assert labels[:50].eq(0).all() and labels[50:80].eq(1).all() and labels[80:].eq(2).all()   # largest first
    # a chain of close points is one body, however long
    chain = torch.stack([torch.tensor([0.3 * i, 0.0, 0.0]) for i in range(20)])
    assert connected_clusters(chain, radius=0.35).eq(0).all()
    assert len(set(connected_clusters(chain, radius=0.25).tolist())) == 20


def test_window_grows_from_its_centre():
    assert window_bounds(0, 40, 0.5, 3, grow_every=0) == (0, 39)
    assert window_bounds(0, 40, 0.5, 3, grow_every=10, hold=100) == (17, 23)
    assert window_bounds(99, 40, 0.5, 3, grow_every=10, hold=100) == (17, 23)
    assert window_bounds(120, 40, 0.5, 3, grow_every=10, hold=100) == (15, 25)
    assert window_bounds(10_000, 40, 0.5, 3, grow_every=10, hold=100) == (0, 39)
    assert window_bounds(50, 40, 0.0, 1, grow_every=10) == (0, 6)


def test_rows_beyond_the_window_continue_its_edges():
    table = torch.zeros(2, 9, 3)
    table[:, 3:6] = torch.arange(3.0)[None, :, None] * torch.tensor([1.0, -2.0, 0.5])   # rows 3..5 move
    extrapolate_rows(table, 3 / 8, 5 / 8, dim=1)
    expect = torch.arange(-3.0, 6.0)[:, None] * torch.tensor([1.0, -2.0, 0.5])
    torch.testing.assert_close(table[0], expect)
    copy = torch.arange(9.0)[:, None].repeat(1, 2)
    extrapolate_rows(copy, 2 / 8, 4 / 8, velocity=False)
    assert copy[:2].eq(2.0).all() and copy[5:].eq(4.0).all() and copy[2:5, 0].tolist() == [2.0, 3.0, 4.0]


def test_window_draws_edges_outside_and_inside():
    from recon.config import CurriculumConfig
    from recon.train.curriculum import TimeWindow
    times = [i / 19 for i in range(20)]
    w = TimeWindow(CurriculumConfig(grow_every=10, center=0.5, start_steps=2, hold=0, edge_weight=0.5,
                                    outside=0.2), times)
    assert w.update(0) == [] and w.bounds == (8, 12)
    assert w.update(10) == [("lo", times[7]), ("hi", times[13])] and w.update(15) == []
    gen = torch.Generator().manual_seed(0)
    picks = [w.pick(times, gen) for _ in range(4000)]
    outside = sum(not w.contains(t) for t in picks) / len(picks)
    edges = sum(t in (times[7], times[13]) for t in picks) / len(picks)
    assert abs(outside - 0.2) < 0.03 and abs(edges - (0.4 + 0.4 * 2 / 7)) < 0.04
    w.update(10_000)
    assert w.complete and w.contains(0.0) and w.contains(1.0)


def test_trimmed_l1_ignores_the_worst_pixels():
    from recon.dtg.losses import trimmed_l1
    gt = torch.zeros(10, 10)
    pred = torch.full((10, 10), 0.1)
    pred[0, :5] = 5.0                        # a moving object the model has not placed: 5 % of pixels
    assert abs(float(trimmed_l1(pred, gt, None, keep=0.9)) - 0.1) < 1e-6
    assert float(trimmed_l1(pred, gt, None, keep=1.0)) > 0.3
    valid = torch.ones(10, 10, dtype=torch.bool)
    valid[0] = False
    assert abs(float(trimmed_l1(pred, gt, valid, keep=1.0)) - 0.1) < 1e-6


def look_at_rotation(eye: np.ndarray, target: np.ndarray, up: np.ndarray, roll: float = 0.0) -> torch.Tensor:
    """World-to-camera rotation (3, 3), OpenCV axes, of a camera at eye looking at target."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    return torch.tensor(np.stack([x, y, z]), dtype=torch.float32)


def test_up_comes_from_the_cameras_level_x_axes_not_their_tilt():
    """Cameras on a +-40 degree arc, 30 degrees above the scene and looking down at it, a little
    rolled, in a world whose up is not an axis: Scene.up's estimate is within 1 degree of the true
    up, where the cameras' mean up is ~25 degrees off; with no sweep it still points up."""
    from recon.scene import up_from_cameras
    rng = np.random.default_rng(3)
    true_up = np.array([0.3, -0.8, 0.52])
    true_up /= np.linalg.norm(true_up)
    a = np.cross(true_up, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(true_up, a)

    def rig(azimuths):
        rots = []
        for az in azimuths:
            eye = 1.5 * (math.cos(math.radians(30)) * (math.cos(az) * a + math.sin(az) * b)
                         + math.sin(math.radians(30)) * true_up)
            rots.append(look_at_rotation(eye, np.zeros(3), true_up, roll=rng.normal(0, 0.02)))
        return torch.stack(rots)

    def angle(u) -> float:
        return math.degrees(math.acos(min(1.0, float(u.double() @ torch.tensor(true_up)))))

    swept = rig(np.radians(np.linspace(-40, 40, 30)))
    assert angle(up_from_cameras(swept)) < 1.0
    mean_up = -swept[:, 1, :].mean(0)
    assert angle(mean_up / mean_up.norm()) > 15.0
    still = rig(np.radians(np.full(10, 10.0)))
    assert angle(up_from_cameras(still)) < 35.0
    on_side = swept[:, [1, 0, 2], :] * torch.tensor([-1.0, 1.0, 1.0])[:, None]   # every camera rolled 90 degrees
    assert float(up_from_cameras(on_side).abs().sum()) == 0.0            # unknown, not a wall


def test_climb_prices_vertical_speed_only():
    up = torch.tensor([0.0, 0.6, 0.8])
    bases = MotionBases(torch.zeros(2, 3), knots=5)
    with torch.no_grad():
        level = torch.tensor([0.0, 0.8, -0.6])                  # orthogonal to up
        bases.translation[:] = torch.linspace(0, 1, 5)[None, :, None] * level
    assert float(bases.climb(up, 2.0).detach()) < 1e-12
    with torch.no_grad():
        bases.translation[1, 3] += 0.2 * up
    climb = bases.climb(up, 2.0)
    assert float(climb.detach()) == pytest.approx(2 * (0.1 ** 2) / 4, rel=1e-5)   # up then down 0.1 extents, 4 steps
    climb.backward()
    grad = bases.translation.grad[1, 3]
    assert float(grad.norm()) > 0 and float((grad - (grad @ up) * up).norm()) < 1e-6


def test_anchor_pull_holds_only_the_anchored_bases_to_their_paths():
    bases = MotionBases(torch.zeros(2, 3), knots=4)
    path = torch.linspace(0, 1, 4)[:, None] * torch.tensor([0.4, 0.0, 0.3])
    with torch.no_grad():
        bases.anchors[0] = path
        bases.anchored[0, :3] = True                     # knot 3 not measured: free
        bases.translation[0] = path
        bases.translation[0, 3] += 1.0
        bases.translation[1] = 5.0                       # not anchored: free to be anywhere
    assert float(bases.anchor_pull(2.0).detach()) == 0
    with torch.no_grad():
        bases.translation[0, 2] += torch.tensor([0.0, 0.2, 0.0])
    pull = bases.anchor_pull(2.0)
    assert float(pull.detach()) == pytest.approx(0.1 ** 2 / 4, rel=1e-5)    # 0.1 extents at one knot of 4
    pull.backward()
    grad = bases.translation.grad
    assert float(grad[1].abs().sum()) == 0 and float(grad[0, 2, 1]) > 0 and float(grad[0, [0, 1, 3]].abs().sum()) == 0
    with torch.no_grad():
        bases.translation[0, 3] -= 1.0                   # knot 3 back on the path: the pull is unchanged
    assert float(bases.anchor_pull(2.0).detach()) == pytest.approx(float(pull.detach()), rel=1e-6)


def test_hold_cost_counts_each_knots_move_in_standard_deviations_of_its_path():
    """A knot moved 5 cm along a direction its path measured to 5 cm costs 1 (before the mean over
    knots), the same move across a direction measured to 1 cm costs 25; unanchored knots and bases
    are free, and only the moved knot gets a gradient, pointing back along the move."""
    bases = MotionBases(torch.zeros(2, 3), knots=4)
    with torch.no_grad():
        bases.anchored[0, :3] = True
        bases.anchor_precision[0] = torch.diag(torch.tensor([1 / 0.05 ** 2, 1 / 0.01 ** 2, 1 / 0.01 ** 2]))
        bases.translation[0, 3] += 1.0                   # knot 3 not measured: free
        bases.translation[1] = 5.0                       # not anchored: free
    assert float(bases.hold_cost().detach()) == 0
    with torch.no_grad():
        bases.translation[0, 1, 0] += 0.05
    assert float(bases.hold_cost().detach()) == pytest.approx(1 / 4, rel=1e-4)
    with torch.no_grad():
        bases.translation[0, 1] = torch.tensor([0.0, 0.05, 0.0])
    cost = bases.hold_cost()
    assert float(cost.detach()) == pytest.approx(25 / 4, rel=1e-4)
    cost.backward()
    grad = bases.translation.grad
    assert float(grad[1].abs().sum()) == 0 and float(grad[0, [0, 2, 3]].abs().sum()) == 0
    assert float(grad[0, 1, 1]) > 0 and float(grad[0, 1, [0, 2]].abs().sum()) == 0


@pytest.mark.parametrize("with_quats", [True, False])
def test_native_body_motion_matches_the_torch_reference_and_its_gradients(with_quats):
    """recon/dtg/csrc/motion.cpp against apply_motion_reference (torch ops), float32, on 3 bodies
    and static rows mixed, gates anywhere in [0, 1]: the moved means and quats and every input's
    gradient (means, quats, gate, the packed transforms), for a random upstream gradient."""
    from recon.dtg.motion import BodyMotion, apply_motion_reference
    gen = torch.Generator().manual_seed(5)
    n, b = 500, 3
    means = torch.randn(n, 3, generator=gen, requires_grad=True)
    quats = torch.randn(n, 4, generator=gen, requires_grad=True)
    basis = torch.randint(0, b + 1, (n,), generator=gen).float()
    gate = torch.rand(n, generator=gen, requires_grad=True)
    transforms = torch.randn(b, 28, generator=gen, requires_grad=True)
    v_m, v_q = torch.randn(n, 3, generator=gen), torch.randn(n, 4, generator=gen)
    results = []
    for fn in ("native", "reference"):
        for x in (means, quats, gate, transforms):
            x.grad = None
        if fn == "native":
            m, q = BodyMotion.apply(means, quats if with_quats else means.new_zeros(0, 4), basis, gate, transforms)
        else:
            m, q = apply_motion_reference(means, quats if with_quats else None, basis, gate, transforms)
        loss = (m * v_m).sum() + ((q * v_q).sum() if with_quats else 0)
        loss.backward()
        results.append([m.detach(), q.detach() if with_quats else None] +
                       [x.grad for x in (means, quats, gate, transforms)])
    for got, want in zip(*results):
        if want is None:
            assert got is None or got.numel() == 0
        else:
            torch.testing.assert_close(got, want, atol=2e-5, rtol=1e-5)
    assert all(float(g.abs().sum()) > 0 for g in results[0][4:])     # the gate's and bodies' gradients are real


def test_native_body_motion_refuses_a_basis_it_has_no_body_for():
    from recon.dtg import _native
    ok = dict(means=np.zeros((4, 3), np.float32), quats=np.zeros((0, 4), np.float32),
              basis=np.array([0, 1, 2, 0], np.float32), gate=np.ones(4, np.float32),
              transforms=np.zeros((2, 28), np.float32))
    _native.forward_float32(*ok.values())
    with pytest.raises(ValueError, match=r"basis\[2\] = 3.*not 0 or a body 1..2"):
        _native.forward_float32(*{**ok, "basis": np.array([0, 1, 3, 0], np.float32)}.values())
    with pytest.raises(ValueError, match="bad shape for gate"):
        _native.forward_float32(*{**ok, "gate": np.ones(3, np.float32)}.values())


def test_native_body_transforms_match_the_torch_reference_and_finite_differences():
    """recon/dtg/csrc/motion.cpp's packed transforms against body_transforms_reference (values and
    gradients, float32) and against finite differences (float64 gradcheck), over large rotations,
    small ones on both sides of the series' switch (|v|^2 = 1e-8) and none at all."""
    from recon.dtg.motion import BodyTransforms, body_transforms_reference
    gen = torch.Generator().manual_seed(7)
    rot = torch.cat([torch.randn(4, 3, generator=gen) * 2.0, torch.randn(2, 3, generator=gen) * 1e-3,
                     torch.full((1, 3), 3e-5), torch.zeros(1, 3)])
    trans, pivots = torch.randn(8, 3, generator=gen), torch.randn(8, 3, generator=gen)
    v = torch.randn(8, 28, generator=gen)
    grads = []
    for fn in (BodyTransforms.apply, body_transforms_reference):
        r, t = rot.clone().requires_grad_(), trans.clone().requires_grad_()
        out = fn(r, t, pivots)
        (out * v).sum().backward()
        grads.append((out.detach(), r.grad, t.grad))
    for got, want in zip(*grads):
        torch.testing.assert_close(got, want, atol=2e-5, rtol=1e-5)
    rot64 = rot[:6].double().requires_grad_()
    assert torch.autograd.gradcheck(lambda r, t: BodyTransforms.apply(r, t, pivots[:6].double()),
                                    (rot64, trans[:6].double().requires_grad_()))
