"""Rasterizer benchmark: `python bench/rasterizer.py --out FILE.json`.

Times forward and forward+backward at 320x240 for N = 2k, 10k, 50k, 200k Gaussians of the research
note's workload (bench/splat_workload.py), cycling over its views, median of --reps runs after a
warm-up, each implementation in its own subprocess so peak RSS (VmHWM, reset after the workload
is built) is separable. Implementations:
  recon.splat          this project's native rasterizer (with a per-stage breakdown)
  dense-reference      tests/splat_reference.py in float32, pixel rows chunked with checkpointing
                       (only up to --dense-max-n: it evaluates every Gaussian at every pixel;
                       at 2k it already peaks at ~5 GB)
  recon.splat:proj     our projection + SH alone, to compare with
  gsplat-1.5.3:proj    gsplat's pure-PyTorch projection + SH (its rasterizer needs CUDA);
                       skipped with a message when gsplat is not importable (--peers-dir helps)
  recon.splat:train    one whole static training step at each N: render (SH degree 3), L1 +
                       0.2 D-SSIM, backward, Adam (OpenSplat's CPU step takes ~510 ms at 50k)
  recon.splat:raster   our rasterizer alone (binning, sort, composite; Rasterize autograd Function)
                       on the projected visible Gaussians of each view, to compare with
  opensplat-2dc4583:raster  OpenSplat's CPU rasterizer (rasterize_forward/backward_tensor_cpu,
                       single-threaded by design) on the same projected inputs; built out of tree
                       from DIR/OpenSplat (AGPL-3.0, never copied here) with --peers-dir DIR,
                       compiled once into a cache under /tmp; skipped with a message without it
Records: {"impl","n","width","height","threads","forward_ms","forward_backward_ms","peak_rss_mb"}
plus "forward_min_ms", "forward_backward_min_ms" (fastest run), "scope", "scale_k", "reps", "load_avg_1min" (other load on the machine skews timings),
"omp_wait_policy"; recon.splat and recon.splat:proj add "breakdown_ms" (native stages), the OpenSplat
record "image_vs_ours_max_abs"/"_mean_abs" (its image vs ours on view 0: same inputs, its conventions)
and "source".
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OPENSPLAT_COMMIT = "2dc4583e6f46317b8429ce7b9b792add38db8bcd"
OPENSPLAT = f"opensplat-{OPENSPLAT_COMMIT[:7]}:raster"
OPENSPLAT_CPU_DIR = Path("OpenSplat/rasterizer/gsplat-cpu")  # under --peers-dir
IMPLS = ["recon.splat", "dense-reference", "recon.splat:proj", "gsplat-1.5.3:proj", "recon.splat:train",
         "recon.splat:raster", OPENSPLAT]
EPILOG = f"""examples:
  python bench/rasterizer.py --out bench/results/rasterizer.json
  python bench/rasterizer.py --out /tmp/r.json --sizes 50000 --impls recon.splat,recon.splat:train
  python bench/rasterizer.py --out /tmp/r.json --peers-dir /tmp/peers
peers in --peers-dir DIR (not part of this project):
  gsplat:    pip install --target DIR gsplat==1.5.3 --no-deps && pip install --target DIR jaxtyping rich
  OpenSplat: git clone https://github.com/pierotofy/OpenSplat DIR/OpenSplat &&
             git -C DIR/OpenSplat checkout {OPENSPLAT_COMMIT}
             (needs ninja: pip install ninja; built once into {tempfile.gettempdir()}/thermal4d-bench-opensplat)
