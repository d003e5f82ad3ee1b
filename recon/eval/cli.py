"""`recon eval`: compare a run's renders with a prepared dataset's ground truth."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from recon.data import DatasetError
from recon.eval.evaluate import evaluate_run, markdown_table, write_results, write_strips
from recon.eval.renders import RenderError

EPILOG = """\
examples:
  recon eval runs/dtg-sim data/sim
  recon eval runs/dtg-sim data/sim --split all --out /tmp/eval --no-lpips
  recon eval runs/dtg-sim data/sim --strips      # + GT | render | error pictures

The render of ground-truth frame F must be RUN_DIR/renders/<F.file_path>, encoded like the
ground truth (RGB 8-bit PNG, thermal 16-bit PNG in the dataset's thermal_scale_k), for the
modalities the run renders (RUN_DIR/config.json: a single-modality method, only its own). Writes
metrics.json (per frame and mean per modality, per region, per named object with masks) and
metrics.md. SSIM: 11x11 Gaussian window, sigma 1.5 (3DGS convention). LPIPS: AlexNet v0.1,
official [-1, 1] input convention, only if its weights are installed (`make setup`); otherwise
it is omitted and the output says so.
"""


def register(sub) -> None:
    p = sub.add_parser("eval", help="metrics of a run's renders against a dataset's ground truth",
                       description=__doc__, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="run folder holding renders/")
    p.add_argument("dataset_dir", type=Path, metavar="DATASET_DIR", help="prepared dataset")
    p.add_argument("--split", choices=("test", "train", "all"), default="test",
                   help="frames to evaluate (default: test)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: RUN_DIR/eval)")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS even if weights exist")
    p.add_argument("--strips", action="store_true",
                   help="also write GT | render | error pictures to OUT/strips/<file_path>.png")
    p.set_defaults(func=run)


def run_modalities(run_dir: Path) -> tuple[str, ...]:
    """The modalities a run renders: its config.json's model.modalities (a single-modality method
    writes only its own), else the renders/ folders present, else both."""
    try:
        found = json.loads((run_dir / "config.json").read_text())["model"]["modalities"]
        if found:
            return tuple(found)
    except (OSError, ValueError, KeyError, TypeError):
        pass
    present = tuple(m for m in ("rgb", "thermal") if (run_dir / "renders" / m).is_dir())
    return present or ("rgb", "thermal")


def run(args) -> int:
    def progress(done: int, total: int) -> None:
        if done == total or done % max(1, total // 10) == 0:
            print(f"  {done}/{total} frames", flush=True)

    try:
        modalities = run_modalities(args.run_dir)
        result = evaluate_run(args.run_dir, args.dataset_dir, args.split,
                              use_lpips=not args.no_lpips, progress=progress, modalities=modalities)
    except (RenderError, DatasetError, ValueError) as e:
        print(f"recon eval: {e}", file=sys.stderr)
        return 2
    out = args.out or args.run_dir / "eval"
    js, md = write_results(result, out)
    if args.strips:
        print(f"wrote {len(write_strips(args.run_dir, args.dataset_dir, out / 'strips', args.split, modalities))} "
              f"pictures to {out / 'strips'}")
    blocks = markdown_table(result).split("\n\n")
    print("\n\n".join([blocks[0]] + [b for b in blocks[1:] if b.startswith("| modality |")]))
    print(f"wrote {js} and {md}")
    return 0
