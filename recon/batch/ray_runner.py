"""The driver of a batch: jobs become Ray tasks with resource requests (CPU threads, memory) on a
local Ray runtime or an existing cluster; the driver keeps RUNS/batch.json current and, at the
end, returns one result per job. Finished jobs (from an earlier batch) are skipped; a job whose
worker died is retried by Ray and resumes from its checkpoint; a job that fails on its input is
reported and the others go on."""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable

from recon.batch.execute import execute_job, run_recon
from recon.batch.jobs import FORMAT, VERSION, Job, finished, read_json
from rig.session import write_json_atomic

COUNTED = ("queued", "running", "done", "failed", "skipped")


def start_ray(address: str | None, log, local_cpus: int | None = None) -> bool:
    """Connect to a cluster (address) or start a local runtime with local_cpus CPUs (default:
    all); -> True if this call started it (and so must shut it down). A Ray already initialised
    in this process is used as it is."""
    import ray
    if ray.is_initialized():
        return False
    try:
        ray.init(address=address, num_cpus=None if address else local_cpus, include_dashboard=False, log_to_driver=False,
                 logging_level=logging.WARNING, configure_logging=True)
    except ConnectionError as exc:
        raise ValueError(f"--address {address}: no Ray cluster answers there ({exc}); start one with "
                         f"`ray start --head` on the head node") from None
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    cpus = sum(n["Resources"].get("CPU", 0) for n in nodes)
    log(f"ray: {'cluster ' + address if address else 'local runtime'}, {len(nodes)} node(s), {cpus:g} CPUs")
    return True


def check_fits(jobs: list[Job], memory_gb: float) -> None:
    """A task asking for more than any node has would wait forever: refuse it now."""
    import ray
    nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
    most_cpus = max((n.get("CPU", 0) for n in nodes), default=0)
    most_mem = max((n.get("memory", 0) for n in nodes), default=0) / 2**30
    threads = max(j.threads for j in jobs)
    if threads > most_cpus:
        raise ValueError(f"--threads {threads}: no node of the cluster has that many CPUs (largest: {most_cpus:g})")
    if memory_gb > most_mem:
        raise ValueError(f"--memory-gb {memory_gb:g}: no node of the cluster has that much memory "
                         f"(largest: {most_mem:.1f} GiB)")


def job_row(job: Job, runs: Path, state: str, result: dict | None, started: float) -> dict:
    """batch.json's entry for a job: the driver's state merged with what the job wrote (a
    job.json older than this batch's start is an earlier batch's)."""
    run_dir = job.run_dir(runs)
    own = read_json(run_dir / "job.json") or {}
    live = read_json(run_dir / "live" / "status.json") or {}
    if state == "queued" and own.get("state") == "running" and (own.get("started_unix") or 0) >= started:
        state = "running"
    result = result or {}
    row = {"name": job.name, "input": job.input, "method": job.method, "seed": job.seed,
           "run_dir": job.name, "state": state, "attempts": own.get("attempts", 0), "node": own.get("node"),
           "progress": live.get("progress") if state == "running" else (1.0 if state in ("done", "skipped") else None),
           "iteration": live.get("iteration"), "error": result.get("error") or (own.get("error") if state == "failed" else None),
           "seconds": own.get("seconds"), "metrics": None}
    if state in ("done", "skipped"):
        from recon.batch.summary import summarise
        summary = read_json(run_dir / "metrics.json")
        row["metrics"] = summarise(summary) if summary else None
    return row


def write_batch(runs: Path, jobs: list[Job], states: dict[str, str], results: dict[str, dict],
                state: str, address: str | None, started: float) -> dict:
    rows = [job_row(j, runs, states[j.name], results.get(j.name), started) for j in jobs]
    counts = {k: sum(r["state"] == k for r in rows) for k in COUNTED}
    doc = {"format": FORMAT, "version": VERSION, "state": state, "address": address or "local",
           "nodes": _alive_nodes(), "started_unix": started, "updated_unix": time.time(),
           "counts": counts, "jobs": rows}
    write_json_atomic(runs / "batch.json", doc)
    return doc


def _alive_nodes() -> int | None:
    try:
        import ray
        return sum(bool(n.get("Alive")) for n in ray.nodes()) if ray.is_initialized() else None
    except Exception:       # noqa: BLE001 - a cluster that went away: the count is unknown
        return None


def run_batch(jobs: list[Job], runs: Path, work: Callable[[Job, Path, bool], int] = run_recon,
              address: str | None = None, memory_gb: float = 2.0, retries: int = 3,
              log: Callable[[str], None] = print, interval_s: float = 2.0, local_cpus: int | None = None
              ) -> list[dict]:
    """Run every unfinished job as a Ray task `execute_job(job, runs, work)` and wait for all
    (work: `recon run` by default; bench/table.py passes its own).
    -> one batch.json row per job (state done / failed / skipped, metrics, error)."""
    import ray
    runs.mkdir(parents=True, exist_ok=True)
    started = time.time()
    states = {j.name: ("skipped" if finished(j.run_dir(runs)) else "queued") for j in jobs}
    skipped = sum(s == "skipped" for s in states.values())
    if skipped:
        log(f"{skipped} of {len(jobs)} jobs finished in an earlier batch: skipped")
    todo = [j for j in jobs if states[j.name] == "queued"]
    results: dict[str, dict] = {}
    owner = start_ray(address, log, local_cpus) if todo else False
    try:
        if todo:
            check_fits(todo, memory_gb)
        task = ray.remote(execute_job)
        pending = {task.options(num_cpus=j.threads, memory=int(memory_gb * 2**30), max_retries=retries,
                                retry_exceptions=False, name=j.name).remote(j.as_dict(), str(runs), work): j
                   for j in todo}
        write_batch(runs, jobs, states, results, "running", address, started)
        last_note = 0.0
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=interval_s)
            for ref in ready:
                job = pending.pop(ref)
                try:
                    results[job.name] = ray.get(ref)
                except ray.exceptions.RayError as exc:      # the worker died more often than retries
                    results[job.name] = {"state": "failed", "error": _one_line(exc)}
                states[job.name] = results[job.name]["state"]
                log(f"{job.name}: {states[job.name]}" + (f": {results[job.name].get('error')}"
                                                         if states[job.name] == "failed" else ""))
            doc = write_batch(runs, jobs, states, results, "running" if pending else "done", address, started)
            if pending and time.time() - last_note > 30:
                last_note = time.time()
                c = doc["counts"]
                log(f"batch: {c['done'] + c['skipped']} done, {c['running']} running, {c['queued']} queued, "
                    f"{c['failed']} failed ({time.time() - started:.0f} s)")
        return write_batch(runs, jobs, states, results, "done", address, started)["jobs"]
    except KeyboardInterrupt:
        write_batch(runs, jobs, states, results, "interrupted", address, started)
        raise
    finally:
        if owner:
            ray.shutdown()


def _one_line(exc: Exception) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:300]}"
