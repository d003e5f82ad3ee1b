"""Moving objects' paths from the thermal frames (recon/train/paths.py): triangulation from a
sweeping camera against known paths, blobs and tracks on drawn frames, and the whole chain on a
simulated family scene graded by the simulator's objects."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from recon.config import make_config
from recon.data import load_dataset
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.scene import Scene
from recon.train import paths as P
from recon.train.trainer import Trainer
from rig.sim.camera import look_at
from rig.sim.family import FamilyScene

pytestmark = pytest.mark.usefixtures("two_threads")


def sweep(times: np.ndarray, degrees: float, shake: float = 0.01) -> np.ndarray:
    """(T, 3, 4) projections of a handheld 160x120 camera 1.5 m away, 25 degrees above the floor,
    sweeping +-degrees about the origin over times at an uneven pace, its position shaking by
    `shake` metres (standard deviation)."""
    k = np.array([[150.0, 0, 80], [0, 150, 60], [0, 0, 1]])
    rng = np.random.default_rng(1)
    out = []
    for t in times:
        az = np.radians(degrees * (2 * t ** 1.3 - 1))
        eye = 1.5 * np.array([np.cos(az) * np.cos(0.44), np.sin(az) * np.cos(0.44), np.sin(0.44)])
        out.append(k @ np.linalg.inv(look_at(eye + rng.normal(0, shake, 3), np.zeros(3)))[:3])
    return np.stack(out)


def half_circle(times: np.ndarray) -> np.ndarray:
    a = np.pi * times
    return np.stack([0.25 * np.cos(a), 0.25 * np.sin(a) - 0.1, np.full_like(a, 0.08)], 1)


def pixels_of(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = np.einsum("tij,tj->ti", projections, np.concatenate([points, np.ones((len(points), 1))], 1))
    return p[:, :2] / p[:, 2:]


def test_a_sweeping_camera_triangulates_a_moving_object_and_a_still_one_cannot():
    """One ray per instant: from a rig sweeping +-40 degrees the smooth path through the rays is the
    object's own (within 2 cm, pixels off by up to 0.3 px); from a camera that does not move, the same
    object could be anywhere along its rays (off by more than 20 cm), which is why a single view's
    loss cannot place it."""
    times = np.linspace(0, 1, 40)
    truth = half_circle(times)
    noise = np.random.default_rng(0).uniform(-0.3, 0.3, (40, 2))
    up = np.array([0, 0, 1.0])
    moving = sweep(times, 40)
    knots = P.triangulate_path(times, moving, pixels_of(moving, truth) + noise, 11, 1.0, 1e4, up)
    fitted = P.hat_basis(times, 11) @ knots
    assert np.linalg.norm(fitted - truth, axis=1).max() < 0.02
    assert np.median(P.reprojection_errors(knots, times, moving, pixels_of(moving, truth) + noise)) < 0.5
    still = sweep(np.full(40, 0.5), 0)
    knots = P.triangulate_path(times, still, pixels_of(still, truth) + noise, 11, 1.0, 0.0, None)
    assert np.linalg.norm(P.hat_basis(times, 11) @ knots - truth, axis=1).max() > 0.2


def test_a_robust_fit_halves_the_pull_of_frames_whose_blob_merged_and_leaves_clean_frames_alone():
    """Five frames whose centroid is pulled 8 px (a blob merged with something beside it) move the
    least-squares path by decimetres: a smooth path scaled about the camera explains them (the
    depth is the ill-measured direction). Soft-L1 beyond 1 px (`PathConfig.robust_px`) at least
    halves that; on clean frames it gives the least-squares path."""
    times = np.linspace(0, 1, 40)
    truth = half_circle(times)
    up = np.array([0, 0, 1.0])
    cams = sweep(times, 40)
    clean = pixels_of(cams, truth) + np.random.default_rng(0).uniform(-0.3, 0.3, (40, 2))
    merged = clean.copy()
    merged[12:17] += np.array([8.0, 3.0])

    def error(pixels, robust):
        knots = P.triangulate_path(times, cams, pixels, 11, 1.0, 1e4, up, robust_px=robust)
        return np.median(np.linalg.norm(P.hat_basis(times, 11) @ knots - truth, axis=1))

    plain, robust = error(merged, 0.0), error(merged, 1.0)
    assert plain > 0.2 and robust < 0.6 * plain
    assert abs(error(clean, 1.0) - error(clean, 0.0)) < 1e-3 and error(clean, 1.0) < 0.01


def test_a_paths_covariance_matches_the_spread_of_its_fit_and_is_loose_along_the_rays_of_a_steady_rig():
    """knot_covariance predicts how far noise moves the fit: over 24 draws of 0.17 px noise the
    positions' spread along the rays is within a factor 2 of the predicted standard deviation, and
    across the rays it is millimetres. A steadier hand (2 mm of shake instead of 10) measures the
    depth far worse, as the path's family scaled about the camera fits nearly as well, and the
    covariance says so (over 3x looser along the rays)."""
    times = np.linspace(0, 1, 40)
    truth = half_circle(times)
    up = np.array([0, 0, 1.0])
    prior = P.path_priors(11, 1.0, 1e4, up)
    ones = np.ones((40, 2))

    def along(cams, noise_seed):
        pixels = pixels_of(cams, truth) + np.random.default_rng(noise_seed).uniform(-0.3, 0.3, (40, 2))
        knots = P.triangulate_path(times, cams, pixels, 11, 1.0, 1e4, up)
        return knots, pixels

    def rays(cams):
        eyes = np.stack([-np.linalg.inv(c[:, :3]) @ c[:, 3] for c in cams])
        d = truth - eyes
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def predicted(cams, knots, pixels):
        cov = P.knot_covariance(knots, times, cams, pixels, prior, ones, 0.0)
        path = P.TrackedPath(torch.as_tensor(knots), 0.5, 0.05, 0.0, 0.0, 40, {}, cov)
        c = path.covariance_at(times)
        d = rays(cams)
        return np.sqrt(np.einsum("ti,tij,tj->t", d, c, d)), np.sqrt(np.linalg.eigvalsh(c)[:, 0])

    cams = sweep(times, 40)
    fits = [along(cams, seed) for seed in range(24)]
    positions = np.stack([P.hat_basis(times, 11) @ k for k, _ in fits])        # (24, T, 3)
    spread = np.sqrt(np.mean(np.einsum("stj,tj->st", positions - truth, rays(cams)) ** 2, 0))
    sigma, across = predicted(cams, *fits[0])
    ratio = np.median(spread) / np.median(sigma)
    assert 0.5 < ratio < 2.0, (np.median(spread), np.median(sigma))
    assert np.median(across) < 0.005
    steady = sweep(times, 40, shake=0.002)
    loose, _ = predicted(steady, *along(steady, 0))
    assert np.median(loose) > 3 * np.median(sigma)


def disc(frame: np.ndarray, centre, radius: float, kelvin: float) -> None:
    yy, xx = np.mgrid[: frame.shape[0], : frame.shape[1]] + 0.5
    frame[(xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius ** 2] = kelvin


def test_a_path_that_stops_stays_put_where_its_frames_show_a_rest():
    """An object that covers a half circle by t = 0.4 and then stands still, seen by a rig that
    sweeps at an uneven pace: rest_windows finds the rest (one still point explains those frames
    within 1 px) and finds none on an object that keeps moving. With the rest's knots held
    together the still part of the path lies nearer the object than the plain fit's, which
    slides along the rays (its smoothness does not charge a steady pace), and its pixels fit as
    well."""
    times = np.linspace(0, 1, 40)
    truth = half_circle(np.minimum(2.5 * times, 1.0))
    up = np.array([0, 0, 1.0])
    cams = sweep(times, 40, shake=0.003)
    pixels = pixels_of(cams, truth) + np.random.default_rng(0).uniform(-0.3, 0.3, (40, 2))
    ones = np.ones((40, 2))

    rests = P.rest_windows(times, cams, pixels, ones, 1.0, 10)
    assert len(rests) == 1 and 0.38 <= rests[0][0] <= 0.5 and rests[0][1] == 1.0
    assert P.rest_windows(times, cams, pixels_of(cams, half_circle(times)), ones, 1.0, 10) == []

    still = times >= 0.45
    plain = P.triangulate_path(times, cams, pixels, 11, 1.0, 1e4, up)
    held = P.triangulate_path(times, cams, pixels, 11, 1.0, 1e4, up, rests=rests, rest_weight=1e4)
    error = lambda knots: np.linalg.norm(P.hat_basis(times, 11) @ knots - truth, axis=1)     # noqa: E731
    assert np.median(error(held)[still]) < 0.5 * np.median(error(plain)[still])
    assert np.median(error(held)[still]) < 0.01
    assert np.median(P.reprojection_errors(held, times, cams, pixels)) < 0.5


def test_blobs_link_into_one_track_per_object_and_part_at_a_hotter_level():
    """A hot disc moving across the frame, a still warm one and a cold one: one track each over all
    20 frames. Where the moving disc touches the warm one, the 10 K level sees one blob and the
    40 K level the hot disc alone."""
    settings = P.PathConfig()
    frames = []
    for i in range(20):
        f = np.full((60, 80), 295.0)
        disc(f, (40, 30), 6, 320)                     # warm, still
        disc(f, (10 + 3 * i, 15), 5, 360)             # hot, moving right
        disc(f, (65, 50), 5, 270)                     # cold, still
        frames.append(f)
    blobs = [P.frame_blobs(f, None, i / 19, 10.0, settings) for i, f in enumerate(frames)]
    tracks = P.link_tracks(blobs, 80)
    assert sorted(len(t) for t in tracks) == [20, 20, 20]
    assert sorted(t[0].sign for t in tracks) == [-1, 1, 1]
    hot = next(t for t in tracks if t[0].sign > 0 and t[0].centroid[1] < 20)
    assert np.allclose([b.centroid[0] for b in hot], [10 + 3 * i for i in range(20)], atol=0.5)
    touching = np.full((60, 80), 295.0)
    disc(touching, (40, 30), 6, 320)
    disc(touching, (40, 19), 5, 360)
    assert len(P.frame_blobs(touching, None, 0.0, 10.0, settings)) == 1
    (hottest,) = P.frame_blobs(touching, None, 0.0, 40.0, settings)
    assert np.allclose(hottest.centroid, (40, 19), atol=0.5)


def test_a_track_does_not_jump_to_an_object_of_another_temperature_across_a_gap():
    """A still cup (340 K) is hidden from frame 8 on; a can (352 K) comes out from behind it at
    frame 11, moving right. By position alone the can continues the cup's track (one track, two
    objects: family-inside seed 49's can path was the cup's for its first third, 0.5-0.7 m off).
    With `link_kelvin` 3 the can starts its own track; blobs keep their median temperature."""
    settings = P.PathConfig()
    frames = []
    for i in range(24):
        f = np.full((60, 80), 295.0)
        if i < 8:
            disc(f, (30, 30), 5, 340)
        if i >= 11:
            disc(f, (32 + 2 * (i - 11), 31), 5, 352)
        frames.append(f)
    blobs = [P.frame_blobs(f, None, i / 23, 10.0, settings) for i, f in enumerate(frames)]
    assert blobs[0][0].kelvin == 340 and blobs[20][0].kelvin == 352
    assert sorted(len(t) for t in P.link_tracks(blobs, 80)) == [21]
    apart = P.link_tracks(blobs, 80, max_kelvin=3.0)
    assert sorted(len(t) for t in apart) == [8, 13]
    assert all(len({b.kelvin for b in t}) == 1 for t in apart)


def test_a_blob_is_whole_by_its_neighbours_size_when_its_object_nears_the_camera():
    """An object nearing the camera grows smoothly (60 -> 280 px over 24 frames), as family-inside
    seed 42's ball: against the track's 25th percentile every frame from the 13th on looks merged,
    while the cut one passes, and too few are left to fit (that ball was never learned). Against the
    median of the 3 blobs either side every frame is whole but the cut one (half the area) and the
    merged one (twice)."""
    areas = np.linspace(60, 280, 24).astype(int)
    areas[8] //= 2                     # cut by a cup in front of it
    areas[16] *= 2                     # merged with a hot thing behind it
    blobs = [P.Blob(i / 23, np.zeros(2), int(a), 1, False, np.array([]), 160) for i, a in enumerate(areas)]

    def whole(window: int) -> list[int]:
        typical = P.typical_areas(blobs, window)
        return [i for i, a in enumerate(areas) if 0.6 <= a / typical[i] <= 1.6]
    assert whole(3) == [i for i in range(24) if i not in (8, 16)]
    assert whole(0) == list(range(1, 12)) and len(whole(0)) < P.PathConfig().min_frames


def test_a_still_cup_is_found_before_linking_and_a_ball_merged_with_it_is_not_fitted_there():
    """A hot cup stands where a hot ball on a half circle passes (both 160x120 discs, seen by a
    sweeping camera): at the instants they touch in the image they are one blob. The cup's blobs
    are one still group (every instant but the merged ones), found before any linking, so no
    track carries the cup; the ball's track keeps its own blobs and the merged ones, and the merged
    ones are the instants merged_times drops before its path is fitted (still_share is off by
    default: docs/training.md)."""
    settings = P.PathConfig(still_share=0.3)
    times = np.linspace(0, 1, 40)
    projections = sweep(times, 40)
    cup = np.array([0.0, 0.25, 0.08])
    at_cup = pixels_of(projections, np.repeat(cup[None], 40, 0))
    at_ball = pixels_of(projections, half_circle(times))
    frames = []
    for c, b in zip(at_cup, at_ball):
        f = np.full((120, 160), 295.0)
        disc(f, c, 6, 330)
        disc(f, b, 5, 350)
        frames.append(f)
    blobs = [P.frame_blobs(f, None, t, 10.0, settings) for f, t in zip(frames, times)]
    merged = {i for i in range(40) if len(blobs[i]) == 1}
    assert 4 <= len(merged) <= 20
    groups, rest = P.still_groups(blobs, projections, settings)
    (group,) = groups
    assert sorted(int(round(b.time * 39)) for b in group) == [i for i in range(40) if i not in merged]
    assert all(np.linalg.norm(b.centroid - at_cup[int(round(b.time * 39))]) < 0.5 for b in group)
    (ball,) = P.link_tracks(rest, 160)
    assert len(ball) == 40
    k = np.array([[150.0, 0, 80], [0, 150, 60], [0, 0, 1]])             # sweep()'s intrinsics
    cameras = {float(t): SimpleNamespace(fx=150.0, fy=150.0, cx=80.0, cy=60.0, width=160, height=120,
                                         viewmat=torch.as_tensor(np.vstack([np.linalg.inv(k) @ m, [0, 0, 0, 1]])))
               for t, m in zip(times, projections)}
    still = P.fit_track(group, cameras, np.array([0, 0, 1.0]), settings)
    assert still is not None and np.linalg.norm(still.at(0.5).numpy() - cup) < 0.03
    path = P.TrackedPath(torch.zeros(2, 3), 0.5, 0.05, 0.0, 99.0, 40, {b.time: b for b in ball})
    dropped = {int(round(t * 39)) for t in P.merged_times(path, [still], cameras)}
    assert dropped and dropped <= merged


@pytest.fixture(scope="module")
def family(tmp_path_factory):
    out = tmp_path_factory.mktemp("paths")
    simulate_dataset(out, SimulateConfig(variant="family-outside", frames=40, width=160, height=120, seed=43,
                                         points=1500))
    return Scene(load_dataset(out)), FamilyScene.build("outside", 43)


def object_paths(fam: FamilyScene, times: np.ndarray) -> np.ndarray:
    """(O, T, 3) the moving objects' centres at times (fractions of the sequence)."""
    return np.stack([[o.instance(t * fam.duration_s, fam.duration_s).position for t in times]
                     for o in fam.objects if o.moving])


