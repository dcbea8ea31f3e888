"""Reading a command's argparse parser and ``--help`` text, for the tests that compare generated
flags with their configs (test_cli_configs, test_estimate_cli)."""

from __future__ import annotations

import argparse
import re

from ebr_mitsuba.cli import build_parser


def subparser(name: str) -> argparse.ArgumentParser:
    """The parser of ``ebr NAME`` (``"dataset sheet"``: the parser of a subcommand's action)."""
    parser = build_parser()
    for word in name.split():
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[word]
    return parser


def help_entries(parser: argparse.ArgumentParser) -> dict[str, str]:
    """``--help`` as {flag: its help text, whitespace folded} (``-h`` listed as ``--help``)."""
    entries, flag = {}, None
    for line in parser.format_help().splitlines():
        if line.startswith("  -"):
            invocation, *text = re.split(r"\s{2,}", line.strip(), maxsplit=1)
            flag = invocation.split()[0].rstrip(",")
            if flag == "-h":
                flag = "--help"
            entries[flag] = text[0] if text else ""
        elif flag and line.startswith(" " * 10):
            entries[flag] += " " + line.strip()
        else:
            flag = None
    return {k: " ".join(v.split()) for k, v in entries.items()}
