"""The `rig capture` status line, during the capture (rates of the last seconds) and at its end."""
from __future__ import annotations

import time

from rig.capture.config import CaptureStats


def progress_line(elapsed_s: float, duration_s: float, streams: dict, markers: int,
                  residual_ms: float | None, offset_ms: float | None) -> str:
    """The `rig capture` status line. streams as `rig info` has them: {"thermal": {"frames",
    "fps", "incomplete", "dropped", "resent" (packets, optional)}, "rgb": {"frames", "files",
    "fps", "dropped"}}."""
    th, rgb = streams["thermal"], streams["rgb"]
    resent = f" resent {th['resent']}" if th.get("resent") is not None else ""
    res = "-" if residual_ms is None else f"{residual_ms:.1f} ms"
    off = "" if offset_ms is None else f" offset {offset_ms:+.0f} ms"
    return (f"{elapsed_s:6.1f}/{duration_s:.0f} s | thermal {th['frames']} ({th['fps']:4.1f} fps) incomplete "
            f"{th['incomplete']} dropped {th['dropped']}{resent} | rgb {rgb['frames']} in {rgb['files']} files "
            f"({rgb['fps']:4.1f} fps) dropped {rgb['dropped']} | markers {markers} | sync residual {res}{off}")


class LiveStreams:
    """Stream figures while capturing: the thermal rate over the last 2 s of arrivals."""

    def __init__(self):
        self._rate: list[tuple[float, int]] = []      # (time, thermal frames)

    def __call__(self, st: CaptureStats) -> dict:
        now = time.monotonic()
        self._rate.append((now, st.thermal_frames))
        while len(self._rate) > 2 and now - self._rate[0][0] > 2.0:
            self._rate.pop(0)
        (t0, n0), (t1, n1) = self._rate[0], self._rate[-1]
        return {"thermal": {"frames": st.thermal_frames, "fps": (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0,
                            "incomplete": st.thermal_incomplete, "dropped": st.thermal_dropped,
                            "resent": st.thermal_resent},
                "rgb": {"frames": st.rgb_frames, "files": st.rgb_files, "dropped": st.rgb_dropped,
                        # phone files arrive whole, after the fact: their recorded rate
                        "fps": (st.rgb_frames - st.rgb_files) / st.rgb_span_s if st.rgb_span_s else 0.0}}
