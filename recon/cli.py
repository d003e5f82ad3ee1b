"""`recon`: reconstruction commands.

Each subcommand lives beside the concept it drives; a module listed in
COMMANDS exposes `register(subparsers)` which adds its parser and sets
`func(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS = [
    "recon.data.cli",
    "recon.prepare.cli",
    "recon.eval.cli",
    "recon.splat.cli",
    "recon.run",
    "recon.render",
    "recon.demo",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="recon",
        description="thermal4d reconstruction: datasets, Dynamic Thermal Gaussians training, rendering, evaluation.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
