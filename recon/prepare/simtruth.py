"""Ground truth of a simulated session (for grading `recon prepare` in tests and benchmarks).

`rig capture` with the simulated rig records, per phone file (closed.json `sim_truth`), the
file's true start on the host clock, the phone's drift, the host time of scene time 0 and the
scene (`rig.simulated.WorldScene.describe()`). Thermal frames carry their true host time in
`host_ns`. From these, every frame's scene time and hence its true pose in the world follow.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SessionTruth:
    world: object                   # rig.sim.World
    rig: int
    scene_t0: float                 # host s at scene time 0
    files: dict[str, dict]          # "rgb/IMG_0001.MOV" -> sim_truth entry

    def rgb_time(self, record: dict) -> float:
        """Scene time (s) of a phone frame record."""
        f = self.files[record["file"]]
        host = f["true_start_host_s"] + record["pts_s"] / (1 + f["drift_ppm"] * 1e-6)
        return host - self.scene_t0

    def thermal_time(self, record: dict) -> float:
        return record["host_ns"] / 1e9 - self.scene_t0

    def rgb_pose(self, record: dict) -> np.ndarray:
        """(4, 4) true camera-to-world (OpenCV axes, metres) of a phone frame."""
        return self.world.rig_pose(self.rig, self.rgb_time(record))[0]

    def thermal_pose(self, record: dict) -> np.ndarray:
        return self.world.rig_pose(self.rig, self.thermal_time(record))[1]


def session_truth(session) -> SessionTruth | None:
    """The truth of a simulated session of the rig.sim world (None for other sessions)."""
    from rig.sim import make_calibration_world, make_world
    entries = (session.summary or {}).get("sim_truth") or [   # closed.json, else live rgb_file events
        e["sim_truth"] for e in session.events if e.get("event") == "rgb_file" and e.get("sim_truth")]
    scene = next((e.get("scene") for e in entries if e.get("scene")), None)
    if scene is None:
        return None
    world = make_calibration_world(scene["seed"]) if scene["kind"] == "calibration" else \
        make_world(scene["variant"], scene["seed"])
    files = {f"rgb/{e['file']}": e for e in entries}
    return SessionTruth(world, scene["rig"], entries[0]["scene_t0_host_s"], files)


def prepared_rgb_pose_errors(session, data_dir) -> dict:
    """`recon.prepare.poses.pose_errors` of a prepared dataset's RGB poses (data_dir, written by
    `recon prepare` from the simulated `session`) against the simulator's true path."""
    import json
    from pathlib import Path

    from recon.data import load_dataset
    from recon.prepare.report import REPORT_FILE
    from recon.prepare.poses import pose_errors
    truth = session_truth(session)
    report = json.loads((Path(data_dir) / REPORT_FILE).read_text())
    est = np.stack([f.c2w_opencv() for f in load_dataset(data_dir).frames if f.modality == "rgb"])
    gt = np.stack([truth.rgb_pose(session.rgb[e["rgb_record"]]) for e in report["frame_list"]])
    return pose_errors(est, gt)
