"""The ``pdcov`` console script: parses arguments and dispatches to ``pdcov.commands``.

Errors pdcov raises on purpose (``PdcovError``) print one clear line and exit with status 2;
nothing else is caught, so a real bug still shows its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from pdcov import __version__
from pdcov.errors import PdcovError

# Each sub-command and the module that registers it, in the order ``pdcov --help`` lists
# them. Only the module of the command given is imported: start-up stays short.
COMMANDS = {
    "demo": "pdcov.commands.demo",
    "evaluate": "pdcov.commands.evaluate",
    "compare": "pdcov.commands.evaluate",
    "footprint": "pdcov.commands.evaluate",
    "detector": "pdcov.commands.detector",
    "plan": "pdcov.commands.plan",
    "optimise": "pdcov.commands.optimise",
    "refly": "pdcov.commands.refly",
    "report": "pdcov.commands.report",
    "upload": "pdcov.commands.upload",
    "mount-check": "pdcov.commands.mount",
    "serve": "pdcov.commands.serve",
    "watch": "pdcov.commands.watch",
    "keys": "pdcov.commands.keys",
}


class _DefaultsFormatter(argparse.HelpFormatter):
    """Appends "(default: X)" to an option's help when it has a default and the help does
    not already give it; None and False (flags) are no defaults worth showing."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (action.option_strings and action.default not in (None, False, argparse.SUPPRESS)
                and "default" not in text and "%(default)" not in text):
            default = action.default
            shown = (" ".join(str(v) for v in default) if isinstance(default, (list, tuple))
                     else str(default))
            text += f" (default: {shown.replace('%', '%%')})"
        return text


class _StoreOnce(argparse._StoreAction):
    """An option's value, given at most once: argparse keeps the last of two silently
    (``pdcov evaluate --log A --log B`` evaluated B alone and exited 0); a second is a usage
    error naming both. Options meant to repeat say so (``action="append"``, ``nargs``)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        before = getattr(namespace, self.dest, self.default)
        if before is not self.default:
            raise argparse.ArgumentError(self, f"given twice ({before} and {values}): it "
                                               "takes one value")
        setattr(namespace, self.dest, values)


class _Parser(argparse.ArgumentParser):
    """Every command's parser: help shows the defaults (_DefaultsFormatter); an option given
    twice is refused (_StoreOnce)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", _DefaultsFormatter)
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with ``command``'s module registered, or every module when it is None or
    not a known command (for ``--help`` and the usage error)."""
    parser = argparse.ArgumentParser(
        prog="pdcov",
        description="Probability-of-detection coverage maps for search-and-rescue UAVs.")
    parser.add_argument("--version", action="version", version=f"pdcov {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    modules = ([COMMANDS[command]] if command in COMMANDS
               else list(dict.fromkeys(COMMANDS.values())))
    for name in modules:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv else None)
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