"""


# ---------------------------------------------------------------- worker side (one subprocess)

def _reset_peak_rss() -> None:
    Path("/proc/self/clear_refs").write_text("5")  # Linux: VmHWM := current RSS


def _peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


_MINIMA: list[float] = []  # min of each _timed() call, in call order (load-robust companion)


def _timed(fn, reps: int) -> float:
    """Median wall time in ms of fn(rep) over reps runs, after one warm-up."""
    fn(0)
    times = []
    for rep in range(reps):
        start = time.perf_counter()
        fn(rep + 1)
        times.append(1e3 * (time.perf_counter() - start))
    _MINIMA.append(min(times))
    return statistics.median(times)


def _params(w, torch, sh: bool):
    from recon.dtg.gaussians import value_to_sh_dc

    feats = w.colors
    if sh:  # degree-3 SH whose DC term reproduces the colours
        feats = torch.zeros(w.colors.shape[0], 16, 3)
        feats[:, 0] = value_to_sh_dc(w.colors)
    return [t.clone().requires_grad_(True) for t in (w.means, w.quats, w.log_scales, w.opacities, feats)]


def _bench_ours(w, reps, threads):
    import torch

    from recon.splat import rasterization

    params = _params(w, torch, sh=False)
    nv = len(w.viewmats)

    def render(rep):
        return rasterization(*params, w.viewmats[rep % nv], w.fx, w.fy, w.cx, w.cy, w.width, w.height, threads=threads)

    def forward(rep):
        with torch.no_grad():
            render(rep)

    def forward_backward(rep):
        out = render(rep)
        (out.image.sum() + out.alpha.sum()).backward()

    return _timed(forward, reps), _timed(forward_backward, reps), {"breakdown_ms": _breakdown(w, reps, threads)}


def _breakdown(w, reps, threads) -> dict:
    """Median ms of each native stage on view 0 (what the Python wrapper adds is the rest)."""
    import numpy as np

    from recon.splat import _native

    a = lambda t: t.detach().numpy()  # noqa: E731
    cam = _intrinsics(w)
    g = (a(w.means), a(w.quats), a(w.log_scales))
    vm = a(w.viewmats[0])
    stage = {}
    m2, con, dep, rad, _ = _native.project_forward(*g, a(w.opacities), vm, *cam, None, 0, threads)
    stage["projection"] = _timed(lambda _: _native.project_forward(*g, a(w.opacities), vm, *cam, None, 0, threads),
                                 reps)
    raster = lambda: _native.rasterize_forward(m2, con, a(w.colors), a(w.opacities), dep, rad,  # noqa: E731
                                               w.width, w.height, 1 << 28, threads)
    bins = [raster()[-1] for _ in range(reps)]
    stage["binning_sort"] = 1e3 * statistics.median(bins)
    stage["composite"] = _timed(lambda _: raster(), reps) - stage["binning_sort"]
    image, alpha, _, final_t, last, tx, ty, offsets, ids, boxes, _ = raster()
    grads = (np.ones_like(image), np.ones_like(alpha), np.zeros_like(alpha))
    bwd = lambda: _native.rasterize_backward(m2, con, a(w.colors), a(w.opacities), dep, rad, w.width,  # noqa: E731
                                             w.height, final_t, last, tx, ty, offsets, ids, boxes, *grads, threads)
    stage["composite_backward"] = _timed(lambda _: bwd(), reps)
    v = bwd()
    stage["projection_backward"] = _timed(
        lambda _: _native.project_backward(*g, rad, vm, *cam, v[0], v[1], v[4], None, None, None, 0, threads), reps)
    stage["tile_pairs"] = int(len(ids))
    stage["visible"] = int((rad > 0).sum())
    return {k: (round(x, 3) if isinstance(x, float) else x) for k, x in stage.items()}


def _bench_dense(w, reps, threads, chunk_rows=8):
    import torch
    from torch.utils.checkpoint import checkpoint

    sys.path.insert(0, str(ROOT))
    from tests import splat_reference as ref

    params = _params(w, torch, sh=False)
    nv = len(w.viewmats)

    def render(rep):
        means, quats, log_scales, opacities, colors = params
        view = w.viewmats[rep % nv]
        means2d, conics, depths, _ = ref.project(means, quats, log_scales, view, w.fx, w.fy, w.cx, w.cy,
                                                 w.width, w.height)
        valid = (depths >= 0.01) & (opacities >= 1 / 255)
        means2d = torch.where(valid[:, None], means2d, torch.zeros_like(means2d))
        conics = torch.where(valid[:, None], conics, torch.ones_like(conics))
        rows = []
        for y0 in range(0, w.height, chunk_rows):
            h = min(chunk_rows, w.height - y0)
            shifted = means2d - torch.tensor([0.0, float(y0)])
            rows.append(checkpoint(ref.composite, shifted, conics, colors, opacities, depths, valid, w.width, h,
                                   use_reentrant=False))
        return torch.cat([r[0] for r in rows]), torch.cat([r[1] for r in rows])

    def forward(rep):
        with torch.no_grad():
            render(rep)

    def forward_backward(rep):
        image, alpha = render(rep)
        (image.sum() + alpha.sum()).backward()

    return _timed(forward, reps), _timed(forward_backward, reps), {}


def _projection_inputs(w, torch):
    params = _params(w, torch, sh=True)
    return params, [w.viewmats[i % len(w.viewmats)] for i in range(64)]


def _bench_our_projection(w, reps, threads):
    import torch

    from recon.splat.rasterization import project

    params, views = _projection_inputs(w, torch)
    cam = _intrinsics(w)

    def run(rep):  # what rasterization() runs before compositing: one fused native pass
        means2d, conics, depths, _, colors = project(*params, views[rep], cam, 3, threads)
        return means2d.sum() + conics.sum() + depths.sum() + colors.sum()

    def forward(rep):
        with torch.no_grad():
            run(rep)

    return (_timed(forward, reps), _timed(lambda rep: run(rep).backward(), reps),
            {"breakdown_ms": _projection_breakdown(params, views[0], cam, reps, threads)})


def _projection_breakdown(params, view, cam, reps, threads) -> dict:
    """Median ms of the fused native projection + SH (degree 3) kernels on one view (the rest of
    a :proj record is torch: autograd, the sums and accumulating .grad)."""
    import numpy as np

    from recon.splat import _native

    means, quats, log_scales, opacities, sh = (t.detach().numpy() for t in params)
    args = (means, quats, log_scales, opacities, view.numpy(), *cam)
    fwd = lambda: _native.project_forward(*args, sh, 3, threads)  # noqa: E731
    means2d, conics, depths, radii, colors = fwd()
    ones = [np.ones_like(a) for a in (means2d, conics, depths, colors)]
    bwd = lambda: _native.project_backward(means, quats, log_scales, radii, view.numpy(), *cam,  # noqa: E731
                                           *ones[:3], sh, colors, ones[3], 3, threads)
    return {"forward": round(_timed(lambda _: fwd(), reps), 3), "backward": round(_timed(lambda _: bwd(), reps), 3)}


def _bench_gsplat_projection(w, reps, threads):
    import torch
    from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci, _spherical_harmonics

    params, views = _projection_inputs(w, torch)
    means, quats, log_scales, _, sh = params
    K = torch.tensor([[w.fx, 0, w.cx], [0, w.fy, w.cy], [0, 0, 1.0]])[None]

    def run(rep):
        view = views[rep]
        covars, _ = _quat_scale_to_covar_preci(quats, log_scales.exp(), compute_preci=False)
        radii, means2d, depths, conics, _ = _fully_fused_projection(means, covars, view[None], K, w.width, w.height)
        campos = -view[:3, :3].T @ view[:3, 3]
        colors = (_spherical_harmonics(3, means - campos, sh) + 0.5).clamp_min(0)
        return means2d.sum() + conics.sum() + depths.sum() + colors.sum()

    def forward(rep):
        with torch.no_grad():
            run(rep)

    return _timed(forward, reps), _timed(lambda rep: run(rep).backward(), reps), {}


def _ssim(a, b, torch):
    """Mean SSIM of (1,C,H,W) images: 11x11 Gaussian window (sigma 1.5) as two separable passes."""
    x = torch.arange(11, dtype=a.dtype) - 5
    g = torch.exp(-(x**2) / (2 * 1.5**2))
    g = g / g.sum()
    ch = a.shape[1]
    conv = torch.nn.functional.conv2d
    blur = lambda t: conv(conv(t, g.view(1, 1, 1, 11).expand(ch, 1, 1, 11), padding=(0, 5), groups=ch),  # noqa: E731
                          g.view(1, 1, 11, 1).expand(ch, 1, 11, 1), padding=(5, 0), groups=ch)
    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    return (((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))).mean()


def _bench_train_step(w, reps, threads):
    import torch

    from recon.splat import rasterization

    params = _params(w, torch, sh=True)
    nv = len(w.viewmats)
    with torch.no_grad():  # targets: the model's own renders with shifted colours
        targets = [rasterization(*params, v, w.fx, w.fy, w.cx, w.cy, w.width, w.height, sh_degree=3).image * 0.9
                   for v in w.viewmats]
    optim = torch.optim.Adam(params, lr=1e-3, fused=True)

    def render(rep):
        return rasterization(*params, w.viewmats[rep % nv], w.fx, w.fy, w.cx, w.cy, w.width, w.height,
                             sh_degree=3, threads=threads)

    def forward(rep):
        with torch.no_grad():
            render(rep)

    def step(rep):
        optim.zero_grad(set_to_none=True)
        image = render(rep).image
        target = targets[rep % nv]
        loss = 0.8 * (image - target).abs().mean() + 0.2 * (
            1 - _ssim(image.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], torch))
        loss.backward()
        optim.step()
        with torch.no_grad():  # keep Adam from wandering off: quaternions stay non-zero, opacity in [0,1]
            params[3].clamp_(0.0, 1.0)

    return _timed(forward, reps), _timed(step, reps), {}


def _intrinsics(w) -> tuple:
    """The native projection's camera tuple for the workload's whole view (fx .. near_plane, window, beside)."""
    from recon.splat.rasterization import intrinsics

    return intrinsics(w.fx, w.fy, w.cx, w.cy, w.width, w.height, 0.01)


def _raster_inputs(w, torch, threads) -> list[tuple]:
    """Per view: our projection of its visible Gaussians -> (means2d (M,2), conics (M,3), colors (M,3),
    opacities (M,), depths (M,)), the inputs both rasterizer-only records composite."""
    from recon.splat.rasterization import project

    cam = _intrinsics(w)
    views = []
    with torch.no_grad():
        for view in w.viewmats:
            means2d, conics, depths, radii, colors = project(w.means, w.quats, w.log_scales, w.opacities, w.colors,
                                                             view, cam, None, threads)
            vis = radii > 0
            views.append(tuple(t[vis].contiguous() for t in (means2d, conics, colors, w.opacities, depths)))
    return views


def _bench_our_raster(w, reps, threads):
    import torch

    from recon.splat._functions import Rasterize
    from recon.splat.rasterization import MAX_TILE_PAIRS

    views = _raster_inputs(w, torch, threads)

    def raster(rep, grad: bool):
        means2d, conics, colors, opacities, depths = (t.requires_grad_(grad) for t in views[rep % len(views)])
        radii = torch.ones(len(depths), dtype=torch.int32)  # all visible (culled before)
        return Rasterize.apply(means2d, conics, colors, opacities, depths, radii, w.width, w.height,
                               MAX_TILE_PAIRS, threads)

    def forward(rep):
        with torch.no_grad():
            raster(rep, False)

    def forward_backward(rep):
        image, alpha, _ = raster(rep, True)
        (image.sum() + alpha.sum()).backward()

    return _timed(forward, reps), _timed(forward_backward, reps), {}


# Our glue, not OpenSplat code: exposes its CPU rasterizer to Python and owns the per-pixel
# Gaussian lists (px2gid) its forward returns for its backward (freed as OpenSplat's training
# step does after the backward).
_OPENSPLAT_GLUE = r"""
#include <torch/extension.h>
#include "bindings.h"

