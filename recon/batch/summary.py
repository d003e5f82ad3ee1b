"""What a batch (or bench/table.py's grid) measured, in one place: flat per-run rows, median and
worst over runs per method, Markdown tables, and the speed-vs-accuracy chart."""
from __future__ import annotations

import statistics
from pathlib import Path

# Summary columns: (key, header, digits, higher is better)
COLUMNS = [("psnr_rgb", "RGB PSNR", 2, True), ("psnr_rgb_moving", "RGB PSNR moving", 2, True),
           ("psnr_thermal", "th PSNR", 2, True), ("mae_k_thermal", "th MAE K", 2, False),
           ("mae_k_moving", "MAE moving", 2, False), ("mae_k_moving_hot", "MAE moving-hot", 2, False),
           ("mae_k_static", "MAE static", 2, False), ("p95_k_moving", "p95 moving", 1, False),
           ("mae_k_worst_moving_object", "MAE worst moving object", 1, False),
           ("gaussians", "Gaussians", 0, None), ("iterations", "it", 0, None), ("train_s", "train s", 0, None),
           ("ms_per_it", "ms/it", 1, None)]


def flatten(metrics: dict) -> dict:
    """evaluate_model()/metrics.json metrics -> the flat summary keys of COLUMNS."""
    get = lambda *path: _dig(metrics, path)  # noqa: E731
    return {"psnr_rgb": get("rgb", "psnr"), "ssim_rgb": get("rgb", "ssim"),
            "psnr_thermal": get("thermal", "psnr"), "ssim_thermal": get("thermal", "ssim"),
            "mae_k_thermal": get("thermal", "mae_k"),
            "psnr_rgb_moving": get("regions", "rgb", "moving", "psnr"),
            "mae_k_moving": get("regions", "thermal", "moving", "mae_k"),
            "mae_k_moving_hot": get("regions", "thermal", "moving_hot", "mae_k"),
            "mae_k_static": get("regions", "thermal", "static", "mae_k"),
            "mae_k_hot": get("regions", "thermal", "hot", "mae_k"),
            "p95_k_moving": get("regions", "thermal", "moving", "p95_k"),
            "mae_k_worst_moving_object": _worst_moving(get("objects", "thermal"))}


def _worst_moving(objects: dict | None) -> float | None:
    """The largest thermal MAE of a moving named object (None: no such object graded)."""
    maes = [m["mae_k"] for m in (objects or {}).values() if m.get("moving") and m.get("mae_k") is not None]
    return max(maes) if maes else None


def _dig(d, path):
    for key in path:
        if not isinstance(d, dict) or d.get(key) is None:
            return None
        d = d[key]
    return d


def summarise(summary: dict) -> dict:
    """A run's metrics.json (recon/run.py) -> one flat row."""
    return {**flatten(summary["metrics"]), "gaussians": summary["gaussians"],
            "roles": summary["gaussians_per_role"], "model_mb": summary["model_bytes"] / 1e6,
            "train_s": summary["train_seconds"], "iterations": summary["iterations"],
            "ms_per_it": 1000 * summary["train_seconds"] / max(summary["iterations"], 1),
            "peak_rss_mb": summary.get("peak_rss_mb"), "stop_reason": summary.get("stop_reason"),
            "events": sum(1 for e in summary.get("events", []) if not e.get("warning"))}


def aggregate(rows: list[dict]) -> dict:
    """Median and worst over runs of every column (worst: lowest PSNR, highest error)."""
    out = {"seeds": len(rows), "events": sum(r.get("events", 0) for r in rows)}
    for key, _, _, higher in COLUMNS:
        vals = [r[key] for r in rows if r.get(key) is not None]
        if not vals:
            continue
        out[key] = statistics.median(vals)
        if higher is not None:
            out[f"{key}_worst"] = min(vals) if higher else max(vals)
    return out


def markdown(groups: dict[str, dict], title: str, count: str = "seeds") -> str:
    """One table: rows method, cells 'median (worst)'."""
    def cell(agg, key, digits, higher):
        if agg.get(key) is None:
            return "–"
        text = f"{agg[key]:.{digits}f}"
        return text + (f" ({agg[key + '_worst']:.{digits}f})" if higher is not None and agg["seeds"] > 1 else "")
    lines = [f"**{title}**", "", f"| method | {count} | " + " | ".join(c[1] for c in COLUMNS) + " | rollbacks |",
             "|---|---|" + "---|" * (len(COLUMNS) + 1)]
    for method, agg in groups.items():
        lines.append(f"| {method} | {agg['seeds']} | " + " | ".join(cell(agg, k, d, h) for k, _, d, h in COLUMNS)
                     + f" | {agg['events']} |")
    return "\n".join(lines)


def plot_final(rows: list[dict], path: Path) -> bool:
    """Accuracy against training time, one point per run, one colour per method: RGB PSNR,
    thermal PSNR, thermal MAE. rows: [{"method", "train_s", psnr_rgb, ...}]. False (and no
    file) without matplotlib."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    panels = [("psnr_rgb", "RGB PSNR (dB)"), ("psnr_thermal", "thermal PSNR (dB)"), ("mae_k_thermal", "thermal MAE (K)")]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.4 * len(panels), 3.4), squeeze=False)
    for ax, (key, label) in zip(axes[0], panels):
        for i, method in enumerate(methods):
            pts = [(r["train_s"], r[key]) for r in rows if r["method"] == method and r.get(key) is not None]
            if pts:
                ax.scatter(*zip(*pts), s=18, color=f"C{i % 10}", label=method)
        ax.set_xlabel("training wall-clock (s)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


def write_summary(runs: Path, rows: list[dict]) -> str:
    """summary.json, summary.md and speed_vs_accuracy.png from batch.json's job rows; -> the
    Markdown. Per input, per method: median (worst) over the jobs that finished."""
    import json
    done = [r for r in rows if r.get("metrics")]
    parts, per_input = [], {}
    for inp in dict.fromkeys(r["input"] for r in done):
        picked = [r for r in done if r["input"] == inp]
        groups = {m: aggregate([r["metrics"] for r in picked if r["method"] == m])
                  for m in dict.fromkeys(r["method"] for r in picked)}
        per_input[inp] = groups
        parts.append(markdown(groups, f"{inp}: median (worst) over jobs", count="jobs"))
    failed = [r for r in rows if r["state"] == "failed"]
    if failed:
        parts.append("**failed**\n\n" + "\n".join(f"- {r['name']}: {r.get('error')}" for r in failed))
    text = "\n\n".join(parts) + "\n"
    (runs / "summary.md").write_text(text)
    (runs / "summary.json").write_text(json.dumps(
        {"jobs": [{k: r.get(k) for k in ("name", "input", "method", "seed", "state", "attempts", "error",
                                         "seconds", "metrics")} for r in rows],
         "aggregate": per_input}, indent=1))
    plot_final([{"method": r["method"], **r["metrics"]} for r in done], runs / "speed_vs_accuracy.png")
    return text
