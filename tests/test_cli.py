"""The ``ebr`` entry point: every listed subcommand exists and builds, unknown input exits 2."""

from __future__ import annotations

import importlib

import pytest

from ebr_mitsuba import cli


@pytest.mark.parametrize("name", cli.COMMANDS)
def test_every_listed_command_has_a_module(name):
    module = importlib.import_module(f"ebr_mitsuba.commands.{name.replace('-', '_')}")
    assert module.NAME == name
    assert module.HELP and module.__doc__
    assert callable(module.add_arguments) and callable(module.run)


def test_help_lists_every_command(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert name in out


def test_no_command_and_unknown_command(capsys):
    assert cli.main([]) == 2
    assert cli.main(["no-such-command"]) == 2
    assert "invalid choice" in capsys.readouterr().err
