"""Every option of every command says what it does, and its default when it has one."""

from __future__ import annotations

import argparse

from pdcov import cli


def subparsers(parser: argparse.ArgumentParser, path: str = "pdcov"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{path} {name}", sub
                yield from subparsers(sub, f"{path} {name}")


def test_every_option_has_help_and_its_default() -> None:
    missing, no_default = [], []
    for name, parser in subparsers(cli.build_parser()):
        formatter = parser._get_formatter()
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            where = f"{name} {'/'.join(action.option_strings) or action.dest}"
            if not (action.help or "").strip():
                missing.append(where)
                continue
            shown = formatter._expand_help(action) if action.help else ""
            if action.default not in (None, False, argparse.SUPPRESS) and action.option_strings \
                    and "default" not in shown:
                no_default.append(f"{where} (default {action.default!r}): {shown!r}")
    assert not missing, "options without help:\n" + "\n".join(missing)
    assert not no_default, "defaults not shown:\n" + "\n".join(no_default)


def test_help_shows_defaults_in_words(capsys) -> None:
    parser = cli.build_parser("plan")
    plan = dict(subparsers(parser))["pdcov plan"]
    text = " ".join(plan.format_help().split())
    assert "(default: lawnmower)" in text and "(default: 5.0)" in text
    assert "None" not in text and "False" not in text
