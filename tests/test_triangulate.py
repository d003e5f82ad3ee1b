"""Bodies' depth from the camera's motion (recon/train/triangulate.py): rays from a moving camera
through an object on a smooth path pin its depth, which one view cannot."""
import math

import torch

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.dtg.motion import apply_motion
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.train.triangulate import camera_pins_depth, knot_cameras, retriangulate, smooth_path


def arc_rig_and_object(steps: int = 40):
    """A handheld camera sweeping +-40 degrees of a 1.5 m arc and back while an object moves a
    quarter circle of 0.3 m near the arc's centre: (camera centres (K, 3), true object path (K, 3))."""
    t = torch.linspace(0, 1, steps, dtype=torch.float64)
    az = math.radians(40) * torch.sin(2 * math.pi * t)
    cams = torch.stack([1.5 * torch.sin(az), -1.5 * torch.cos(az), 0.6 + 0.05 * torch.sin(6 * t)], 1)
    obj = torch.stack([0.3 * torch.cos(0.5 * math.pi * t), 0.3 * torch.sin(0.5 * math.pi * t), torch.full_like(t, 0.05)], 1)
    return cams, obj


def test_smooth_path_recovers_depth_that_each_ray_leaves_open():
    cams, obj = arc_rig_and_object()
    rays = torch.nn.functional.normalize(obj - cams, dim=1)
    true_depth = ((obj - cams) * rays).sum(1)
    # start 30 % too far along every ray, as a constant-velocity guess can leave a body
    start = cams + 1.3 * true_depth[:, None] * rays
    path = smooth_path(cams, rays, torch.ones(len(cams), dtype=torch.float64), start, smooth=100.0)
    depth = ((path - cams) * rays).sum(1)
    assert (depth - true_depth).abs().max() < 0.05, (depth - true_depth).abs().max()
    # the start is on every ray too: only the smoothness tells the two apart
    assert (start - obj).norm(dim=1).median() > 0.3


def test_smooth_path_holds_knots_without_rays_on_the_smooth_curve():
    cams, obj = arc_rig_and_object()
    rays = torch.nn.functional.normalize(obj - cams, dim=1)
    weights = torch.ones(len(cams), dtype=torch.float64)
    weights[15:20] = 0                     # the object left the view for five steps
    path = smooth_path(cams, rays, weights, obj + 0.5, smooth=100.0)
    assert (path - obj).norm(dim=1).max() < 0.06, (path - obj).norm(dim=1).max()


def test_a_still_camera_does_not_pin_depth_a_handheld_sweep_does():
    """From one fixed eye every path scaled about it fits the rays, and the smoothest is the one
    collapsed onto the camera: retriangulate must leave such a body alone."""
    cams, obj = arc_rig_and_object()
    ones = torch.ones(len(cams), dtype=torch.float64)
    still = cams[:1].expand_as(cams).clone()
    assert not camera_pins_depth(still, obj, ones)
    assert camera_pins_depth(cams, obj, ones)
    gaps = ones.clone()
    gaps[1::2] = 0                         # no three consecutive knots with rays: nothing to judge by
    assert not camera_pins_depth(cams, obj, gaps)


def test_retriangulate_slides_bodies_back_to_the_smooth_path_keeping_their_pixels(tmp_path):
    """A fresh dtg's bodies on the family's handheld sweep: each body's centre put on a smooth
    path, then every knot pushed 30 % deeper along its training camera's ray (what a wrong depth
    at intake looks like: the same pixels). retriangulate brings the depths back within a few
    centimetres, keeps every centre's pixel, and shrinks the body to keep its apparent size."""
    simulate_dataset(tmp_path, SimulateConfig(variant="family-inside", frames=40, width=96, height=72, seed=47,
                                              points=1500))
    scene = Scene(load_dataset(tmp_path))
    cfg = make_config("dtg", iterations=100, log_every=10**9, checkpoint_every=10**9, eval_every=10**9)
    trainer = Trainer(cfg, scene, log=lambda _: None)
    model, motion = trainer.model, trainer.model.motion
    assert motion is not None and motion.count >= 1
    g, gate = model.gaussians, model.dynamic_gate()
    knots = motion.translation.shape[1]
    cams = knot_cameras(scene, "rgb", knots, 0.0, 1.0)
    weight = torch.sigmoid(g["opacity_rgb"]) * gate

    def centres(b: int) -> torch.Tensor:
        sel = g["motion_basis"] == b + 1
        w = weight[sel]
        return torch.stack([(apply_motion(g["means"][sel], None, g["motion_basis"][sel], gate[sel], motion,
                                          k / (knots - 1))[0] * w[:, None]).sum(0) / w.sum() for k in range(knots)])

    def mean_gate(b: int) -> float:
        sel = g["motion_basis"] == b + 1
        return float((gate[sel] * weight[sel]).sum() / weight[sel].sum())

    truth, scales = {}, {}
    with torch.no_grad():
        for b in range(motion.count):
            x = centres(b)
            s = torch.linspace(0, 1, knots)[:, None]
            path = x + 0.25 * s * torch.tensor([1.0, 0.5, 0.0]) + 0.1 * s * s * torch.tensor([0.0, -1.0, 0.0])
            truth[b] = path
            deep = path.clone()
            for k, cs in cams.items():
                deep[k] = cs[0].center + 1.3 * (path[k] - cs[0].center)
            motion.translation[b] += (deep - x) / mean_gate(b)
            sel = (g["motion_basis"] == b + 1) & (gate > 0.5)
            scales[b] = g["log_scales"][sel].clone()
    before = {b: centres(b) for b in range(motion.count)}
    report = retriangulate(model, scene, 0.0, 1.0, smooth=100.0)
    moved = {r["body"] for r in report}
    # a body with less than one opaque Gaussian's worth of opacity is too faint to have a centre
    faint = {b for b in range(motion.count) if float(weight[g["motion_basis"] == b + 1].sum()) < 1.0}
    assert moved and moved == set(range(motion.count)) - faint, (report, faint)
    for b in moved:
        after = centres(b)
        for k, cs in cams.items():
            eye = cs[0].center
            ray = torch.nn.functional.normalize(before[b][k] - eye, dim=0)
            assert float(torch.linalg.cross(after[k] - eye, ray).norm()) < 1e-3       # same ray, same pixel
            assert abs(float((after[k] - truth[b][k]).norm())) < 0.05 * float((truth[b][k] - eye).norm())
        sel = (g["motion_basis"] == b + 1) & (gate > 0.5)
        shrink = float((g["log_scales"][sel] - scales[b]).mean().exp())
        assert abs(shrink - 1 / 1.3) < 0.05, shrink
