"""argparse plumbing shared by the `rig` and `recon` commands: help that shows defaults and keeps
the epilog's examples on their own lines, and the subcommand dispatch (each module listed in a
CLI's COMMANDS exposes `register(subparsers)`, which adds its parser and sets `func(args) -> int`)."""
import argparse
import importlib


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass


def command_parser(prog: str, description: str, modules: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in modules:
        importlib.import_module(name).register(sub)
    return parser


def run_command(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)
