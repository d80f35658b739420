"""The ``pdcov`` console script: parses arguments and dispatches to ``pdcov.commands``.

Errors pdcov raises on purpose (``PdcovError``) print one clear line and exit with status 2;
nothing else is caught, so a real bug still shows its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__
from .errors import PdcovError

# One module per command group, in the order ``pdcov --help`` lists them.
COMMAND_MODULES = (
    "pdcov.commands.demo",
    "pdcov.commands.evaluate",
    "pdcov.commands.detector",
    "pdcov.commands.plan",
    "pdcov.commands.mount",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pdcov",
        description="Probability-of-detection coverage maps for search-and-rescue UAVs.")
    parser.add_argument("--version", action="version", version=f"pdcov {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except PdcovError as exc:
        print(f"pdcov {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"pdcov {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
