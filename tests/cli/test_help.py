"""Every option of every subcommand has help with its default shown, and the README's command
table lists the parsers' options, no more and no fewer (issue 32)."""

import argparse
import re
from pathlib import Path

import pytest

from gonio.cli import build_parser

README = Path(__file__).resolve().parents[2] / "README.md"
#: options the README's table names once for every command (its heading says so)
COMMON = {"--json", "--help"}


def _commands() -> dict[str, argparse.ArgumentParser]:
    """``{"campaign": parser, "devices serve": parser, ...}``: every runnable (sub)command."""
    out = {}

    def walk(name: str, parser: argparse.ArgumentParser) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs and name:
            out[name] = parser
        for a in subs:
            for n, sp in a.choices.items():
                walk(f"{name} {n}".strip(), sp)

    walk("", build_parser())
    return out


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [
        a for a in parser._actions if a.option_strings and not isinstance(a, argparse._HelpAction)
    ]


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_option_has_help_and_shows_its_default(name):
    parser = _commands()[name]
    fmt = parser._get_formatter()
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        assert a.help, f"gonio {name} {a.option_strings or a.dest}: no help"
        text = fmt._expand_help(a) if hasattr(fmt, "_expand_help") else a.help
        valued = a.default not in (None, False, [], argparse.SUPPRESS) and not (
            a.nargs == 0 and a.const is not None
        )
        if valued and a.option_strings:
            assert "default" in text, f"gonio {name} {a.option_strings}: default not shown"
    assert parser.description, f"gonio {name}: no description"


def _readme_rows() -> dict[str, set[str]]:
    """The options each command of the README's command table names (first column)."""
    rows: dict[str, set[str]] = {}
    for line in README.read_text().splitlines():
        if not line.startswith("| `gonio "):
            continue
        first = line.split(" | ")[0]
        for usage in re.findall(r"`(gonio [^`]+)`", first):
            words = usage.split()
            name = words[1]
            if len(words) > 2 and f"{name} {words[2]}" in _commands():
                name = f"{name} {words[2]}"
            rows.setdefault(name, set()).update(re.findall(r"(?<![\w-])--?[a-z][a-z0-9-]*", usage))
    return rows


def test_readme_command_table_lists_exactly_the_parsers_options():
    rows = _readme_rows()
    commands = _commands()
    assert set(rows) == set(commands), "README command table: commands differ from the parser"
    for name, documented in rows.items():
        actions = _options(commands[name])
        known = {s for a in actions for s in a.option_strings}
        unknown = documented - known
        assert not unknown, f"README names options gonio {name} does not have: {sorted(unknown)}"
        missing = [
            a.option_strings[-1]
            for a in actions
            if not (set(a.option_strings) & (documented | COMMON))
        ]
        assert not missing, f"README omits options of gonio {name}: {missing}"


def test_materials_table_fits_100_columns_and_says_when_none_match(capsys):
    from gonio.cli import main

    assert main(["materials"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) > 40 and max(map(len, out)) <= 100
    assert any(line.startswith("rolled_brass ") for line in out)
    assert main(["materials", "--model", "cook_torrance"]) == 0
    out = capsys.readouterr().out
    assert "no material preset of model 'cook_torrance'" in out and "ward" in out
