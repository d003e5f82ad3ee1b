"""Phone drop folder: PyAV decode with per-frame PTS, QuickTime creationdate, settling, photos."""
import threading
import time

import numpy as np
import pytest

from rig.drivers.phone import DropFolder, decode_frames, parse_creationdate, probe_video, read_photo
from tests.fakes.fake_phone import drop_slowly, iso_creationdate, write_mov


def moving_square(n: int, w=96, h=64):
    for i in range(n):
        img = np.full((h, w, 3), 30, np.uint8)
        img[20:40, 4 + 3 * i:24 + 3 * i] = (250, 200, 40)
        yield img


@pytest.mark.parametrize("codec", ["libx264", "libx265"])
def test_vfr_pts_and_creationdate(tmp_path, codec):
    pts_s = [0, 1 / 30, 2 / 30, 0.11, 0.15, 5 / 30, 6 / 30, 0.245]   # variable frame intervals
    created = 1_717_000_000.0
    write_mov(tmp_path / "IMG_0001.MOV", moving_square(len(pts_s)), pts_s, created, codec=codec)
    info = probe_video(tmp_path / "IMG_0001.MOV")
    assert info.time_base == (1, 600)
    assert [f["pts"] for f in info.frames] == [round(t * 600) for t in pts_s]
    assert info.creationdate.endswith("+0200") and info.creation_unix_s == created
    assert sum(info.frames[0]["motion"]) == 0 and all(sum(f["motion"]) > 0 for f in info.frames[1:])
    assert info.codec == ("h264" if codec == "libx264" else "hevc")
    frames = list(decode_frames(tmp_path / "IMG_0001.MOV", start_pts=round(0.11 * 600)))
    assert [p for p, _ in frames] == [round(t * 600) for t in pts_s[3:]]
    img = frames[0][1]
    assert img.shape == (64, 96, 3) and img[30, 4 + 9 + 10, 0] > 200 and img[5, 5, 0] < 60


@pytest.mark.parametrize("text,unix", [
    ("2024-05-29T18:26:40+0200", 1717000000), ("2024-05-29T16:26:40Z", 1717000000),
    ("2024-05-29T12:26:40-04:00", 1717000000), ("garbage", None)])
def test_parse_creationdate(text, unix):
    assert parse_creationdate(text) == unix
    if unix:
        assert parse_creationdate(iso_creationdate(unix, 2)) == unix


def test_drop_folder_waits_for_copy_to_finish(tmp_path):
    src_dir, drop = tmp_path / "phone", tmp_path / "drop"
    src_dir.mkdir()
    drop.mkdir()
    src = write_mov(src_dir / "IMG_0002.MOV", moving_square(60, 320, 240), [i / 30 for i in range(60)], 1.7e9)
    (drop / ".IMG_0003.MOV").write_bytes(b"hidden")
    (drop / "IMG_0004.MOV.part").write_bytes(b"partial")
    (drop / "notes.txt").write_text("not media")
    folder = DropFolder(drop, settle_s=0.3)
    copier = threading.Thread(target=drop_slowly, args=(src, drop), kwargs={"chunk": 4096, "delay_s": 0.02})
    copier.start()
    early = []
    while copier.is_alive():
        early += folder.poll()
        time.sleep(0.05)
    assert early == []                                   # never handed over while growing
    ready = []
    deadline = time.monotonic() + 3
    while not ready and time.monotonic() < deadline:
        ready = folder.poll()
        time.sleep(0.05)
    assert ready == [drop / "IMG_0002.MOV"]
    assert len(probe_video(ready[0]).frames) == 60
    folder.mark_done(ready[0])
    time.sleep(0.35)
    assert folder.poll() == []


def test_missing_drop_folder_is_a_clear_error(tmp_path):
    with pytest.raises(NotADirectoryError, match="drop folder"):
        DropFolder(tmp_path / "nope")


def test_photos_jpeg_and_heic(tmp_path):
    from PIL import Image
    img = np.zeros((40, 60, 3), np.uint8)
    img[:, :30] = (200, 30, 30)
    Image.fromarray(img).save(tmp_path / "IMG_1.JPG", quality=95)
    pillow_heif = pytest.importorskip("pillow_heif")
    pillow_heif.from_bytes(mode="RGB", size=(60, 40), data=img.tobytes()).save(tmp_path / "IMG_2.HEIC", quality=95)
    for name in ("IMG_1.JPG", "IMG_2.HEIC"):
        out = read_photo(tmp_path / name)
        assert out.shape == (40, 60, 3)
        assert abs(int(out[20, 10, 0]) - 200) < 12 and out[20, 50].max() < 15