def test_a_hold_on_rests_only_anchors_the_knots_inside_them():
    """priors.path_hold_rests: a body is held only at the knots inside its path's rests (the frames
    showed it still there), and the hold costs nothing for moving it elsewhere."""
    from recon.dtg.motion import MotionBases
    from recon.train.initial import measured_knots, resting_knots
    knots = torch.linspace(0, 1, 11)
    blobs = {t: None for t in np.linspace(0.1, 0.9, 20)}
    path = P.TrackedPath(torch.zeros(11, 3), 0.5, 0.05, 0.0, 0.0, 20, blobs, None, ((0.4, 0.7),))
    assert resting_knots(knots, path).tolist() == [False] * 4 + [True] * 4 + [False] * 3
    assert measured_knots(knots, path).sum() == 11
    assert not resting_knots(knots, P.TrackedPath(torch.zeros(11, 3), 0.5, 0.05, 0.0, 0.0, 20, blobs)).any()

    motion = MotionBases(torch.zeros(1, 3), 11)
    with torch.no_grad():
        motion.anchored[0] = resting_knots(knots, path)
        motion.anchor_precision[0] = torch.eye(3).expand(11, 3, 3) * 1e4
        motion.translation[0, :4] += 0.1            # moved where the object moves: free
    assert float(motion.hold_cost().detach()) == 0.0
    with torch.no_grad():
        motion.translation[0, 5] += 0.1             # moved where it rests: held
    assert float(motion.hold_cost().detach()) > 0.0


