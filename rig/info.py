"""`rig info SESSION`: what a session holds: frames, losses, rates, sync."""
from __future__ import annotations

import json
import sys

import numpy as np

from rig.cli_format import HelpFormatter
from rig.drivers.phone import pts_drops
from rig.session import Session, open_session
from rig.sync import SyncResult, FileSync, fit_clock, pair_frames, ptp_slave, synchronise_session


def _fps(times_s: np.ndarray) -> float:
    return float((len(times_s) - 1) / np.ptp(times_s)) if len(times_s) > 1 and np.ptp(times_s) > 0 else 0.0


def _sync_result(d: dict) -> SyncResult:
    return SyncResult(**{**d, "files": [FileSync(**f) for f in d["files"]]})


def camera_profile(thermal_meta: dict) -> dict:
    """What session.json says of the thermal camera: its profile and whether its counts are
    temperatures (sessions older than profiles were all FLIR IRFormat: radiometric)."""
    return {"profile": thermal_meta.get("profile", "flir-irformat"),
            "radiometric": thermal_meta.get("radiometric", True),
            "kelvin_map": thermal_meta.get("kelvin_map"), "ptp": thermal_meta.get("ptp")}


def session_info(session: Session, resync: bool = False) -> dict:
    """Summary dict of a session (works on a crashed or still-growing session)."""
    sync = None if resync else session.sync
    sync_res = synchronise_session(session) if sync is None else _sync_result(sync)
    th = session.thermal
    tick = session.meta.get("thermal", {}).get("tick_hz", 1e9)
    led = [r for r in th if r.get("device_ts")]
    th_t = np.array([r["host_ns"] for r in th], float) / 1e9
    if len(led) >= 2:
        clock = fit_clock(np.array([r["device_ts"] for r in led], float) / tick,
                          np.array([r["host_ns"] for r in led], float) / 1e9, fixed_rate=ptp_slave(session.meta))
        th_t = clock(np.array([r["device_ts"] for r in led], float) / tick)
    thermal = {"frames": len(th), "complete": sum(bool(r["complete"]) for r in th),
               "incomplete": sum(not r["complete"] for r in th),
               "dropped": int(sum(r.get("dropped_before", 0) for r in th)),
               "missing_packets": int(sum(r.get("missing_packets", 0) for r in th)),
               "fps": round(_fps(th_t), 3),
               "ir_formats": sorted({r.get("ir_format") for r in th if r.get("ir_format")}),
               "gaps": len(sync_res.thermal_gaps), **camera_profile(session.meta.get("thermal", {}))}
    rgb_t, dropped = [], 0
    files = sorted({r["file"] for r in session.rgb})
    for name in files:
        recs = [r for r in session.rgb if r["file"] == name]
        pts = np.array([r["pts_s"] for r in recs])
        dropped += pts_drops(pts)
        if any(f.file == name for f in sync_res.files):
            fs = next(f for f in sync_res.files if f.file == name)
            rgb_t.append(sync_res.rgb_host_s(name, fs.nominal_start_s + pts))
    rgb_all = np.concatenate(rgb_t) if rgb_t else np.zeros(0)
    rgb_fps = float(np.mean([_fps(t) for t in rgb_t])) if rgb_t else 0.0
    rgb = {"frames": len(session.rgb), "files": len(files), "complete": len(session.rgb),
           "incomplete": 0, "dropped": dropped, "fps": round(rgb_fps, 3)}
    spans = [np.ptp(x) for x in (th_t, rgb_all) if len(x) > 1]
    period = 1 / thermal["fps"] if thermal["fps"] else 1 / 30
    pairs = pair_frames(th_t, rgb_all, period / 2) if len(rgb_all) and len(th_t) else []
    return {"path": str(session.path), "closed": session.closed,
            "duration_s": round(float(max(spans)), 3) if spans else 0.0,
            "sync_residual_ms": None if sync_res.residual_ms is None else round(sync_res.residual_ms, 3),
            "sync_residual_note": sync_res.residual_note,
            "streams": {"thermal": thermal, "rgb": rgb},
            "sync": {"method": sync_res.method, "rgb_offset_ms": sync_res.rgb_offset_ms,
                     "drift_ppm": sync_res.drift_ppm, "drift_sd_ppm": sync_res.drift_sd_ppm,
                     "drift_method": sync_res.drift_method,
                     "files": [{"file": f.file, "offset_ms": f.offset_s * 1e3, "correlation": f.correlation}
                               for f in sync_res.files]},
            "pairs": len(pairs),
            "pair_dt_ms_median": round(float(np.median(np.abs([p[2] for p in pairs]))) * 1e3, 3) if pairs else None,
            "markers": sum(e.get("event") == "marker" for e in session.events),
            "unreadable_index_lines": session.torn_or_bad_lines}


def register(sub) -> None:
    p = sub.add_parser("info", help="summarise a session (frames, losses, fps, sync)",
                       description="Summarise a session folder written by `rig capture`; works on "
                                   "sessions still being written and on ones cut short by a crash.",
                       formatter_class=HelpFormatter,
                       epilog="example:\n  rig info sessions/20260101-120000 --json")
    p.add_argument("session", help="session folder")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--resync", action="store_true", help="recompute sync instead of reading sync.json")
    p.set_defaults(func=main)


def main(args) -> int:
    try:
        info = session_info(open_session(args.session), resync=args.resync)
    except (FileNotFoundError, ValueError) as exc:
        print(f"rig info: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    th, rgb = info["streams"]["thermal"], info["streams"]["rgb"]
    print(f"{info['path']}  ({'closed' if info['closed'] else 'open or interrupted'})")
    print(f"  duration   {info['duration_s']:.1f} s")
    print(f"  thermal    {th['frames']} frames ({th['complete']} complete, {th['incomplete']} incomplete, "
          f"{th['dropped']} dropped), {th['fps']:.2f} fps, {', '.join(th['ir_formats']) or '-'}")
    kmap = th["kelvin_map"]
    print(f"  camera     {th['profile']} profile, " + ("radiometric" if th["radiometric"] else
          "NOT radiometric: " + (f"kelvin = counts x {kmap['gain_k']:g} + {kmap['offset_k']:g} (stated by the user)"
                                 if kmap else "counts only, no temperatures"))
          + (f", PTP {th['ptp']['status']}" if (th.get("ptp") or {}).get("enabled") else ""))
    print(f"  rgb        {rgb['frames']} frames in {rgb['files']} files ({rgb['dropped']} dropped), {rgb['fps']:.2f} fps")
    s = info["sync"]
    res = info["sync_residual_ms"]
    res_text = f"{res:.1f} ms" if res is not None else f"- ({info['sync_residual_note']})"
    sd = "" if s["drift_sd_ppm"] is None else f" +- {s['drift_sd_ppm']:.0f}"
    print(f"  sync       {s['method']}, phone offset {s['rgb_offset_ms'] if s['rgb_offset_ms'] is None else round(s['rgb_offset_ms'], 1)} ms, "
          f"drift {s['drift_ppm']:.0f}{sd} ppm ({s['drift_method']}), residual {res_text}, {info['pairs']} pairs")
    return 0
