"""bench/ must keep running against the code it measures (issue 14: every script runs on a fresh
install). Once, a changed native signature broke bench/rasterizer.py's records for weeks while it
still exited 0; these cheap runs catch that in CI."""
import importlib
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_bench_script_imports():
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        for script in sorted((ROOT / "bench").glob("*.py")):
            importlib.import_module(script.stem)  # a missing dependency raises here
    finally:
        sys.path.remove(str(ROOT / "bench"))


def test_rasterizer_bench_measures_our_implementations(tmp_path):
    out = tmp_path / "r.json"
    impls = ["recon.splat", "recon.splat:raster", "recon.splat:proj", "recon.splat:train"]
    run = subprocess.run([sys.executable, "bench/rasterizer.py", "--out", str(out), "--sizes", "2000",
                          "--reps", "5", "--impls", ",".join(impls)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    records = json.loads(out.read_text())
    assert [r["impl"] for r in records] == impls
    for r in records:
        assert r["forward_ms"] > 0 and r["forward_backward_ms"] > 0, r
    stages = records[0]["breakdown_ms"]
    assert stages["tile_pairs"] > 0 and stages["visible"] > 1000, stages


def test_trained_model_bench_measures_two_checkouts(tmp_path):
    """bench/raster_trained.py against a second checkout (here: this one again) on a small PLY."""
    import torch

    from recon.data.frame import c2w_opencv_to_opengl
    from recon.splat.ply import write_gaussians_ply
    from tests.splat_scenes import look_at, random_gaussians

    g = random_gaussians(300, 3, seed=4)
    write_gaussians_ply(tmp_path / "m.ply", g.means, g.quats, g.log_scales, torch.logit(g.opacities),
                        g.features[:, None, :])
    c2w_gl = c2w_opencv_to_opengl(torch.linalg.inv(look_at((0.3, -0.2, -4.0), (0.0, 0.0, 0.0)).double()).numpy())
    (tmp_path / "transforms.json").write_text(json.dumps(
        {"fl_x": 40.0, "fl_y": 40.0, "cx": 24.0, "cy": 16.0, "w": 48, "h": 32,
         "frames": [{"file_path": "rgb/0.png", "transform_matrix": c2w_gl.tolist()}]}))
    out = tmp_path / "rt.json"
    run = subprocess.run([sys.executable, "bench/raster_trained.py", "--ply", str(tmp_path / "m.ply"),
                          "--transforms", str(tmp_path / "transforms.json"), "--scale", "1,2", "--reps", "2",
                          "--against", str(ROOT), "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    result = json.loads(out.read_text())
    builds = [r for r in result["rounds"] if "checkout" in r]
    assert len(builds) == 4 and {r["size"] for r in builds} == {"48x32", "96x64"}
    for name in ("this x1", "against x2"):
        assert result["median"][name]["tile_pairs"] > 0 and result["median"][name]["total"] > 0
    paired = [r for r in result["rounds"] if "paired" in r]
    assert len(paired) == 2 and all(r["paired"] > 0 and r["max_image_diff"] == 0.0 for r in paired), paired


def test_long_gaussians_bench_measures_what_training_views_see(tmp_path):
    """bench/long_gaussians.py: its two measures checked on known cases, then a run end to end."""
    import math

    import torch

    from recon.splat.cameras import PinholeCamera
    from tests.splat_scenes import look_at, random_gaussians

    sys.path.insert(0, str(ROOT / "bench"))
    try:
        lg = importlib.import_module("long_gaussians")
    finally:
        sys.path.remove(str(ROOT / "bench"))
    camera = PinholeCamera(look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0)).float(), 40.0, 40.0, 24.0, 16.0, 48, 32)
    # a needle (1 x 0.01 x 0.01) along the ray through the origin, then turned across it
    along = {"means": torch.zeros(2, 3), "log_scales": torch.tensor([[0.01, 0.01, 1.0]] * 2).log(),
             "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0], [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]])}
    extent, seen = lg.across_ray(along, camera)
    assert seen.all()
    assert abs(float(extent[0]) - 0.01) < 1e-4 and abs(float(extent[1]) - 1.0) < 1e-4
    # blending weights summed over Gaussians are the render's coverage, pixel for pixel summed
    g = random_gaussians(40, 1, seed=3)
    g = {"means": g.means, "quats": g.quats, "log_scales": g.log_scales, "opacities": g.opacities}
    weights = lg.pixel_weights(g, camera)
    out = lg.rasterization(g["means"], g["quats"], g["log_scales"], g["opacities"], torch.zeros(40, 1, 1),
                           *camera.args(), sh_degree=0)
    assert (weights >= 0).all() and abs(float(weights.sum()) - float(out.alpha.sum())) < 1e-3 * float(out.alpha.sum())

    def cli(*argv):
        done = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stdout + done.stderr

    cli("recon", "simulate", "d", "--frames", "4", "--size", "48x36", "--points", "300")
    cli("recon", "run", "d", "--out", "r", "--iterations", "20", "--threads", "1")
    cli(sys.executable, str(ROOT / "bench" / "long_gaussians.py"), "r", "--out", "o.json")
    (result,) = json.loads((tmp_path / "o.json").read_text())
    assert set(result["graded"]) == set(lg.VARIANTS)
    none = result["graded"]["none"]
    assert none["rgb_psnr"] > 10 and none["thermal_mae_k"] > 0
    assert result["under_weight"]["0.05"] <= result["under_weight"]["1.0"] <= result["gaussians"]
