"""Sync accuracy on simulated streams: a phone with a 137 ms clock lead and 50 ppm drift, one
60 s movie, thermal at 30 Hz from its own drifting clock, several scene seeds; with sync-box
lamp markers (1 s irregular pulses) and without (energy cross-correlation only). Reports the
frame-time error, the phone lead at the first frame and the drift found (with its sd).

    PYTHONPATH=. python bench/rig_sync.py --seeds 5 --duration 60 [--drift 50]
writes bench/results/rig_sync.json (bench/results/rig_sync_drift<D>.json for another --drift)
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from rig.sync import synchronise
from tests.test_rig_sync import mapping_error_ms, simulate

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--drift", type=float, default=50.0, help="phone clock drift, ppm (fast > 0)")
    args = p.parse_args()
    rows = []
    for seed in range(args.seeds):
        for lamp in (1.0, None):
            with tempfile.TemporaryDirectory() as d:
                thermal, rgb, events, times, epoch, phone = simulate(Path(d), args.duration, lamp_period_s=lamp,
                                                                     seed=seed, drift_ppm=args.drift)
            res = synchronise(thermal, rgb, events, 1e9, epoch)
            err = mapping_error_ms(res, rgb, times)
            # the phone's lead over the host clock at its first frame, as found (truth: 137 ms + drift)
            true_lead_ms = (phone.phone_unix(times[0]) - phone.realtime_minus_monotonic - times[0]) * 1e3
            rows.append({"seed": seed, "method": res.method, "max_abs_error_ms": float(np.abs(err).max()),
                         "mean_error_ms": float(err.mean()), "phone_lead_found_ms": true_lead_ms - err[0],
                         "phone_lead_true_ms": true_lead_ms, "drift_ppm_found": res.drift_ppm,
                         "drift_sd_ppm": res.drift_sd_ppm, "drift_method": res.drift_method,
                         "residual_ms": res.residual_ms, "correlation": res.files[0].correlation})
            print(json.dumps(rows[-1]))
    summary = {}
    for method in ("markers", "xcorr"):
        r = [x for x in rows if x["method"] == method]
        summary[method] = {"median_max_abs_error_ms": float(np.median([x["max_abs_error_ms"] for x in r])),
                           "worst_max_abs_error_ms": float(np.max([x["max_abs_error_ms"] for x in r])),
                           "median_phone_lead_found_ms": float(np.median([x["phone_lead_found_ms"] for x in r])),
                           "drift_ppm_found": [round(x["drift_ppm_found"], 1) for x in r],
                           "median_abs_drift_error_ppm": float(np.median([abs(x["drift_ppm_found"] - args.drift)
                                                                           for x in r])),
                           "median_drift_sd_ppm": float(np.median([x["drift_sd_ppm"] or np.nan for x in r]))}
    name = "rig_sync.json" if args.drift == 50.0 else f"rig_sync_drift{args.drift:g}.json"
    out = ROOT / "bench" / "results" / name
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"true_phone_lead_ms": 137.0, "true_drift_ppm": args.drift, "duration_s": args.duration,
                               "runs": rows, "summary": summary}, indent=1))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
