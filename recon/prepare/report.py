"""The report of `recon prepare`: prepare_report.json beside the dataset, and a printed summary."""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

REPORT_FILE = "prepare_report.json"      # OUT/<this>: what `recon prepare` measured, also when it refused


def _finite(x):
    """JSON without NaN/inf (strict readers reject them): such numbers become strings."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


@dataclass
class Report:
    session: str
    options: dict = field(default_factory=dict)
    status: str = "running"
    error: str | None = None
    calibration: dict = field(default_factory=dict)
    sync: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)        # paired, selected, registered, brightness
    sfm: dict = field(default_factory=dict)           # pycolmap stats and wall times
    scale: dict = field(default_factory=dict)
    output: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    frame_list: list[dict] = field(default_factory=list)  # per time step: session records and times

    def warn(self, message: str) -> None:
        self.warnings.append(message)

    def note(self, message: str) -> None:
        self.notes.append(message)

    def finish(self, status: str, error: str | None = None) -> None:
        self.status, self.error = status, error

    def write(self, path: Path) -> None:
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(json.dumps(_finite(asdict(self)), indent=1) + "\n")
        os.replace(tmp, path)

    def summary_lines(self) -> list[str]:
        """What `recon prepare` prints at the end."""
        f, s = self.frames, self.sfm
        lines = [f"status       {self.status}"]
        if self.calibration:
            lines.append(f"calibration  {self.calibration.get('source')} (baseline "
                         f"{self.calibration.get('baseline_m', 0) * 100:.1f} cm)")
        if self.sync:
            res = self.sync.get("residual_ms")
            lines.append(f"sync         {self.sync.get('method')}, residual "
                         f"{'-' if res is None else f'{res:.1f} ms'}, pair |dt| median "
                         f"{self.sync.get('pair_dt_ms_median', 0):.1f} ms")
        if f:
            lines.append(f"frames       {f.get('paired', 0)} paired, {f.get('selected', 0)} selected, "
                         f"{f.get('registered', '-')} registered")
        if s.get("registered") is not None:
            lines.append(f"sfm          {s['registered']}/{s['frames']} registered, {s['points']} points, "
                         f"reprojection {s['mean_reprojection_error_px']:.3f} px, track length "
                         f"{s['mean_track_length']:.2f}")
        if s.get("pycolmap_s") is not None:
            lines.append(f"pycolmap     {s['pycolmap_s']:.1f} s wall (extract {s.get('extract_s', 0):.1f}, match "
                         f"{s.get('match_s', 0):.1f}, map {s.get('map_s', 0):.1f}; {s.get('pairs', 0)} pairs)")
        if self.scale.get("metres_per_unit") is not None:
            lines.append(f"scale        {self.scale['metres_per_unit']:.5g} m per SfM unit ({self.scale['method']}), "
                         f"median depth {self.scale.get('median_depth_m', float('nan')):.3f} m")
        if self.output:
            lines.append(f"dataset      {self.output['frames']} frames, {self.output['points']} points -> "
                         f"{self.output['dataset']}")
        lines += [f"note         {n}" for n in self.notes]
        lines += [f"warning      {w}" for w in self.warnings]
        if self.error:
            lines.append(f"error        {self.error}")
        return lines
