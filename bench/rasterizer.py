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
Records: {"impl","n","width","height","threads","forward_ms","forward_backward_ms","peak_rss_mb"}
plus "forward_min_ms", "forward_backward_min_ms" (fastest run), "scope", "scale_k", "reps", "load_avg_1min" (other load on the machine skews timings),
"omp_wait_policy" and, for recon.splat, "breakdown_ms".
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMPLS = ["recon.splat", "dense-reference", "recon.splat:proj", "gsplat-1.5.3:proj", "recon.splat:train"]
EPILOG = """examples:
  python bench/rasterizer.py --out bench/results/rasterizer.json
  python bench/rasterizer.py --out /tmp/r.json --sizes 50000 --impls recon.splat,recon.splat:train
  python bench/rasterizer.py --out /tmp/r.json --peers-dir /tmp/peers   # gsplat installed with
      pip install --target /tmp/peers gsplat==1.5.3 --no-deps && pip install --target /tmp/peers jaxtyping rich
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
    feats = w.colors
    if sh:  # degree-3 SH whose DC term reproduces the colours
        feats = torch.zeros(w.colors.shape[0], 16, 3)
        feats[:, 0] = (w.colors - 0.5) / 0.28209479177387814
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
    cam = (w.fx, w.fy, w.cx, w.cy, w.width, w.height, 0.01)
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
    cam = (w.fx, w.fy, w.cx, w.cy, w.width, w.height, 0.01)

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


WORKERS = {
    "recon.splat": (_bench_ours, "render"),
    "dense-reference": (_bench_dense, "render"),
    "recon.splat:proj": (_bench_our_projection, "projection+sh (degree 3)"),
    "gsplat-1.5.3:proj": (_bench_gsplat_projection, "projection+sh (degree 3)"),
    "recon.splat:train": (_bench_train_step, "train step: render SH3 + L1 + 0.2 D-SSIM + backward + Adam"),
}


def worker(args) -> None:
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "bench"))
    if args.peers_dir:
        sys.path.insert(0, args.peers_dir)
    import torch

    torch.set_num_threads(args.threads)
    from splat_workload import make_workload

    fn, scope = WORKERS[args.worker]
    w = make_workload(args.n, args.scale_k)
    _reset_peak_rss()
    forward_ms, forward_backward_ms, extra = fn(w, args.reps, args.threads)
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
    p.add_argument("--peers-dir", help="extra sys.path entry where peers (gsplat) are installed")
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
    records = []
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
                continue
            record = json.loads(run.stdout.strip().splitlines()[-1])
            records.append(record)
            print(f"forward {record['forward_ms']:.1f} ms, forward+backward {record['forward_backward_ms']:.1f} ms, "
                  f"peak RSS {record['peak_rss_mb']:.0f} MB", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(records, indent=1) + "\n")
    print(f"wrote {len(records)} records to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
