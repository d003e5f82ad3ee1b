"""Every malformed dataset gets a DatasetError naming the file and the problem."""
import json
from pathlib import Path

import numpy as np
import pytest

from recon.data import DatasetError, Frame, load_dataset, write_dataset


@pytest.fixture
def dataset(tmp_path) -> Path:
    """A valid two-frame dataset to break in each test."""
    c2w = np.eye(4)
    frames = [
        (Frame("rgb/0.png", "rgb", "cam0", 0.0, 0.0, c2w, 10, 10, 4, 3, 8, 6),
         np.zeros((6, 8, 3), np.uint8)),
        (Frame("thermal/0.png", "thermal", "cam0", 0.5, 1.0, c2w, 10, 10, 4, 3, 8, 6),
         np.full((6, 8), 30000, np.uint16)),
    ]
    write_dataset(tmp_path, frames, 0.01, (250.0, 400.0))
    load_dataset(tmp_path)  # sanity: valid as written
    return tmp_path


def _edit(root: Path, change) -> None:
    path = root / "transforms.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _fails(root: Path, *fragments: str) -> str:
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    message = str(err.value)
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_missing_transforms(tmp_path):
    _fails(tmp_path, "transforms.json", "not found")


def test_bad_json(dataset):
    (dataset / "transforms.json").write_text('{"frames": [ {"file_path": "rgb/0.png",, ]}')
    _fails(dataset, "transforms.json", "bad JSON", "line 1")


def test_missing_image(dataset):
    (dataset / "rgb" / "0.png").unlink()
    _fails(dataset, "rgb/0.png", "image missing")


def test_size_mismatch_with_w_h(dataset):
    _edit(dataset, lambda d: d["frames"][0].update(w=9))
    _fails(dataset, "rgb/0.png", "8x6", "9x6")


def test_unknown_modality(dataset):
    _edit(dataset, lambda d: d["frames"][1].update(modality="infrared"))
    _fails(dataset, "transforms.json", "thermal/0.png", "unknown modality 'infrared'")


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_matrix(dataset, bad):
    def change(d):
        d["frames"][0]["transform_matrix"][0][3] = bad
    _edit(dataset, change)
    _fails(dataset, "rgb/0.png", "non-finite")


@pytest.mark.parametrize("matrix", [np.diag([2.0, 2.0, 2.0, 1.0]), np.diag([1.0, 1.0, -1.0, 1.0]),
                                    np.array([[1, 0.1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])])
def test_non_rigid_matrix(dataset, matrix):
    _edit(dataset, lambda d: d["frames"][1].update(transform_matrix=matrix.tolist()))
    _fails(dataset, "thermal/0.png", "not rigid")


def test_matrix_with_wrong_shape_or_last_row(dataset):
    _edit(dataset, lambda d: d["frames"][0].update(transform_matrix=np.eye(4)[:3].tolist()))
    _fails(dataset, "rgb/0.png", "4x4")
    m = np.eye(4)
    m[3, 0] = 0.5
    _edit(dataset, lambda d: d["frames"][0].update(transform_matrix=m.tolist()))
    _fails(dataset, "rgb/0.png", "last row")


@pytest.mark.parametrize("time", [-0.01, 1.5, "0.5", None])
def test_time_outside_unit_interval_or_not_a_number(dataset, time):
    _edit(dataset, lambda d: d["frames"][0].update(time=time))
    _fails(dataset, "rgb/0.png", "time")


def test_missing_time(dataset):
    _edit(dataset, lambda d: d["frames"][0].pop("time"))
    _fails(dataset, "rgb/0.png", "time missing")


def test_thermal_needs_scale_and_range(dataset):
    _edit(dataset, lambda d: d.pop("thermal_scale_k"))
    _fails(dataset, "transforms.json", "thermal_scale_k")


def test_thermal_image_must_be_16_bit(dataset):
    import cv2
    cv2.imwrite(str(dataset / "thermal" / "0.png"), np.zeros((6, 8), np.uint8))
    _fails(dataset, "thermal/0.png", "16-bit")


def test_rgb_image_must_be_colour(dataset):
    import cv2
    cv2.imwrite(str(dataset / "rgb" / "0.png"), np.zeros((6, 8), np.uint8))
    _fails(dataset, "rgb/0.png", "8-bit RGB")


def test_duplicate_file_path(dataset):
    _edit(dataset, lambda d: d["frames"].append(dict(d["frames"][0])))
    _fails(dataset, "rgb/0.png", "more than one frame")


def test_split_lists_must_name_frames(dataset):
    _edit(dataset, lambda d: d.update(test_filenames=["rgb/404.png"]))
    _fails(dataset, "test_filenames", "rgb/404.png")


def test_unknown_camera_model(dataset):
    _edit(dataset, lambda d: d.update(camera_model="FISHEYE"))
    _fails(dataset, "transforms.json", "FISHEYE")


def test_missing_intrinsics(dataset):
    _edit(dataset, lambda d: d["frames"][0].pop("fl_x"))
    _fails(dataset, "rgb/0.png", "fl_x missing")


def test_top_level_intrinsics_are_a_fallback(dataset):
    def change(d):
        d.update(fl_x=12.0)
        d["frames"][0].pop("fl_x")
    _edit(dataset, change)
    assert load_dataset(dataset).frames[0].fx == 12.0


def test_broken_points_ply(dataset):
    (dataset / "points3d.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\n"
                                           b"property float x\nend_header\n1\n")
    _fails(dataset, "points3d.ply", "lacks y")


def test_default_and_explicit_splits(dataset):
    _edit(dataset, lambda d: d["frames"][1].update(camera="cam1"))
    assert [f.split for f in load_dataset(dataset).frames] == ["train", "test"]
    _edit(dataset, lambda d: d.update(train_filenames=["thermal/0.png"]))
    assert [f.split for f in load_dataset(dataset).frames] == ["test", "train"]
