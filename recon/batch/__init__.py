"""`recon batch`: many (input, method, seed) runs as Ray tasks, on this machine or a cluster.

One job = what `recon run INPUT --out RUNS/NAME --method M --seed S` does (prepare a session,
train, render, grade, export), executed by the same code in a Ray worker. The driver
(`recon.batch.ray_runner`) keeps the list and the states; each job writes its own state file, so
whatever dies, the folders on disk say what is finished.

Contract, ``RUNS/`` (format "thermal4d-batch", v1); every JSON file replaced whole (written to a
hidden temporary file, then os.replace):

  batch.json         the driver's view, rewritten every few seconds while it runs:
                     format, version, state ("running" | "done" | "interrupted"), address (Ray
                     address or "local"), nodes (alive Ray nodes), started_unix, updated_unix,
                     counts {queued, running, done, failed}, jobs: [JOB, ...] in submission order,
                     JOB = {name, input, method, seed (int or null), run_dir (relative to RUNS, also
                     the job's name), state ("queued" | "running" | "done" | "failed" | "skipped"
                     = finished by an earlier batch), attempts, node (Ray node id or null),
                     progress [0, 1] (from RUN/live/status.json while running), iteration,
                     error (one line or null), seconds (wall time of the last attempt or null),
                     metrics (flat summary once done: psnr_rgb, psnr_thermal, mae_k_thermal,
                     mae_k_moving, ... as in summary.json, else null)}
  NAME/job.json      written by the worker: state ("running" | "done" | "failed"), attempts,
                     node, pid, started_unix, ended_unix, seconds, resumed_from (iteration or
                     null), error
  NAME/...           the usual `recon run` folder (see recon/run.py), plus NAME/log.txt (the
                     job's stdout and stderr)
  summary.json       after the batch: per job its flat metrics and speed; per method median and
                     worst over jobs
  summary.md         the same as Markdown tables
  speed_vs_accuracy.png   accuracy against training time, every job, one colour per method
"""
