"""A built-in command's start builds only its own parser: the contributed commands' modules and the sweep's are not
imported, and the command parses, helps and fails exactly as with every command's parser."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from evsda.graph import cli
from evsda.graph.commands import contributed_commands

IMPORTED = """
import json, sys
from evsda.graph import cli
cli._parser_for({argv!r})
print(json.dumps(sorted(m for m in sys.modules if m.startswith("evsda"))))
"""


def imported_after_parser(argv: list[str]) -> set[str]:
    out = subprocess.run([sys.executable, "-c", IMPORTED.format(argv=argv)], capture_output=True, text=True,
                         check=True)
    return set(json.loads(out.stdout.splitlines()[-1]))


def contributed_modules() -> set[str]:
    return {type(command).__module__ for command in contributed_commands()}


@pytest.mark.parametrize("argv", [["run", "g.yaml"], ["-q", "validate", "g.yaml"], ["-v", "--quiet", "info", "s"]])
def test_a_built_in_command_imports_no_contributed_command(argv):
    imported = imported_after_parser(argv)
    assert not imported & contributed_modules()
    assert "evsda.graph.sweep" not in imported


@pytest.mark.parametrize("argv", [["--help"], ["export", "--help"], ["--verb", "run"], []])
def test_anything_else_gets_every_command(argv):
    imported = imported_after_parser(argv)
    assert contributed_modules() <= imported
    assert "evsda.graph.sweep" in imported


def sub_parser(parser, name):
    (action,) = parser._subparsers._group_actions
    return action.choices[name]


@pytest.mark.parametrize("name", [name for name, *_ in cli.BUILT_IN_COMMANDS])
def test_a_built_in_commands_own_parser_is_the_same(name):
    full, own = cli.build_parser(contributed_commands()), cli._parser_for([name])
    assert sub_parser(own, name).format_help() == sub_parser(full, name).format_help()
    assert list(sub_parser(own, name)._option_string_actions) == list(sub_parser(full, name)._option_string_actions)


@pytest.mark.parametrize("argv", [["run", "g.yaml", "--set", "a.b=1", "-o", "x.zarr", "--no-pipeline", "-q"],
                                  ["-v", "sweep", "g.yaml", "--vary", "a.b=[1, 2]", "--sample", "lhs", "--points", "3"],
                                  ["validate", "g.yaml", "--limit", "windows=10"]])
def test_a_built_in_command_line_parses_the_same(argv):
    full, own = cli.build_parser(contributed_commands()), cli._parser_for(argv)
    assert vars(own.parse_args(argv)) == vars(full.parse_args(argv))


@pytest.mark.parametrize("argv", [["run"], ["run", "g.yaml", "--bogus"], ["sweep", "g.yaml", "--sample", "x"],
                                  ["runn", "g.yaml"]])
def test_a_mistake_is_told_the_same(argv, capsys):
    told = []
    for parser in (cli.build_parser(contributed_commands()), cli._parser_for(argv)):
        with pytest.raises(SystemExit) as stop:
            parser.parse_args(argv)
        told.append((stop.value.code, capsys.readouterr().err))
    assert told[0] == told[1] and told[0][0] == 2
