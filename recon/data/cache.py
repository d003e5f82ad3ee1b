"""A least-recently-used cache bounded by the bytes of the numpy arrays it holds."""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Hashable

import numpy as np


class ByteLRU:
    """Keeps at most `max_bytes` of arrays; the least recently used go first.

    Cached arrays are made read-only, since every caller shares them. An array larger than
    the whole budget is returned without being kept. Thread-safe (a loader thread may prefetch).
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self.nbytes = 0
        self._items: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._items)

    def get(self, key: Hashable, load: Callable[[], np.ndarray]) -> np.ndarray:
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        value = load()
        value.flags.writeable = False
        with self._lock:
            if value.nbytes > self.max_bytes or key in self._items:
                return value
            self._items[key] = value
            self.nbytes += value.nbytes
            while self.nbytes > self.max_bytes:
                _, old = self._items.popitem(last=False)
                self.nbytes -= old.nbytes
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self.nbytes = 0