def test_the_thermal_frames_give_the_moving_objects_paths(family):
    """family-outside seed 43 (three moving objects, a hot cup, a warm spot): every path found
    follows a moving object (median over the sequence within 10 cm; measured 2-7 cm), at least two
    objects are found, and the still hot things are not taken for moving ones."""
    scene, fam = family
    found = P.tracked_paths(scene).moving
    times = np.linspace(0, 1, 40)
    truth = object_paths(fam, times)
    matched = set()
    for path in found:
        err = np.median(np.linalg.norm(path.at(torch.as_tensor(times)).numpy()[None] - truth, axis=2), 1)
        assert err.min() < 0.10, err
        matched.add(int(err.argmin()))
    assert len(matched) == len(found) >= 2


def test_training_builds_its_bodies_on_the_tracked_paths(family, tmp_path):
    """With curriculum.tracked_paths a run starts with one body per path: its pivot where the path
    is at the body's instant, its translation knots along the path, and no growing window; a
    resumed run keeps both. The priors that read the bodies (path_hold, body_temperature) take
    part in the loss, and the paths' precision is saved with the model."""
    scene, fam = family
    cfg = make_config("dtg", iterations=30, log_every=10**9, checkpoint_every=10**9, eval_every=10**9)
    cfg.curriculum.tracked_paths = True
    cfg.priors.path_hold, cfg.priors.body_temperature = 0.1, 1.0
    messages = []
    tr = Trainer(cfg, scene, log=messages.append)
    found = P.tracked_paths(scene).moving
    motion = tr.model.motion
    assert motion.count == len(found) >= 2, messages
    assert not tr.window.enabled and any("paths tracked in the thermal frames" in m for m in messages)
    knots = torch.linspace(0, 1, motion.translation.shape[1])
    for b, path in enumerate(found):
        assert torch.allclose(motion.pivots[b] + motion.translation[b].detach(), path.at(knots), atol=1e-5)
    assert motion.anchored.any(1).all() and torch.equal(motion.anchors, motion.translation.detach())
    assert bool((motion.anchor_precision[motion.anchored] > 0).any())
    while not tr.done():
        stats = tr.step()
    assert torch.isfinite(motion.translation).all()
    assert stats["basis_hold"] >= 0 and stats["body_warmth"] >= 0
    tr.save_checkpoint(tmp_path / "latest.pt")
    back = Trainer.resume(tmp_path / "latest.pt", scene, log=messages.append)
    assert not back.window.enabled and back.model.motion.count == motion.count
    assert torch.equal(back.model.motion.translation, motion.translation)
    assert torch.equal(back.model.motion.anchors, motion.anchors) and torch.equal(back.model.motion.anchored, motion.anchored)
    assert torch.equal(back.model.motion.anchor_precision, motion.anchor_precision)


