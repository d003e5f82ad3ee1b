"""Session folder: crash safety (kill -9 mid-capture), torn lines, reading while writing."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from rig.session import SessionWriter, open_session

W, H = 32, 24


def frame(i: int) -> tuple[bytes, dict]:
    counts = np.full((H, W), 1000 + i, "<u2")
    counts[0, 0] = i
    return counts.tobytes(), {"block_id": i + 1, "device_ts": 10 ** 9 * i, "host_ns": 5 * 10 ** 8 * i,
                              "width": W, "height": H, "pixel_format": "Mono16",
                              "ir_format": "TemperatureLinear10mK", "scale_k": 0.01, "complete": True,
                              "missing_packets": 0, "dropped_before": 0}


def test_roundtrip_and_chunk_rotation(tmp_path):
    w = SessionWriter(tmp_path / "s", {"note": "x"}, chunk_bytes=3 * W * H * 2)
    w.add_thermal([frame(i) for i in range(4)])
    w.add_thermal([frame(4)])
    w.add_event({"event": "nuc", "host_ns": 1})
    w.close({"why": "test"})
    s = open_session(tmp_path / "s")
    assert s.closed and s.summary["thermal_frames"] == 5 and s.meta["note"] == "x"
    assert len({r["chunk"] for r in s.thermal}) == 2          # rotated after 3 frames
    for f in s.iter_thermal():
        assert f.counts[0, 0] == f.index and f.counts[1, 1] == 1000 + f.index
        assert f.kelvin()[1, 1] == pytest.approx((1000 + f.index) * 0.01)
    assert s.events == [{"event": "nuc", "host_ns": 1}]


def test_refuses_to_overwrite(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "x").write_text("keep me")
    with pytest.raises(FileExistsError):
        SessionWriter(tmp_path / "s", {})


def test_torn_last_line_is_ignored_until_completed(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    w.add_thermal([frame(0), frame(1)])
    s = open_session(tmp_path / "s")
    assert len(s.thermal) == 2
    data, rec = frame(2)
    line = json.dumps({"i": 2, **rec, "chunk": s.thermal[0]["chunk"], "offset": 2 * len(data),
                       "nbytes": len(data)}) + "\n"
    with open(tmp_path / "s" / "thermal.jsonl", "a") as f:      # a writer dying mid-line
        f.write(line[:25])
    assert s.refresh()["thermal"] == 0 and len(s.thermal) == 2
    assert len(open_session(tmp_path / "s").thermal) == 2
    w.add_thermal([frame(2)])            # (a resumed writer would start a new line; here the
    assert s.refresh()["thermal"] == 0   #  torn prefix glues to it and that line is unreadable)
    assert s.torn_or_bad_lines == 1


WRITER = textwrap.dedent("""
    import sys, numpy as np
    sys.path.insert(0, {root!r})
    from tests.test_rig_session import frame
    from rig.session import SessionWriter
    w = SessionWriter(sys.argv[1], {{}}, chunk_bytes=40 * {nbytes})
    i = 0
    while True:
        batch = [frame(i + k) for k in range(1 + i % 3)]      # group commits of 1..3 frames
        w.add_thermal(batch)
        i += len(batch)
        print(i, flush=True)                                  # frames committed so far
""")


def test_kill_9_leaves_every_committed_frame_readable(tmp_path):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    script = WRITER.format(root=root, nbytes=W * H * 2)
    proc = subprocess.Popen([sys.executable, "-c", script, str(tmp_path / "s")], stdout=subprocess.PIPE, text=True)
    committed = 0
    while committed < 150:
        committed = int(proc.stdout.readline())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    rest = proc.stdout.read().split()
    committed = max([committed] + [int(x) for x in rest])
    s = open_session(tmp_path / "s")
    assert not s.closed
    assert len(s.thermal) >= committed                        # nothing acknowledged is lost
    for f in s.iter_thermal():                                # and everything indexed loads
        assert f.counts[0, 0] == f.index and np.all(f.counts[1:] == 1000 + f.index)
    assert [r["i"] for r in s.thermal] == list(range(len(s.thermal)))


def test_follow_sees_frames_while_they_are_written(tmp_path):
    w = SessionWriter(tmp_path / "s", {})
    seen = []

    def write():
        for i in range(30):
            w.add_thermal([frame(i)])
            time.sleep(0.005)
        w.close()
    t = threading.Thread(target=write)
    t.start()
    time.sleep(0.02)
    for kind, f in open_session(tmp_path / "s").follow(poll_s=0.01, timeout_s=5):
        if kind == "thermal":
            assert f.counts[0, 0] == f.index
            seen.append(f.index)
    t.join()
    assert seen == list(range(30))
