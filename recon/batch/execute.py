"""One `recon batch` job, executed where a Ray worker (or the caller) runs it: exactly
`recon run INPUT --out RUNS/NAME --method M --seed S ...` through the same CLI code, with
`--resume` when an earlier attempt left a checkpoint. Output goes to RUNS/NAME/log.txt, the
job's state to RUNS/NAME/job.json."""
from __future__ import annotations

import os
import re
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Callable

from recon.batch.jobs import Job, has_checkpoint, read_json
from rig.session import write_json_atomic

RESUMED = re.compile(r"resumed at iteration (\d+)")


def node_id() -> str | None:
    """The Ray node this process runs on (None outside Ray)."""
    try:
        import ray
        return ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    except Exception:       # noqa: BLE001 - a worker without a runtime context is just "unknown"
        return None


def run_argv(job: Job, run_dir: Path, resume: bool) -> list[str]:
    """recon run's command line for a job: spec {"iterations": 300, "fixed": True} ->
    ["--iterations", "300", "--fixed"]."""
    argv = ["run", job.input, "--out", str(run_dir), "--method", job.method, "--threads", str(job.threads)]
    if job.seed is not None:
        argv += ["--seed", str(job.seed)]
    for key, value in job.spec.items():
        flag = "--" + key.replace("_", "-")
        if value is True:
            argv.append(flag)
        elif value not in (None, False):
            argv += [flag, str(value)]
    return argv + (["--resume"] if resume else [])


def last_line(path: Path) -> str | None:
    try:
        lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return None
    return lines[-1] if lines else None


def run_recon(job: Job, run_dir: Path, resume: bool) -> int:
    """A `recon batch` job's work: `recon run` with the job's options. -> exit code"""
    from recon.cli import main as recon_main      # the whole CLI: imported in the worker only
    return recon_main(run_argv(job, run_dir, resume))


def execute_job(job: dict, runs: str, work: Callable[[Job, Path, bool], int] = run_recon) -> dict:
    """Run one job to the end with `work(job, run_dir, resume) -> exit code`, keeping
    RUNS/NAME/job.json and log.txt. Errors are caught and reported, never raised (a job that
    fails on its input fails the same way on every retry). A worker that dies mid-job is
    retried by Ray, and `resume` tells the work to go on from the checkpoint it left.
    -> {name, state ("done" | "failed"), error, seconds, attempts, node, resumed_from}"""
    from recon.train.guard import TrainingDiverged    # torch: in the worker only, as run_recon's CLI
    job = Job(**job)
    run_dir = job.run_dir(Path(runs))
    run_dir.mkdir(parents=True, exist_ok=True)
    previous = read_json(run_dir / "job.json") or {}
    state = {"state": "running", "attempts": int(previous.get("attempts", 0)) + 1, "node": node_id(),
             "pid": os.getpid(), "started_unix": time.time(), "ended_unix": None, "seconds": None,
             "resumed_from": None, "error": None}
    write_json_atomic(run_dir / "job.json", state)
    resume = has_checkpoint(run_dir) and not (run_dir / "metrics.json").exists()
    log_path = run_dir / "log.txt"
    t0 = time.perf_counter()
    with open(log_path, "a", buffering=1) as log, redirect_stdout(log), redirect_stderr(log):
        print(f"=== attempt {state['attempts']} on node {state['node']} pid {os.getpid()}: {job.name}"
              + (" (resuming)" if resume else ""), flush=True)
        try:
            code = work(job, run_dir, resume)
            message = None
        except SystemExit as exc:           # recon run's loud failures (a divergence it could not recover)
            code = exc.code if isinstance(exc.code, int) else 1
            message = None if isinstance(exc.code, int) else str(exc.code)
        except TrainingDiverged as exc:     # the same, from work that trains without recon run's CLI
            code, message = 1, str(exc)
        except Exception as exc:            # noqa: BLE001 - reported in job.json, not raised into Ray
            code, message = 1, f"internal error: {type(exc).__name__}: {exc}"
        if message:
            print(message, flush=True)
    text = log_path.read_text(errors="replace")
    resumed = RESUMED.findall(text.split("=== attempt")[-1])
    state.update(state="done" if code == 0 else "failed", ended_unix=time.time(),
                 seconds=round(time.perf_counter() - t0, 2),
                 resumed_from=int(resumed[-1]) if resumed else None,
                 error=None if code == 0 else (message or last_line(log_path) or f"exit code {code}"))
    write_json_atomic(run_dir / "job.json", state)
    return {"name": job.name, **state}
