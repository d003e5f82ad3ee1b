"""`recon demo`: the appliance in one command, on the embedded simulated rig (no hardware).

1. `rig capture --duration D` records the simulated rig (FLIR-like GigE thermal stream, phone
   videos dropped in a folder, sync-box lamp) into OUT/session, in its own process;
2. `recon run OUT/session --follow --serve` trains Dynamic Thermal Gaussians while the capture
   grows (poses re-solved with pycolmap as frames arrive) and serves the status page;
3. when the capture ends it trains --after more iterations, renders the held-out views, grades
   them and exports the model, then prints where everything is.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from rig.cli_format import positive_float


def demo(args: argparse.Namespace) -> int:
    out = Path(args.out or time.strftime("runs/demo-%Y%m%d-%H%M%S"))
    session, run_dir = out / "session", out / "run"
    if session.exists() or run_dir.exists():
        raise ValueError(f"{out}: holds an earlier demo; remove it or pass --out NEW_FOLDER")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(f"[1/2] simulated capture, {args.duration:g} s -> {session}", flush=True)
    capture = subprocess.Popen(
        [sys.executable, "-m", "rig", "capture", "--duration", str(args.duration), "--out", str(session),
         "--quiet"], stdout=subprocess.DEVNULL, stderr=open(out / "capture.log", "w"))
    try:
        while not (session / "session.json").exists():
            if capture.poll() is not None:
                raise SystemExit(f"rig capture failed (exit {capture.returncode}); see {out / 'capture.log'}")
            time.sleep(0.2)
        print(f"[2/2] live training while capturing -> {run_dir}", flush=True)
        run_argv = ["run", str(session), "--follow", "--out", str(run_dir), "--after", str(args.after)]
        if args.serve:
            run_argv += ["--serve", "--host", args.host, "--port", str(args.port)]
        from recon.cli import main as recon_main
        code = recon_main(run_argv)
    finally:
        if capture.poll() is None:
            capture.wait(timeout=args.duration + 60)
    summary = json.loads((run_dir / "metrics.json").read_text())
    thermal = summary["metrics"].get("thermal", {})
    rgb = summary["metrics"].get("rgb", {})
    print(f"\ndemo finished in {time.perf_counter() - t0:.0f} s: held-out RGB {rgb.get('psnr', float('nan')):.2f} dB, "
          f"thermal {thermal.get('psnr', float('nan')):.2f} dB, MAE {thermal.get('mae_k', float('nan')):.2f} K\n"
          f"  {run_dir / 'eval' / 'metrics.md'}   metrics per held-out frame\n"
          f"  {run_dir / 'strips'}/               ground truth | render | error (thermal in deg C)\n"
          f"  {run_dir / 'animation.gif'}         a held-out view across time\n"
          f"  recon render {run_dir} --time 0.5 --out mid   # any time, any pose\n"
          f"  python -m server --run {run_dir} --session {session}   # the status page again")
    return code


def register(sub) -> None:
    p = sub.add_parser("demo", help="the appliance on the simulated rig: capture + live training + status page",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=None, help="output folder (default: runs/demo-<date>-<time>, new each time)")
    p.add_argument("--duration", type=positive_float, default=60.0, help="capture seconds (default: 60)")
    p.add_argument("--after", type=int, default=1500, help="iterations after the capture ends (default: 1500)")
    p.add_argument("--no-serve", dest="serve", action="store_false", help="no status page")
    p.add_argument("--host", default="127.0.0.1", help="status page address (default: 127.0.0.1)")
    p.add_argument("--port", type=int, default=8765, help="status page port (default: 8765)")
    p.set_defaults(func=demo)
