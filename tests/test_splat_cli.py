"""`recon splat-render` and the OpenGL camera-to-world -> OpenCV viewmat conversion."""
import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from recon.cli import main
from recon.splat import rasterization
from recon.splat.cameras import viewmat_from_c2w_opengl
from recon.splat.ply import write_gaussians_ply
from tests.splat_scenes import look_at, random_gaussians


def test_opengl_pose_converts_to_opencv_viewmat():
    # OpenGL camera at (0,0,5) with identity rotation looks down -z: the origin is 5 in front
    c2w = np.eye(4)
    c2w[2, 3] = 5.0
    view = viewmat_from_c2w_opengl(c2w)
    point = view @ torch.tensor([0.0, 1.0, 0.0, 1.0])  # world +y is up: image y (down) is negative
    assert torch.allclose(point[:3], torch.tensor([0.0, -1.0, 5.0]))


def test_conversion_inverts_an_opencv_look_at():
    view = look_at((1.0, -2.0, 3.0), (0.2, 0.1, 0.0))
    c2w_gl = torch.linalg.inv(view.double()) @ torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
    assert torch.allclose(viewmat_from_c2w_opengl(c2w_gl.numpy()), view, atol=1e-6)


def _dataset(tmp_path, view):
    c2w_gl = torch.linalg.inv(view.double()) @ torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
    meta = {"camera_model": "PINHOLE", "fl_x": 40.0, "fl_y": 44.0, "cx": 16.0, "cy": 12.5, "w": 33, "h": 25,
            "frames": [{"file_path": "rgb/0.png", "transform_matrix": np.eye(4).tolist()},
                       {"file_path": "rgb/1.png", "transform_matrix": c2w_gl.tolist(), "fl_x": 30.0}]}
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(meta))
    return path


def test_splat_render_matches_direct_rasterization(tmp_path):
    g = random_gaussians(60, 3, seed=3, sh_coeffs=4)
    logits = torch.logit(g.opacities)
    write_gaussians_ply(tmp_path / "m.ply", g.means, g.quats, g.log_scales, logits, g.features)
    view = look_at((0.3, -0.2, -4.0), (0.0, 0.0, 0.0))
    transforms = _dataset(tmp_path, view)
    out_png = tmp_path / "out" / "r.png"
    code = main(["splat-render", str(tmp_path / "m.ply"), "--transforms", str(transforms), "--frame", "1",
                 "--out", str(out_png), "--background", "0.2,0.4,1"])
    assert code == 0
    png = np.asarray(Image.open(out_png))
    with torch.no_grad():
        ref = rasterization(g.means, g.quats, g.log_scales, torch.sigmoid(logits), g.features, view,
                            30.0, 44.0, 16.0, 12.5, 33, 25, background=torch.tensor([0.2, 0.4, 1.0]), sh_degree=1,
                            cull_beside=1.0)
    expected = (ref.image.clamp(0, 1) * 255).round().to(torch.uint8).numpy()
    assert png.shape == (25, 33, 3)
    assert np.abs(png.astype(int) - expected.astype(int)).max() <= 1
    assert ref.alpha.max() > 0.5 and (png != expected[0, 0]).any()  # the Gaussians are in view


def test_splat_render_leaves_out_a_giant_beside_the_view_unless_told(tmp_path, capsys):
    """One 20 m Gaussian 0.3 m in front of frame 0's camera and 5 m to its side covers the view
    when drawn; by default (`--cull-beside 1`, as recon draws its models) it is left out."""
    g = random_gaussians(1, 3, seed=4, sh_coeffs=1)
    means = torch.tensor([[-5.0, 0.0, -0.3]])       # frame 0: identity camera-to-world, OpenGL axes
    write_gaussians_ply(tmp_path / "m.ply", means, g.quats, torch.full((1, 3), math.log(20.0)),
                        torch.full((1,), 5.0), g.features)
    transforms = _dataset(tmp_path, torch.eye(4))
    pixels = {}
    for flag in ("1", "off"):
        out = tmp_path / f"{flag}.png"
        assert main(["splat-render", str(tmp_path / "m.ply"), "--transforms", str(transforms), "--out", str(out),
                     "--cull-beside", flag]) == 0
        pixels[flag] = np.asarray(Image.open(out))
    assert pixels["1"].max() == 0 and pixels["off"].min() > 0
    with pytest.raises(SystemExit) as exit_:
        main(["splat-render", str(tmp_path / "m.ply"), "--transforms", str(transforms),
              "--out", str(tmp_path / "x.png"), "--cull-beside", "-1"])
    assert exit_.value.code == 2 and "--cull-beside must be a number >= 0 or 'off'" in capsys.readouterr().err


def test_splat_render_errors_name_file_and_key(tmp_path, capsys):
    g = random_gaussians(5, 3, seed=1, sh_coeffs=1)
    write_gaussians_ply(tmp_path / "m.ply", g.means, g.quats, g.log_scales, torch.zeros(5), g.features)
    bad = tmp_path / "transforms.json"
    bad.write_text(json.dumps({"frames": [{"transform_matrix": np.eye(4).tolist(), "w": 8, "h": 8}]}))
    args = ["splat-render", str(tmp_path / "m.ply"), "--transforms", str(bad), "--out", str(tmp_path / "o.png")]
    assert main(args) == 2
    assert "transforms.json: frame 0 has no numeric 'fl_x'" in capsys.readouterr().out
    assert main(args[:4] + ["--frame", "3"] + args[4:]) == 2
    assert "--frame 3 out of range (the file has 1 frames)" in capsys.readouterr().out
    (tmp_path / "m.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    good = _dataset(tmp_path, look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0)))
    assert main(["splat-render", str(tmp_path / "m.ply"), "--transforms", str(good), "--out", str(tmp_path / "o.png")]) == 2
    assert "m.ply: format 'ascii' is not supported" in capsys.readouterr().out
