"""The C heap's behaviour for training: keep freed memory in the process instead of returning it.

A training step allocates and frees the same few dozen tensors every iteration; at 640x480 many of
them are 1-30 MB (images, (N, 32) embedding gradients, per-Gaussian arrays). With glibc's defaults a
block that large is mmap'ed when allocated and unmapped when freed (or the heap top is trimmed), so
every step pays a page fault and a page zeroing per 4 kB of it: 1120 faults (4.5 MB) per
640x480 windowed step, 229 with these settings. `retain_freed_memory` sets glibc's mmap threshold to its maximum (32 MB)
and its trim threshold to 1 GB, so those blocks are reused from the heap
(docs/training.md "The heap keeps what a step frees"). The process holds its peak heap until it
exits; no values change.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD = -1     # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 * 1024 * 1024      # glibc's largest allowed value on 64-bit
TRIM_THRESHOLD = 1024 * 1024 * 1024

_done: bool | None = None


def retain_freed_memory() -> bool:
    """Set the thresholds once per process. Returns whether they are set (False where the C
    library is not glibc, e.g. macOS or musl: nothing is changed there)."""
    global _done
    if _done is None:
        _done = False
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                mallopt = libc.mallopt
            except (OSError, AttributeError):
                return False
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            _done = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _done