struct PixelLists {
  std::vector<int32_t>* px2gid = nullptr;
  PixelLists() = default;
  PixelLists(const PixelLists&) = delete;
  ~PixelLists() { delete[] px2gid; }
};

py::tuple forward(int width, int height, torch::Tensor xys, torch::Tensor conics, torch::Tensor colors,
                  torch::Tensor opacities, torch::Tensor background, torch::Tensor cov2d, torch::Tensor depths) {
  auto out = rasterize_forward_tensor_cpu(width, height, xys, conics, colors, opacities, background, cov2d, depths);
  auto lists = std::make_shared<PixelLists>();
  lists->px2gid = std::get<2>(out);
  return py::make_tuple(std::get<0>(out), std::get<1>(out), lists);
}

py::tuple backward(int width, int height, torch::Tensor xys, torch::Tensor conics, torch::Tensor colors,
                   torch::Tensor opacities, torch::Tensor background, torch::Tensor cov2d, torch::Tensor depths,
                   torch::Tensor final_ts, std::shared_ptr<PixelLists> lists, torch::Tensor v_image,
                   torch::Tensor v_alpha) {
  auto g = rasterize_backward_tensor_cpu(height, width, xys, conics, colors, opacities, background, cov2d, depths,
                                         final_ts, lists->px2gid, v_image, v_alpha);
  return py::make_tuple(std::get<0>(g), std::get<1>(g), std::get<2>(g), std::get<3>(g));
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  py::class_<PixelLists, std::shared_ptr<PixelLists>>(m, "PixelLists");
  m.def("forward", &forward);
  m.def("backward", &backward);
}
"""


def _opensplat_extension(peers_dir: str):
    """OpenSplat's gsplat_cpu.cpp + our glue, compiled once (ninja caches it) under /tmp."""
    from torch.utils.cpp_extension import load

    src = Path(peers_dir).resolve() / OPENSPLAT_CPU_DIR
    build = Path(tempfile.gettempdir()) / "thermal4d-bench-opensplat"
    build.mkdir(parents=True, exist_ok=True)
    glue = build / "glue.cpp"
    if not glue.exists() or glue.read_text() != _OPENSPLAT_GLUE:
        glue.write_text(_OPENSPLAT_GLUE)
    # -O3 as OpenSplat's CMake Release build; -march=native as ours
    return load("opensplat_cpu_raster", [str(glue), str(src / "gsplat_cpu.cpp")], extra_include_paths=[str(src)],
                extra_cflags=["-O3", "-march=native"], build_directory=str(build))


