"""The console script's dispatch table names every sub-command the modules register."""

import argparse

from pdcov import cli


def test_commands_table_matches_registered_subcommands():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == list(cli.COMMANDS)
    for name, module in cli.COMMANDS.items():
        only = cli.build_parser(name)
        sub = next(a for a in only._actions if isinstance(a, argparse._SubParsersAction))
        assert name in sub.choices, (name, module)


def test_no_command_prints_help_and_fails(capsys):
    assert cli.main([]) == 2
    assert "COMMAND" in capsys.readouterr().out
