"""Flow tracks of the bodies (recon/train/tracks.py): chained optical flow follows a moving hot
disc, and the track loss and the intake offset put a body's points on their tracks."""
import numpy as np
import torch

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.dtg.motion import MotionBases
from recon.eval.evaluate import moving_masks
from recon.scene import Scene
from recon.train.trainer import Trainer
from recon.train.tracks import Tracks, chain_flow, moved_at, moved_points, project, track_loss, track_offset


def disc_frames(centres, size=(64, 96), radius=6.0):
    """Frames (H, W) uint8 of a hot soft-edged disc at centres [(u, v)] over a faint static texture."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    texture = 20 + 10 * np.sin(xx / 3.0) * np.cos(yy / 4.0)
    frames = []
    for u, v in centres:
        disc = 200 / (1 + np.exp((np.hypot(xx - u, yy - v) - radius) / 1.0))
        frames.append(np.clip(texture + disc, 0, 255).astype(np.uint8))
    return frames


def test_chained_flow_follows_a_moving_hot_disc_both_ways():
    centres = [(20 + 3 * k, 30 + 1.5 * k) for k in range(9)]
    frames = disc_frames(centres)
    k0 = 4
    start = np.array([centres[k0]], np.float32)
    uv, valid = chain_flow(frames, start, k0, fb=1.0)
    assert valid[:, 0].sum() >= 7, valid[:, 0]
    err = np.linalg.norm(uv[valid[:, 0], 0] - np.array(centres)[valid[:, 0]], axis=1)
    assert err.max() < 1.5, err
    # a track that leaves the image ends there
    far = np.array([[95.5, 30.0]], np.float32)
    moving = disc_frames([(95.5 + 4 * k, 30) for k in range(4)])
    _, valid = chain_flow(moving, far, 0, fb=1.0)
    assert not valid[-1, 0]


def straight_scene(knots=5, m=6):
    """One body whose true path translates +x by 0.1 m a knot, 2 m in front of a camera that
    slides sideways; its points' true pixels as tracks (the track at step 3 made invalid and wild)."""
    gen = torch.Generator().manual_seed(0)
    points = torch.randn(m, 3, generator=gen) * 0.05 + torch.tensor([0.0, 0.0, 2.0])
    times = [k / (knots - 1) for k in range(knots)]
    viewmats = torch.eye(4).repeat(knots, 1, 1)
    viewmats[:, 0, 3] = torch.linspace(0, -0.2, knots)
    intrinsics = torch.tensor([[100.0, 100.0, 48.0, 32.0]]).repeat(knots, 1)
    truth = MotionBases(points.mean(0, keepdim=True), knots)
    with torch.no_grad():
        truth.translation[0, :, 0] = 0.1 * torch.arange(knots)
    basis = torch.ones(m, dtype=torch.long)
    uv = torch.stack([project(viewmats[k], intrinsics[k], moved_points(truth, points, basis, t))[0]
                      for k, t in enumerate(times)]).detach()
    valid = torch.ones(knots, m, dtype=torch.bool)
    valid[3] = False
    uv[3] += 500.0
    return Tracks(points, basis, times, viewmats, intrinsics, uv, valid), truth


def test_track_offset_moves_a_body_onto_its_tracks():
    tracks, _ = straight_scene()
    body = MotionBases(tracks.points.mean(0, keepdim=True), len(tracks.times))
    t = tracks.times[2]
    offset = track_offset(body, tracks, 0, t)
    with torch.no_grad():
        body.translation[0, 2] += offset
        uv, _ = project(tracks.viewmats[2], tracks.intrinsics[2], moved_points(body, tracks.points, tracks.basis, t))
    assert (uv - tracks.uv[2]).norm(dim=1).median() < 0.05
    assert track_offset(body, tracks, 0, tracks.times[3]) is None     # no valid track there


def test_track_loss_pulls_the_knots_onto_the_tracks_and_ignores_invalid_steps():
    tracks, truth = straight_scene()
    body = MotionBases(tracks.points.mean(0, keepdim=True), len(tracks.times))
    steps = torch.arange(len(tracks.times))
    opt = torch.optim.Adam(body.parameters(), lr=0.01)
    first = float(track_loss(body, tracks, steps).detach())
    for _ in range(400):
        opt.zero_grad()
        loss = track_loss(body, tracks, steps)
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.01 * first
    fitted = [0, 1, 2, 4]        # step 3's tracks are invalid: nothing pulls its knot
    err = (body.translation[0, fitted] - truth.translation[0, fitted]).detach().norm(dim=1)
    assert float(err.max()) < 0.02, err
    assert float(body.translation[0, 3].detach().norm()) < 0.05      # not dragged 500 px off by the invalid track


def test_every_step_at_once_moves_points_as_each_step_alone():
    gen = torch.Generator().manual_seed(1)
    body = MotionBases(torch.randn(2, 3, generator=gen), 6)
    with torch.no_grad():
        body.rotation.normal_(0, 0.3, generator=gen)
        body.translation.normal_(0, 0.2, generator=gen)
    points = torch.randn(5, 3, generator=gen)
    basis = torch.tensor([1, 2, 1, 2, 2])
    times = torch.tensor([0.0, 0.13, 0.5, 0.77, 1.0])
    at_once = moved_at(body, points, basis, times)
    alone = torch.stack([moved_points(body, points[i:i + 1], basis[i:i + 1], float(t))[0] for i, t in enumerate(times)])
    assert torch.allclose(at_once, alone, atol=1e-5)


def test_tracks_start_near_a_body_and_stay_on_the_moving_object(tmp_path):
    """A simulated family scene (seed 8 at 96x72: of seeds 3, 5, 8, 11, 22 and 47 the one whose moving
    object is hot near a body where the bodies were seen): the tracks the trainer builds lie on the
    moving object's pixels (the simulator's per-frame masks), not on the static hot cup."""
    simulate_dataset(tmp_path, SimulateConfig(variant="family-inside", frames=40, width=96, height=72, seed=8,
                                              points=1500))
    scene = Scene(load_dataset(tmp_path))
    cfg = make_config("dtg", iterations=500)
    cfg.priors.flow_tracks = 0.01
    tracks = Trainer(cfg, scene, log=lambda _: None).tracks
    assert tracks is not None
    views = [scene.views_at("thermal", t)[0] for t in tracks.times]
    masks = moving_masks(scene.dataset, [v.frame for v in views])
    on, total = 0, 0
    for k, view in enumerate(views):
        mask = torch.from_numpy(masks[view.frame.file_path])
        mask = torch.nn.functional.max_pool2d(mask[None, None].float(), 5, 1, 2)[0, 0] > 0   # within 2 px
        uv = tracks.uv[k, tracks.valid[k]].long()
        on += int(mask[uv[:, 1].clamp(0, mask.shape[0] - 1), uv[:, 0].clamp(0, mask.shape[1] - 1)].sum())
        total += len(uv)
    assert len(tracks.basis) >= 5 and total >= 10 * len(tracks.basis) // 2, (len(tracks.basis), total)
    assert on >= 0.85 * total, (on, total)      # 0.91 here; 0.75 with every hot pixel and no static test
