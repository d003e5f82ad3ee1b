"""How many threads training uses, from the CPU time other processes take.

On the 2-core appliance two threads make a step 1.3-1.7x faster than one while training has the
machine. When another process keeps a core busy (the capture beside live training, a second run)
two threads fight it for the cores and are slower than one: a trained 160x120 model's step took
20-23 ms on two threads idle, 44 ms on two threads and 29 ms on one with a core busy; a 640x480
run's windows 67-73, 148 and 114 ms (docs/rasterizer.md, "Threads that follow the machine";
`bench/results/wait-policy/`). So every `period_s` the trainer compares the machine's busy time
(/proc/stat) with its own (os.times) and trains on one thread while the others take more than
`down_at` of a core, and on all of its threads again once they take less than `up_at`.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import torch

_lowered: tuple[int, int] | None = None    # (the thread count a ThreadShare set, the count before it)


def machine_busy_s(stat: str = "/proc/stat") -> float | None:
    """CPU seconds all processors have spent busy since boot (user, nice, system, irq, softirq and
    steal: time another virtual machine took), or None where there is no /proc/stat."""
    try:
        with open(stat) as f:
            fields = f.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def own_cpu_s() -> float:
    """CPU seconds this process (all its threads) has used."""
    t = os.times()
    return t.user + t.system


def others_cores(busy_s: float, own_s: float, wall_s: float) -> float:
    """Cores the rest of the machine kept busy on average over wall_s seconds in which the machine
    was busy busy_s CPU seconds and this process used own_s of them."""
    return max(0.0, busy_s - own_s) / wall_s if wall_s > 0 else 0.0


def threads_for(others: float, current: int, most: int, cpus: int, down_at: float = 0.4,
                up_at: float = 0.2) -> int:
    """Threads to train on (1..most), now `current`, while others keep `others` cores busy on a
    machine of `cpus`: a core counts as taken once the others use more than `down_at` of it, and
    as free again only once they use less than `up_at` of it (no flapping on a load between)."""
    def fit(margin: float) -> int:
        return max(1, min(most, math.floor(cpus - others + margin)))

    if fit(down_at) < current:
        return fit(down_at)
    return max(current, fit(up_at))


FIXED_ENV = "RECON_FIXED_THREADS"    # =1: never share (results then do not depend on the machine's load)


def sharing_allowed() -> bool:
    """False where the environment asks for fixed threads (the test suite does: torch's float sums
    depend on the thread count, and tests compare numbers)."""
    return os.environ.get(FIXED_ENV, "") != "1"


def threads_asked() -> int:
    """torch's thread count as its caller set it: if a ThreadShare lowered it (a trainer that has
    ended, say) and it is still as lowered, the count before that."""
    n = torch.get_num_threads()
    return _lowered[1] if _lowered and _lowered[0] == n else n


@dataclass
class ThreadShare:
    """Call `update()` once per iteration; it returns the new thread count when it changes it
    (torch.set_num_threads: torch's ops and the native kernels follow), else None."""
    most: int
    period_s: float = 1.0
    cpus: int = 0                      # 0: the processors this process may run on

    def __post_init__(self):
        self.cpus = self.cpus or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                  else os.cpu_count() or 1)
        self.current = self.most
        self.others = 0.0
        self.switches = 0
        self._last = self._sample()

    @staticmethod
    def _sample() -> tuple[float, float, float] | None:
        busy = machine_busy_s()
        return None if busy is None else (time.monotonic(), busy, own_cpu_s())

    def update(self) -> int | None:
        if self._last is None or self.most <= 1 or time.monotonic() - self._last[0] < self.period_s:
            return None
        now = self._sample()
        if now is None:
            return None
        (t0, b0, o0), (t1, b1, o1) = self._last, now
        self._last = now
        self.others = others_cores(b1 - b0, o1 - o0, t1 - t0)
        n = threads_for(self.others, self.current, self.most, self.cpus)
        if n == self.current:
            return None
        global _lowered
        _lowered = (n, threads_asked())
        torch.set_num_threads(n)
        self.current = n
        self.switches += 1
        return n
