"""``dexmon`` command line: ``main(argv=None) -> int``.

Subcommands live in :mod:`monitor.commands`, one module each, imported on use.
Errors a user can fix (bad G-code, spec, file, port) print one line and exit 2;
they never show a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from drivers.errors import DriverError
from sim.errors import SimError

#: subcommand -> module under monitor.commands
COMMANDS: dict[str, str] = {
    "simulate": "simulate",
    "moves": "moves",
    "live": "live",
    "dry-run": "dry_run",
    "serve-virtual": "serve_virtual",
    "replay": "replay",
    "report": "report",
    "view": "view",
    "correct": "correct",
}

#: one-line help shown in ``dexmon --help`` (kept here so --help imports nothing heavy)
SUMMARY: dict[str, str] = {
    "simulate": "cut a whole program into a stock model and report removal and findings",
    "moves": "print a program's move table (jsonl or csv)",
    "live": "monitor a running machine from a job file",
    "dry-run": "run a job against the virtual controller",
    "serve-virtual": "expose the virtual controller as a GRBL device and/or Modbus server",
    "replay": "rebuild, picture or export any stage of a recorded run",
    "report": "write an HTML report of a recorded run",
    "view": "show a recorded run in the browser (3-D view, timeline, listing, findings)",
    "correct": "correct a gouging program against its design and write a safe one",
}

#: the errors that mean "bad input or environment", reported as one line
USER_ERRORS = (SimError, DriverError, OSError)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dexmon", description="Hardware-in-the-loop monitor for CNC mills.")
    parser.add_argument("--version", action="version", version=f"dexmon {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        p = sub.add_parser(name, help=SUMMARY[name], description=SUMMARY[name])
        if name == command:
            _load(module).add_arguments(p)
    return parser


def version() -> str:
    """The installed dexmon's version ("unknown" when run from a tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("dexmon")
    except PackageNotFoundError:
        return "unknown"


def _load(module: str):
    return importlib.import_module(f"monitor.commands.{module}")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    if command not in COMMANDS:
        command = None
    try:
        parser = build_parser(command)
    except ModuleNotFoundError as exc:
        print(f"dexmon: {command}: not available in this build ({exc})", file=sys.stderr)
        return 2
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse prints its own one-line usage error
        return 0 if exc.code in (0, None) else 2
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(_load(COMMANDS[args.command]).run(args))
    except USER_ERRORS as exc:
        print(f"dexmon {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM / SIGHUP where a command turns them into one
        from monitor.interrupt import exit_status

        print(f"dexmon {args.command}: interrupted", file=sys.stderr)
        return exit_status(exc)


if __name__ == "__main__":
    sys.exit(main())