def _bench_opensplat(w, reps, threads, peers_dir):
    import torch

    ext = _opensplat_extension(peers_dir)
    background = torch.zeros(3)
    views = _raster_inputs(w, torch, threads)
    inputs = []
    for means2d, conics, colors, opacities, depths in views:
        a, b, c = conics.unbind(-1)
        det = a * c - b * b  # OpenSplat also takes cov2d (its 3-sigma box) = conic^-1
        cov2d = torch.stack([c / det, -b / det, -b / det, a / det], -1).reshape(-1, 2, 2)
        # its pixel (j, i) is at (j, i), ours at (j + 0.5, i + 0.5): shift to render the same image
        inputs.append((means2d - 0.5, conics, colors, opacities, background, cov2d, depths))
    ones = (torch.ones(w.height, w.width, 3), torch.ones(w.height, w.width))

    def forward(rep):
        ext.forward(w.width, w.height, *inputs[rep % len(inputs)])  # its px2gid lists are freed on return

    def forward_backward(rep):
        args = inputs[rep % len(inputs)]
        image, final_t, lists = ext.forward(w.width, w.height, *args)
        ext.backward(w.width, w.height, *args, final_t, lists, *ones)

    # same inputs, same image up to its conventions (alpha clamp 0.999, 3-sigma box, stop rule)
    from recon.splat._functions import Rasterize
    from recon.splat.rasterization import MAX_TILE_PAIRS

    means2d, conics, colors, opacities, depths = views[0]
    with torch.no_grad():
        ours = Rasterize.apply(means2d, conics, colors, opacities, depths, torch.ones(len(depths), dtype=torch.int32),
                               w.width, w.height, MAX_TILE_PAIRS, threads)[0]
    diff = (ext.forward(w.width, w.height, *inputs[0])[0] - ours).abs()
    extra = {"image_vs_ours_max_abs": round(float(diff.max()), 4), "image_vs_ours_mean_abs": round(float(diff.mean()), 6),
             "source": f"{peers_dir}/{OPENSPLAT_CPU_DIR}/gsplat_cpu.cpp (pierotofy/OpenSplat {OPENSPLAT_COMMIT})"}
    return _timed(forward, reps), _timed(forward_backward, reps), extra


