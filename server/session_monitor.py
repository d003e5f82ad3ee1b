"""Capture statistics of a session folder (also while `rig capture` is writing it), in the background.

A thread refreshes the session (`rig.session`) and recomputes `rig.info.session_info` only when
new records, sync.json or closed.json appeared, at most every `poll_s`; requests read the last
result, so a slow summary never delays a page. The summary walks every record, so on a long
capture it slows down: the monitor then waits longer between summaries, keeping its share of the
interpreter below `max_duty` (with `rig capture --serve` it shares the process with the receiver).
"""
from __future__ import annotations

import threading
import time
from pathlib import Path


def capture_view(info: dict, last_host_ns: int | None) -> dict:
    """The capture-health part of session_info plus whether frames are still arriving."""
    age = None if last_host_ns is None else round((time.monotonic_ns() - last_host_ns) / 1e9, 3)
    state = "closed" if info["closed"] else "recording" if age is not None and age < 5 else "stalled"
    return {"state": state, "last_frame_age_s": age,
            **{k: info[k] for k in ("path", "closed", "duration_s", "streams", "pairs", "markers",
                                    "unreadable_index_lines")}}


def sync_view(info: dict) -> dict:
    return {"residual_ms": info["sync_residual_ms"], "pair_dt_ms_median": info["pair_dt_ms_median"],
            **info["sync"]}


class SessionMonitor:
    def __init__(self, session_dir: str | Path, poll_s: float = 1.0, max_duty: float = 0.1):
        self.path = Path(session_dir)
        self.poll_s, self.max_duty = poll_s, max_duty
        self._session = None
        self._stamp = None
        self._lock = threading.Lock()
        self._capture: dict | None = None
        self._sync: dict | None = None
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="session-monitor", daemon=True)
        self._thread.start()

    def capture(self) -> dict | None:
        with self._lock:
            return self._capture

    def sync(self) -> dict | None:
        with self._lock:
            return self._sync

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def _run(self) -> None:
        while True:
            start = time.monotonic()
            try:
                self.update()
            except Exception as exc:      # a half-made session must not end the monitor
                self.error = f"{type(exc).__name__}: {exc}"
            busy = time.monotonic() - start
            if self._stop.wait(max(self.poll_s, busy / self.max_duty - busy)):
                return

    def _files_stamp(self):
        out = []
        for name in ("sync.json", "closed.json"):
            try:
                st = (self.path / name).stat()
                out.append((st.st_ino, st.st_mtime_ns))
            except OSError:
                out.append(None)
        return tuple(out)

    def update(self) -> bool:
        """Pick up new records; recompute the summary if anything changed. -> whether it did."""
        from rig.info import session_info
        from rig.session import open_session

        if self._session is None:
            try:
                self._session = open_session(self.path)
            except (FileNotFoundError, ValueError):
                return False            # not started yet (or not a session): try again later
        new = self._session.refresh()
        stamp = self._files_stamp()
        if not any(new.values()) and stamp == self._stamp and self._capture is not None:
            return False
        s = self._session
        info = session_info(s)
        last = max((r["host_ns"] for recs in (s.thermal[-1:], s.events[-1:]) for r in recs if "host_ns" in r),
                   default=None)
        with self._lock:
            self._capture, self._sync = capture_view(info, last), sync_view(info)
        self._stamp, self.error = stamp, None
        return True
