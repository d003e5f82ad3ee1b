"""LPIPS (AlexNet) reproduces the official TID2013 calibration values; weights load safely."""
import io
import pickle
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from recon.eval.lpips import Lpips, _NumpyOnlyUnpickler

CALIB = Path("/work/shared/data/lpips_calibration")
OFFICIAL = {"I03": 0.7237, "I06": 0.05079, "I19": 0.4253}  # IQA-PyTorch results_official.csv

needs_weights = pytest.mark.skipif(not Lpips.available(),
                                   reason="LPIPS weights not installed (make setup)")


def _read(kind, name):
    return cv2.imread(str(CALIB / kind / f"{name}.png"))[..., ::-1].astype(np.float32) / 255


@needs_weights
def test_official_tid2013_values():
    if not CALIB.is_dir():
        pytest.skip("calibration pairs not available")
    lpips = Lpips()
    with torch.no_grad():
        for name, expected in OFFICIAL.items():
            value = float(lpips(_read("dist", name), _read("ref", name)))
            assert value == pytest.approx(expected, abs=5e-4), name


@needs_weights
def test_identical_images_have_zero_distance_and_batches_work():
    lpips = Lpips()
    a = torch.rand(2, 64, 64, 3)
    with torch.no_grad():
        same = lpips(a, a)
        diff = lpips(a, a.flip(0))
    assert same.shape == (2,) and float(same.abs().max()) < 1e-6
    assert float(diff.min()) > 0.05


def test_unpickler_refuses_anything_but_numpy_arrays():
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))
    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        _NumpyOnlyUnpickler(io.BytesIO(pickle.dumps(Evil()))).load()
    arrays = {"w": np.arange(6, dtype=np.float32).reshape(2, 3)}
    loaded = _NumpyOnlyUnpickler(io.BytesIO(pickle.dumps(arrays))).load()
    np.testing.assert_array_equal(loaded["w"], arrays["w"])


def test_missing_weights_are_reported(tmp_path, monkeypatch):
    monkeypatch.setenv("THERMAL4D_LPIPS_WEIGHTS", str(tmp_path / "none.ckpt"))
    assert not Lpips.available()
    with pytest.raises(FileNotFoundError, match="make setup"):
        Lpips()
