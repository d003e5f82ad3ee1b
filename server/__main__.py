"""`python -m server`: the status page on its own, for a run and/or a session folder, or a batch."""
from __future__ import annotations

import argparse
import sys
import threading

from server.app import DEFAULT_HOST, DEFAULT_PORT, serve


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m server", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Serve the thermal4d status page: live renders, training progress and capture "
                    "health, read from a run folder (RUN/live/, written by recon.live.publish) and a "
                    "session folder (written by `rig capture`), or of every job of a `recon batch` folder. "
                    "Any may still be empty or absent; the page fills in as they are published.",
        epilog="examples:\n"
               "  python -m server --run runs/live --session sessions/s1\n"
               "  python -m server --session sessions/s1 --host 0.0.0.0 --port 9000   # reachable from the LAN\n"
               "  python -m server --batch runs/b1      # a batch: the jobs' table, each job's page at /job/N/\n"
               "endpoints: /  /api/status  /api/metrics?max=N  /api/gaussians  /api/renders\n"
               "           /api/capture  /api/sync  /render/{latest,t00..}/{rgb.png,thermal.png,kelvin.npy}\n"
               "           /api/batch  /job/N/  /job/N/api/...  /job/N/render/...   (job N of batch.json: its run)\n"
               "the viewer (/view: any pose, any time) needs the model loaded: `recon view RUN` serves it")
    p.add_argument("--run", metavar="RUN", help="a `recon run` output folder (reads RUN/live/)")
    p.add_argument("--session", metavar="SESSION", help="a `rig capture` session folder")
    p.add_argument("--batch", metavar="RUNS", help="a `recon batch` folder (reads RUNS/batch.json and each job's run)")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to bind (default: {DEFAULT_HOST}, this machine only)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"TCP port (default: {DEFAULT_PORT}; 0 = any free)")
    p.add_argument("--verbose", action="store_true", help="log every request to stderr")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if not args.run and not args.session and not args.batch:
        parser().error("give --run RUN, --session SESSION or both (or --batch RUNS)")
    if not 0 <= args.port <= 65535:
        parser().error(f"--port must be in 0..65535, got {args.port}")
    try:
        handle = serve(args.host, args.port, run_dir=args.run, session_dir=args.session,
                       batch_dir=args.batch, verbose=args.verbose)
    except OSError as exc:
        print(f"server: cannot listen on {args.host}:{args.port}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"status page: {handle.url}  (Ctrl-C to stop)", flush=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        handle.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
