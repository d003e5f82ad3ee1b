"""`--serve/--host/--port` for the CLIs that start the status page (`rig capture`, `recon run`,
`recon batch`).

    from server.cli_options import add_serve_arguments, serve_from_args
    add_serve_arguments(parser)                          # when building the argparse parser
    handle = serve_from_args(args, run_dir=out, session_dir=session)   # None without --serve
    handle = serve_from_args(args, batch_dir=runs)                      # `recon batch --serve`
    try: ... finally: handle and handle.stop()
"""
from __future__ import annotations

import argparse

from server.app import DEFAULT_HOST, DEFAULT_PORT, ServerHandle, serve


def add_serve_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("status page")
    g.add_argument("--serve", action="store_true",
                   help="serve the live status page (renders, progress, capture health) while working")
    g.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address the page binds to (default: {DEFAULT_HOST}, this machine only; "
                        f"0.0.0.0 = every interface)")
    g.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port of the page (default: {DEFAULT_PORT})")


def serve_from_args(args: argparse.Namespace, run_dir=None, session_dir=None, batch_dir=None,
                    renderer=None) -> ServerHandle | None:
    """Start the page if --serve was given and print its URL; exits with a clear message if the
    address cannot be bound. batch_dir: a `recon batch` folder (batch panel, one page per job).
    renderer: the viewer's renderer (recon.view; `recon run` passes the training model's).
    -> the handle (stop it when done) or None."""
    if not getattr(args, "serve", False):
        return None
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in 0..65535, got {args.port}")
    try:
        handle = serve(args.host, args.port, run_dir=run_dir, session_dir=session_dir, batch_dir=batch_dir,
                       renderer=renderer)
    except OSError as exc:
        raise ValueError(f"--serve: cannot listen on {args.host}:{args.port}: {exc.strerror or exc}") from None
    print(f"status page: {handle.url}", flush=True)
    return handle
