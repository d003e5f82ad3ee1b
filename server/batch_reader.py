"""Reads a `recon batch` folder (contract: recon/batch/__init__.py): RUNS/batch.json and, per job,
that job's run folder RUNS/<run_dir>/ through a RunReader.

batch.json is cached like the run files (re-parsed only when its stat changes) and size-limited.
A job is named by its index in batch.json's job list, never by a path from the request; the
job's run_dir (from batch.json) must resolve strictly inside RUNS, else the job is refused.
"""
from __future__ import annotations

import threading
import time
from collections import OrderedDict
from functools import partial
from pathlib import Path

from server.run_reader import CachedFile, RunReader, read_json

MAX_BATCH_BYTES = 8 << 20         # batch.json larger than this is refused (~20k jobs)
MAX_JOB_READERS = 16              # run readers kept for recently viewed jobs


class JobError(Exception):
    """A job URL that cannot be served: .status is the HTTP status (404 no such job, 403 refused)."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


class BatchReader:
    """The published state of one batch folder (RUNS/)."""

    def __init__(self, runs_dir: str | Path):
        self.runs_dir = Path(runs_dir)
        self._batch = CachedFile(self.runs_dir / "batch.json", partial(read_json, limit=MAX_BATCH_BYTES))
        self._readers: OrderedDict[Path, RunReader] = OrderedDict()
        self._lock = threading.Lock()

    def batch(self) -> dict | None:
        """batch.json plus age_s (seconds since the driver wrote it), or None before the first."""
        b = self._batch.get()
        if b is None:
            return None
        unix = b.get("updated_unix")
        age = round(time.time() - unix, 3) if isinstance(unix, (int, float)) else None
        return {**b, "age_s": age}

    def job(self, index: int) -> tuple[dict, RunReader] | None:
        """(job entry, reader of its run folder); None while batch.json does not exist.
        Raises JobError(404) for an index not in the list, JobError(403) for a refused run_dir."""
        b = self._batch.get()
        if b is None:
            return None
        jobs = b.get("jobs")
        if not isinstance(jobs, list) or not 0 <= index < len(jobs) or not isinstance(jobs[index], dict):
            raise JobError(404, f"no job {index} in the batch")
        job = jobs[index]
        return job, self._reader(self.resolve(job.get("run_dir")))

    def resolve(self, run_dir) -> Path:
        """RUNS/run_dir with symlinks resolved; JobError(403) unless strictly inside RUNS."""
        shown = repr(run_dir)[:80]
        if not isinstance(run_dir, str) or not run_dir or "\x00" in run_dir or Path(run_dir).is_absolute():
            raise JobError(403, f"run_dir {shown} is not a folder inside the batch")
        try:
            root = self.runs_dir.resolve()
            target = (root / run_dir).resolve()
        except (OSError, RuntimeError, ValueError):
            raise JobError(403, f"run_dir {shown} cannot be resolved") from None
        if root not in target.parents:
            raise JobError(403, f"run_dir {shown} is not a folder inside the batch")
        return target

    def _reader(self, run_dir: Path) -> RunReader:
        with self._lock:
            reader = self._readers.pop(run_dir, None) or RunReader(run_dir)
            self._readers[run_dir] = reader             # most recently used last
            while len(self._readers) > MAX_JOB_READERS:
                self._readers.popitem(last=False)
            return reader
