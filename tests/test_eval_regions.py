"""Errors where they matter (recon/eval/regions.py): moving, hot, moving-hot and static regions,
from the simulator's object masks, or for a still camera from what changes."""
import json
import math

import numpy as np
import pytest

from recon.batch.summary import flatten
from recon.data import load_dataset
from recon.data.errors import DatasetError
from recon.data.simulate import SimulateConfig, simulate_dataset
from recon.eval import evaluate_run
from recon.eval.evaluate import markdown_table
from recon.eval.regions import (RegionPool, changing_pixels, frame_regions, moving_from_labels, object_masks,
                               object_names)
from recon.eval.renders import write_render_pixels


def test_region_masks_of_a_hand_made_thermal_frame():
    gt = np.full((4, 6), 295.0)
    gt[1:3, 1:3] = 340.0                       # a hot object...
    labels = np.zeros((4, 6), np.uint8)
    labels[1:3, 1:4] = 7                       # ...that moves, with a cold moving edge column
    labels[0, 5] = 2                           # a static labelled object
    valid = np.ones_like(gt, bool)
    valid[3, 0] = False
    moving = moving_from_labels(labels, {7: {"name": "ball", "moving": True}, 2: {"name": "cup", "moving": False}})
    r = frame_regions("thermal", gt, valid, moving)
    assert r["moving"].sum() == 6 and r["hot"].sum() == 4 and r["moving_hot"].sum() == 4
    assert r["static"].sum() == valid.sum() - 6 and not r["static"][3, 0]
    assert moving_from_labels(labels, {}).sum() == 7      # no labels given: every object moves


def test_pooled_metrics_weigh_pixels_not_frames():
    pool = RegionPool()
    big, small = np.ones((10, 10), bool), np.zeros((10, 10), bool)
    small[0, 0] = True
    for mask, err in ((big, 1.0), (small, 11.0)):
        regions = {"moving": mask, "hot": mask, "moving_hot": mask, "static": ~mask}
        frame = pool.add("thermal", regions, np.full((10, 10), err))
    assert frame["moving"] == {"mae_k": 11.0, "p95_k": 11.0, "pixels": 1}
    out = pool.result()["thermal"]["moving"]
    assert out["pixels"] == 101 and out["mae_k"] == pytest.approx((100 * 1 + 11) / 101)
    assert out["p95_k"] == pytest.approx(1.0)
    rgb = RegionPool()
    sq = np.full((10, 10, 3), 0.01)
    rgb.add("rgb", {"moving": big, "static": None}, sq)
    res = rgb.result()["rgb"]
    assert res["moving"]["psnr"] == pytest.approx(20.0) and res["static"] is None   # unknown stays unknown


def test_objects_are_named_regions_pooled_over_frames():
    labels = np.zeros((4, 6), np.uint8)
    labels[0, :2] = 1
    labels[1, :3] = 2
    labels[2, :] = 3
    names = {1: {"name": "pan", "moving": False}, 2: {"name": "ball", "moving": True},
             3: {"name": "ball", "moving": True}, 4: {"name": "", "moving": True}}
    assert object_names(names) == {1: "pan", 2: "ball (label 2)", 3: "ball (label 3)", 4: "label 4"}
    valid = np.ones((4, 6), bool)
    valid[2, 0] = False
    objs = object_masks(labels, object_names(names), valid)
    assert sorted(objs) == ["ball (label 2)", "ball (label 3)", "pan"]      # label 4 is not in view
    assert objs["pan"].sum() == 2 and objs["ball (label 3)"].sum() == 5     # invalid pixels left out
    assert object_masks(labels, {}) == {} and object_masks(None, object_names(names)) == {}
    pool = RegionPool()
    moving = {n: names[k]["moving"] for k, n in object_names(names).items()}
    pool.add_objects("thermal", objs, np.where(labels == 1, 2.0, 0.5), moving)
    pool.add_objects("thermal", {"pan": labels == 1}, np.full((4, 6), 5.0), moving)   # a second frame
    out = pool.objects()["thermal"]
    assert out["pan"] == {"mae_k": pytest.approx(3.5), "p95_k": pytest.approx(5.0), "pixels": 4, "moving": False}
    assert out["ball (label 2)"]["mae_k"] == pytest.approx(0.5) and out["ball (label 2)"]["moving"]


def test_a_still_camera_without_masks_finds_what_changes():
    frames = [np.full((5, 5), 293.0) for _ in range(6)]
    frames[2][1, 1] = 330.0
    changing = changing_pixels(frames, "thermal")
    assert changing[2].sum() == 1 and changing[2][1, 1] and not any(c.any() for i, c in enumerate(changing) if i != 2)


@pytest.fixture(scope="module")
def family(tmp_path_factory):
    out = tmp_path_factory.mktemp("family")
    simulate_dataset(out, SimulateConfig(variant="family-inside", frames=4, width=64, height=48, seed=2, points=200))
    return out


def test_simulator_writes_masks_and_an_offset_on_the_moving_object_shows_only_there(family, tmp_path):
    ds = load_dataset(family)
    doc = json.loads((family / "transforms.json").read_text())
    assert any(v["moving"] for v in doc["mask_labels"].values())
    test = [f for f in ds.frames if f.split == "test"]
    assert all(f.mask_path and ds.mask(f).shape == (f.height, f.width) for f in test)
    run = tmp_path / "run"
    offset = 3.0
    for f in test:                              # renders = ground truth, +3 K on moving pixels
        if f.modality == "rgb":
            pixels = ds.read_raw(f)
        else:
            moving = moving_from_labels(ds.mask(f), ds.mask_labels)
            kelvin = np.nan_to_num(ds.image(f)) + offset * moving
            pixels = np.round(kelvin / ds.thermal_scale_k).astype(np.uint16)
        write_render_pixels(run, f, pixels)
    result = evaluate_run(run, family, use_lpips=False)
    th = result["regions"]["thermal"]
    assert th["moving"]["mae_k"] == pytest.approx(offset, abs=0.01) and th["moving"]["pixels"] > 20
    assert th["static"]["mae_k"] < 0.01 and th["moving"]["p95_k"] == pytest.approx(offset, abs=0.01)
    assert math.isinf(result["regions"]["rgb"]["moving"]["psnr"])
    assert "regions" in result["per_frame"][0]
    objects = result["objects"]["thermal"]                 # each moving object carries the offset
    assert objects and all(m["mae_k"] == pytest.approx(offset if m["moving"] else 0.0, abs=0.01)
                           for m in objects.values()), objects
    assert any(m["moving"] for m in objects.values())
    assert "| thermal | " + next(iter(objects)) + " |" in markdown_table(result)
    assert flatten(result)["mae_k_worst_moving_object"] == pytest.approx(offset, abs=0.01)   # tables' column


def test_a_bad_mask_is_named(family, tmp_path):
    import shutil
    bad = tmp_path / "bad"
    shutil.copytree(family, bad)
    ds = load_dataset(bad)
    frame = next(f for f in ds.frames if f.mask_path)
    (bad / frame.mask_path).write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=frame.mask_path.replace("/", ".")):
        load_dataset(bad).mask(frame)
