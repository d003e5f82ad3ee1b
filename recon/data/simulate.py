"""Render a prepared dataset from the simulated world (rig.sim): the ground-truth benchmark data.

Per time step and rig r (camera `cam{r}`): an RGB frame `rgb/{i:06d}_cam{r}.png` (phone noise)
and a thermal frame `thermal/{i:06d}_cam{r}.png` (TemperatureLinear10mK counts with NETD noise)
at the thermal camera's own pose and narrower intrinsics, each with its object-label mask
`masks/<modality>/{i:06d}_cam{r}.png` where the scene labels objects. Poses and intrinsics are exact. The
noise of every frame is seeded by (seed, step, rig, modality), so the bytes depend on the seed
only, never on the order or number of worker processes.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from recon.data.frame import Frame, c2w_opencv_to_opengl
from recon.data.writer import write_dataset
from rig.sim import World, make_world

THERMAL_SCALE_K = 0.01  # FLIR TemperatureLinear10mK
SIDECAR = "sim_meta.json"


@dataclass(frozen=True)
class SimulateConfig:
    variant: str = "default"
    frames: int = 30          # time steps; each gives 2 frames per rig (RGB + thermal)
    width: int = 160
    height: int = 120
    seed: int = 0
    rigs: int = 2
    points: int = 4000        # initial sparse points (SfM-like) in points3d.ply
    explicit_splits: bool = False
    jobs: int = 1

    def step_times(self, duration_s: float) -> np.ndarray:
        """(frames,) capture times in seconds, evenly spread over the script."""
        return np.linspace(0.0, duration_s, self.frames) if self.frames > 1 else np.zeros(1)


@lru_cache(maxsize=2)
def _world(variant: str, seed: int) -> World:
    return make_world(variant, seed)


def render_step(cfg: SimulateConfig, step: int) -> list[tuple[Frame, np.ndarray, np.ndarray | None]]:
    """All frames of one time step: for each rig, (RGB frame, uint8 pixels, labels) and (thermal,
    counts, labels); labels (uint8 object ids) are None for a scene without labelled objects."""
    world = _world(cfg.variant, cfg.seed)
    t = float(cfg.step_times(world.duration_s)[step])
    out = []
    for rig in range(cfg.rigs):
        camera = f"cam{rig}"
        c2w_rgb, c2w_th = world.rig_pose(rig, t)
        for modality, c2w, intr in (("rgb", c2w_rgb, world.rig_config.rgb),
                                    ("thermal", c2w_th, world.rig_config.thermal)):
            k = intr.scaled(cfg.width, cfg.height)
            rng = np.random.default_rng([cfg.seed, step, rig, modality == "thermal"])
            pixels, labels = world.render_frame(modality, c2w, k.fx, k.fy, k.cx, k.cy, k.width, k.height,
                                                t, rng, THERMAL_SCALE_K)
            frame = Frame(f"{modality}/{step:06d}_{camera}.png", modality, camera,
                          t / world.duration_s, t, c2w_opencv_to_opengl(c2w), k.fx, k.fy, k.cx,
                          k.cy, k.width, k.height, split="test" if rig == 1 else "train")
            out.append((frame, pixels, labels if world.mask_labels() else None))
    return out


def _steps(cfg: SimulateConfig, progress: Callable[[int, int], None] | None
           ) -> Iterator[tuple[Frame, np.ndarray, np.ndarray | None]]:
    steps = range(cfg.frames)
    if cfg.jobs > 1:
        pool = ProcessPoolExecutor(cfg.jobs)
        results = pool.map(render_step, [cfg] * cfg.frames, steps)
    else:
        pool, results = None, (render_step(cfg, i) for i in steps)
    try:
        for i, frames in enumerate(results):
            yield from frames
            if progress:
                progress(i + 1, cfg.frames)
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)


def metadata(world: World, cfg: SimulateConfig) -> dict:
    """Ground truth that transforms.json has no place for (the sim_meta.json sidecar)."""
    rc = world.rig_config
    return {
        "generator": "recon simulate (rig.sim ray caster)",
        "config": {k: v for k, v in asdict(cfg).items() if k != "jobs"},  # jobs: same bytes
        "duration_s": world.duration_s,
        "thermal_from_rgb": rc.thermal_from_rgb.tolist(),
        "rig_baseline_m": rc.baseline_m,
        "rgb_intrinsics": asdict(rc.rgb.scaled(cfg.width, cfg.height)),
        "thermal_intrinsics": asdict(rc.thermal.scaled(cfg.width, cfg.height)),
        "netd_k": rc.netd_k,
        "note": "poses and intrinsics in transforms.json are exact; thermal frames use the "
                "thermal camera's own pose (RGB pose composed with thermal_from_rgb)",
    }


def simulate_dataset(out_dir: str | Path, cfg: SimulateConfig,
                     progress: Callable[[int, int], None] | None = None) -> Path:
    """Write the prepared dataset of `cfg` to out_dir; returns the transforms.json path."""
    if not 1 <= cfg.rigs <= 2:
        raise ValueError(f"rigs must be 1 or 2, got {cfg.rigs}")
    if cfg.frames < 1 or cfg.width < 1 or cfg.height < 1:
        raise ValueError("frames, width and height must be positive")
    world = _world(cfg.variant, cfg.seed)
    times = np.linspace(0, world.duration_s, 8)
    rng = np.random.default_rng([cfg.seed, 0x9017])
    xyz, rgb = world.visible_points(list(times), per_view=-(-cfg.points // len(times)), rng=rng)
    return write_dataset(out_dir, _steps(cfg, progress), THERMAL_SCALE_K, world.temperature_range_k,
                         xyz[:cfg.points], rgb[:cfg.points], explicit_splits=cfg.explicit_splits,
                         sidecars={SIDECAR: metadata(world, cfg)}, mask_labels=world.mask_labels())
