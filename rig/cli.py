"""`rig`: capture commands.

Each subcommand lives beside the concept it drives; a module listed in
COMMANDS exposes `register(subparsers)` which adds its parser and sets
`func(args) -> int`.
"""
from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS = [
    "rig.capture",
    "rig.devices",
    "rig.info",
    "rig.calibrate",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rig",
        description="thermal4d rig: devices, capture, sessions, calibration.",
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