WORKERS = {
    "recon.splat": (_bench_ours, "render"),
    "dense-reference": (_bench_dense, "render"),
    "recon.splat:proj": (_bench_our_projection, "projection+sh (degree 3)"),
    "gsplat-1.5.3:proj": (_bench_gsplat_projection, "projection+sh (degree 3)"),
    "recon.splat:train": (_bench_train_step, "train step: render SH3 + L1 + 0.2 D-SSIM + backward + Adam"),
    "recon.splat:raster": (_bench_our_raster, "rasterize only: projected visible Gaussians of each view"),
    OPENSPLAT: (_bench_opensplat, "rasterize only: projected visible Gaussians of each view (single-threaded)"),
}


def worker(args) -> None:
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "bench"))
    import recon  # noqa: F401  (before torch: its OpenMP wait policy, as `recon run` has it)
    if args.peers_dir:
        sys.path.insert(0, args.peers_dir)
    import torch

    torch.set_num_threads(args.threads)
    from splat_workload import make_workload

    fn, scope = WORKERS[args.worker]
    w = make_workload(args.n, args.scale_k)
    _reset_peak_rss()
    peer = (args.peers_dir,) if args.worker == OPENSPLAT else ()
    forward_ms, forward_backward_ms, extra = fn(w, args.reps, args.threads, *peer)
    min_forward, min_forward_backward = _MINIMA[0], _MINIMA[1]
    record = {"impl": args.worker, "n": args.n, "width": w.width, "height": w.height, "threads": args.threads,
              "forward_ms": round(forward_ms, 3), "forward_backward_ms": round(forward_backward_ms, 3),
              "peak_rss_mb": round(_peak_rss_mb(), 1), "forward_min_ms": round(min_forward, 3), "forward_backward_min_ms": round(min_forward_backward, 3),
              "scope": scope, "scale_k": args.scale_k, "reps": args.reps,
              "load_avg_1min": round(os.getloadavg()[0], 2),
              "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "unset (libgomp default: spin, then sleep)")}
    record.update(extra)
    print(json.dumps(record))


# ---------------------------------------------------------------- parent side

def _available(impl: str, peers_dir: str | None) -> str | None:
    """None when impl can run, else why not."""
    if impl == OPENSPLAT:
        src = Path(peers_dir or ".") / OPENSPLAT_CPU_DIR / "gsplat_cpu.cpp"
        return None if peers_dir and src.exists() else f"no {src}; see --help for the OpenSplat checkout"
    if impl != "gsplat-1.5.3:proj":
        return None
    code = "import sys; sys.path.insert(0, sys.argv[1]) if sys.argv[1] else None; import gsplat.cuda._torch_impl"
    probe = subprocess.run([sys.executable, "-c", code, peers_dir or ""], capture_output=True, text=True)
    return None if probe.returncode == 0 else "gsplat is not importable: " + (probe.stderr.strip().splitlines() or ["?"])[-1]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, help="JSON file to write (a list of records)")
    p.add_argument("--sizes", default="2000,10000,50000,200000",
                   help="Gaussian counts N (default: %(default)s; 2000 is where the dense reference fits)")
    p.add_argument("--impls", default=",".join(IMPLS), help="comma list of implementations (default: all)")
    p.add_argument("--reps", type=int, default=7, help="timed runs per measurement, median reported (default: %(default)s)")
    p.add_argument("--threads", type=int, default=2, help="threads for every implementation (default: %(default)s)")
    p.add_argument("--scale-k", type=float, default=3.0, help="Gaussian scale = K x mean 3-NN distance (default: %(default)s)")
    p.add_argument("--dense-max-n", type=int, default=2000, help="largest N for the dense reference (default: %(default)s)")
    p.add_argument("--peers-dir", help="where peers are: gsplat (added to sys.path) and the OpenSplat checkout")
    p.add_argument("--omp-wait-policy", choices=["inherit", "passive", "active"], default="inherit",
                   help="OMP_WAIT_POLICY for the workers; libgomp reads it when torch loads it (default: %(default)s)")
    p.add_argument("--worker", choices=list(WORKERS), help=argparse.SUPPRESS)
    p.add_argument("--n", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        worker(args)
        return 0
    if not args.out:
        p.error("--out is required")
    if args.reps < 5:
        p.error("--reps must be >= 5 (median of at least 5)")
    records, failed = [], []
    for impl in args.impls.split(","):
        if impl not in WORKERS:
            p.error(f"unknown implementation {impl!r}; choose from {', '.join(WORKERS)}")
        reason = _available(impl, args.peers_dir)
        if reason:
            print(f"skip {impl}: {reason}", flush=True)
            continue
        for n in (int(s) for s in args.sizes.split(",")):
            if impl == "dense-reference" and n > args.dense_max_n:
                print(f"skip {impl} n={n}: above --dense-max-n {args.dense_max_n}", flush=True)
                continue
            cmd = [sys.executable, __file__, "--worker", impl, "--n", str(n), "--reps", str(args.reps),
                   "--threads", str(args.threads), "--scale-k", str(args.scale_k)]
            if args.peers_dir:
                cmd += ["--peers-dir", args.peers_dir]
            print(f"{impl} n={n} ...", end=" ", flush=True)
            env = dict(os.environ)
            if args.omp_wait_policy != "inherit":
                env["OMP_WAIT_POLICY"] = args.omp_wait_policy.upper()
            run = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if run.returncode != 0:
                print(f"FAILED:\n{run.stderr[-2000:]}", flush=True)
                failed.append(f"{impl} n={n}")
                continue
            record = json.loads(run.stdout.strip().splitlines()[-1])
            records.append(record)
            print(f"forward {record['forward_ms']:.1f} ms, forward+backward {record['forward_backward_ms']:.1f} ms, "
                  f"peak RSS {record['peak_rss_mb']:.0f} MB", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(records, indent=1) + "\n")
    print(f"wrote {len(records)} records to {args.out}")
    if failed:  # a partial result must not pass for a whole one
        print(f"rasterizer.py: {len(failed)} measurement(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
