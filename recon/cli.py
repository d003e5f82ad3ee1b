"""`recon`: reconstruction commands (each lives beside the concept it drives; see rig.cli_format)."""
from __future__ import annotations

import sys

from rig.cli_format import command_parser, run_command

COMMANDS = [
    "recon.data.cli",
    "recon.prepare.cli",
    "recon.eval.cli",
    "recon.splat.cli",
    "recon.run",
    "recon.batch.cli",
    "recon.render",
    "recon.view",
    "recon.demo",
]


def build_parser():
    return command_parser("recon", "thermal4d reconstruction: datasets, Dynamic Thermal Gaussians training, "
                                   "rendering, evaluation.", COMMANDS)


def main(argv: list[str] | None = None) -> int:
    return run_command(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
