"""Record script: pose error of `recon prepare` on short simulated-rig sessions (the 3 s session of
tests/test_prepare_session.py) over prepare seeds, against the simulator's true path.

    python bench/results/sfm-tries/seeds.py OUT_DIR SESSIONS SEEDS

captures SESSIONS sessions of 3 s into OUT_DIR (real time: frame timing, hence the selected frames,
differ between captures), prepares each with seeds 0..SEEDS-1 (12 frames, as the test) and prints
per run: median rotation (deg) and position (m) error after a similarity alignment, path jitter
median/max (deg), mean reprojection error (px), points, mean track length. before.txt: 11 sessions
x 5 seeds (runs/s0-s2, runs8/s0-s7) at befb848 (one mapping run per prepare); after.txt: the same sessions with mapping
tries (recon/sfm.py `mapping_tries`)."""
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import recon  # noqa: E402,F401  (before torch and cv2, as the package expects)

import numpy as np  # noqa: E402

from recon.prepare import REPORT_FILE, prepare_session  # noqa: E402
from recon.prepare.simtruth import prepared_rgb_pose_errors  # noqa: E402
from rig.capture.config import CaptureConfig  # noqa: E402
from rig.capture.session_capture import Capture  # noqa: E402
from rig.session import open_session  # noqa: E402


def main(root: Path, sessions: int, seeds: int) -> None:
    root.mkdir(parents=True, exist_ok=True)
    for k in range(sessions):
        session = root / f"s{k}"
        if not session.exists():
            Capture(CaptureConfig(duration_s=3.0, out=session, progress=False)).run()
        for seed in range(seeds):
            out = root / "prepared"
            shutil.rmtree(out, ignore_errors=True)
            try:
                prepare_session(session, out, progress=None, frames=12, test_every=4, downscale=2, seed=seed)
            except Exception as exc:  # a refusal is a result here
                print(session.name, seed, "refused:", str(exc)[:120], flush=True)
                continue
            e = prepared_rgb_pose_errors(open_session(session), out)
            f = json.loads((out / REPORT_FILE).read_text())["sfm"]
            print(session.name, seed, "rot %.2f pos %.4f" % (np.median(e["rotation_deg"]), np.median(e["position"])),
                  "jit %.2f %.2f" % (f["path_jitter_deg_median"], f["path_jitter_deg_max"]),
                  "reproj %.3f pts %d track %.2f" % (f["mean_reprojection_error_px"], f["points"],
                                                      f["mean_track_length"]), flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
