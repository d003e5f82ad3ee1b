"""recon/train/cores.py: training takes one thread while another process keeps a core busy."""
import os
import subprocess
import sys
import time

import pytest
import torch

from recon.train.cores import (ThreadShare, machine_busy_s, others_cores, sharing_allowed, threads_asked,
                               threads_for)


def test_threads_for_drops_on_a_taken_core_and_returns_only_when_it_is_free():
    # 2 cores, up to 2 threads: down above 0.4 of a core taken, up again below 0.2
    assert threads_for(0.0, 2, 2, 2) == 2
    assert threads_for(0.35, 2, 2, 2) == 2
    assert threads_for(0.45, 2, 2, 2) == 1
    assert threads_for(1.5, 2, 2, 2) == 1          # never below one
    assert threads_for(0.3, 1, 2, 2) == 1          # between the thresholds: stays
    assert threads_for(0.1, 1, 2, 2) == 2
    # 8 cores, up to 8 threads: one thread per core the others leave
    assert threads_for(2.5, 8, 8, 8) == 5
    assert threads_for(2.5, 5, 8, 8) == 5
    assert threads_for(0.1, 5, 8, 8) == 8
    assert threads_for(0.0, 4, 4, 8) == 4          # never above what was asked


def test_the_suite_trains_on_fixed_threads_and_a_run_shares_by_default(monkeypatch):
    assert not sharing_allowed()                 # tests/conftest.py: numbers must not follow the load
    monkeypatch.delenv("RECON_FIXED_THREADS")
    assert sharing_allowed()


def test_others_cores_is_the_busy_time_this_process_did_not_use():
    assert others_cores(busy_s=3.0, own_s=2.0, wall_s=2.0) == pytest.approx(0.5)
    assert others_cores(busy_s=1.0, own_s=1.2, wall_s=1.0) == 0.0      # tick rounding: never negative


def test_machine_busy_s_reads_proc_stat(tmp_path):
    stat = tmp_path / "stat"
    hz = os.sysconf("SC_CLK_TCK")
    # user nice system idle iowait irq softirq steal guest guest_nice
    stat.write_text(f"cpu  {hz} 0 {hz} 999999 77 0 0 {hz} 0 0\ncpu0 1 2 3 4\n")
    assert machine_busy_s(str(stat)) == pytest.approx(3.0)
    assert machine_busy_s(str(tmp_path / "missing")) is None


@pytest.mark.skipif(not os.path.exists("/proc/stat") or len(os.sched_getaffinity(0)) != 2,
                    reason="measures a real busy process on a 2-core Linux machine")
def test_a_busy_process_beside_training_takes_it_to_one_thread_and_back():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        share = ThreadShare(2, period_s=0.3)
        busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and share.current != 1:
                share.update()
                time.sleep(0.02)
            assert share.current == 1 and torch.get_num_threads() == 1, f"others measured: {share.others:.2f} cores"
            assert threads_asked() == 2          # a trainer made after this one still gets the 2 asked for
        finally:
            busy.kill()
            busy.wait()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and share.current != 2:
            share.update()
            time.sleep(0.02)
        assert share.current == 2 and torch.get_num_threads() == 2, f"others measured: {share.others:.2f} cores"
    finally:
        torch.set_num_threads(before)          # whatever failed: the rest of the suite keeps its threads
