"""argparse plumbing shared by the `rig` and `recon` commands: help that shows defaults and keeps
the epilog's examples on their own lines, the subcommand dispatch (each module listed in a CLI's
COMMANDS exposes `register(subparsers)`, which adds its parser and sets `func(args) -> int`), and
how a failure reaches the user: one line, no traceback unless `--debug`."""
import argparse
import importlib
import sys
import traceback

# Errors about what the user gave us: a missing or unreadable file (OSError), a malformed one
# (ValueError: JSON, dataset, PLY, calibration, GenICam values ... every project validation error
# is one), or a refusal by the project's own code (RuntimeError subclasses such as PrepareError,
# SfmError, FollowError, CheckpointError). Their messages name the file and what to do.
INPUT_ERRORS = (OSError, ValueError, RuntimeError)


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (`--iterations 0` trains nothing: refuse it)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def unit_fraction(text: str) -> float:
    """argparse type: a number in (0, 1]."""
    value = positive_float(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be at most 1, got {text}")
    return value


def command_parser(prog: str, description: str, modules: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--debug", action="store_true",
                        help="show Python tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in modules:
        importlib.import_module(name).register(sub)
    return parser


def run_command(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse and run a subcommand. Bad input ends in one line naming the problem and exit code 2
    (argparse's own convention); an unexpected failure in one line and exit 1 with the hint to
    rerun with --debug; --debug lets every exception through with its traceback."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv        # accepted anywhere on the line, not only before the command
    args = parser.parse_args([a for a in argv if a != "--debug"])
    args.debug = debug
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if args.debug:
        return int(args.func(args) or 0)
    where = f"{parser.prog} {args.command}"
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{where}: interrupted", file=sys.stderr)
        return 130
    except INPUT_ERRORS as exc:
        text = one_line(exc)
        print(text if text.startswith(f"{where}:") else f"{where}: {text}", file=sys.stderr)
        return 2
    except Exception as exc:   # a bug, not the input: still no wall of text, but say how to see it
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        print(f"{where}: internal error: {type(exc).__name__}: {one_line(exc)} (at {frame.filename}:"
              f"{frame.lineno}; rerun with --debug for the traceback, and please report it)", file=sys.stderr)
        return 1


def one_line(exc: BaseException) -> str:
    """The exception's message on one line; an OSError with its file name when it has one."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())