def test_blobs_cut_by_one_border_add_the_coordinate_along_it():
    """A ball on a half circle whose blob is whole in 8 of 40 frames and cut by the image's left
    border in the other 32 (its centroid pulled 3 px inwards; drawn frames flag the cut side, a
    corner both). Whole frames alone are too few for a path (fitted anyway: 40 cm off). With
    `border_frames` each cut frame adds its centroid's y and counts as half a frame: the path is
    found within 10 cm of the ball (measured 6.5 cm: the sweep is horizontal, so x carries most of
    the parallax); the cut frames taken whole, their pulled x included, put it 16 cm off. 8 whole
    and 5 cut frames are too few."""
    f = np.full((120, 160), 295.0)
    disc(f, (2, 60), 6, 340)
    disc(f, (157, 118), 6, 340)
    cuts = sorted(b.cut for b in P.frame_blobs(f, None, 0.0, 10.0, P.PathConfig()))
    assert cuts == [(True, False), (True, True)]

    times = np.linspace(0, 1, 40)
    truth = half_circle(times)
    projections = sweep(times, 40)
    pixels = pixels_of(projections, truth) + np.random.default_rng(0).uniform(-0.3, 0.3, (40, 2))
    whole = set(range(0, 40, 5))
    blobs = [P.Blob(t, xy if i in whole else xy + np.array([3.0, 0.0]), 110, 1, i not in whole, np.array([]), 160,
                    cut=(False, False) if i in whole else (True, False))
             for i, (t, xy) in enumerate(zip(times, pixels))]
    k = np.array([[150.0, 0, 80], [0, 150, 60], [0, 0, 1]])             # sweep()'s intrinsics
    cameras = {float(t): SimpleNamespace(fx=150.0, fy=150.0, cx=80.0, cy=60.0, width=160, height=120,
                                         viewmat=torch.as_tensor(np.vstack([np.linalg.inv(k) @ m, [0, 0, 0, 1]])))
               for t, m in zip(times, projections)}
    up = np.array([0, 0, 1.0])
    assert P.fit_track(blobs, cameras, up, P.PathConfig(border_frames=False)) is None
    path = P.fit_track(blobs, cameras, up, P.PathConfig())             # border_frames: the default
    assert path is not None and path.frames == 40 and not path.seen[times[1]].cut[1]
    off = np.linalg.norm(path.at(torch.as_tensor(times)).numpy() - truth, axis=1)
    assert np.median(off) < 0.1
    few = [b for i, b in enumerate(blobs) if i in whole or i < 7]     # 8 whole + 5 cut: 10.5 frames' worth
    assert P.fit_track(few, cameras, up, P.PathConfig()) is None
    taken_whole = P.triangulate_path(times, projections, np.stack([b.centroid for b in blobs]), 11, 1.0, 1e4, up)
    assert np.median(np.linalg.norm(P.hat_basis(times, 11) @ taken_whole - truth, axis=1)) > 2 * np.median(off)
