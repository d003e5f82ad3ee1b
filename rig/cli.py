"""`rig`: capture commands (each lives beside the concept it drives; see rig.cli_format)."""
from __future__ import annotations

import sys

from rig.cli_format import command_parser, run_command

COMMANDS = [
    "rig.capture.cli",
    "rig.devices",
    "rig.info",
    "rig.calibrate",
    "rig.importing",
]


def build_parser():
    return command_parser("rig", "thermal4d rig: devices, capture, sessions, calibration.", COMMANDS)


def main(argv: list[str] | None = None) -> int:
    return run_command(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
