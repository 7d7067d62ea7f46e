"""Sphinx directives for the ``gonio`` command pages, generated from the code.

``.. gonio-command:: NAME`` renders a subcommand's one-line help (``HELP``), the body of its
module docstring (without its References, which the API reference carries) and its options,
read from the argparse parser that ``gonio.cli.build_parser`` builds (through
sphinx-argparse), so the page cannot drift from the command.

``.. gonio-json:: ARGS`` runs ``gonio ARGS --json PATH`` in a temporary folder while the docs
build and shows the JSON it wrote (long lists shortened), for commands cheap enough to run;
``:before:`` gives ``;``-separated commands run first in that folder (to make its input).

At the end of reading, every registered subcommand must have a ``gonio-command`` page, and
every such page must name a registered subcommand (a warning otherwise, an error under ``-W``).
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import io
import json
import os
import shlex
import tempfile
from typing import Any, ClassVar

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

logger = logging.getLogger(__name__)


def _commands() -> dict[str, Any]:
    """Registered subcommands: name -> module (``gonio.cli`` discovers them)."""
    from gonio import cli

    return {mod.COMMAND: mod for mod in cli._subcommand_modules()}


def _docstring_body(mod: Any) -> list[str]:
    """The module docstring after its first line, up to a numpydoc References section."""
    doc = inspect.getdoc(mod) or ""
    lines = doc.splitlines()[1:]
    out: list[str] = []
    for i, line in enumerate(lines):
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if line.strip() == "References" and set(nxt.strip()) == {"-"}:
            break
        out.append(line)
    return out


class GonioCommand(SphinxDirective):
    """A subcommand's help, description and options, from ``gonio.cli``."""

    required_arguments = 1
    has_content = False

    def run(self) -> list[nodes.Node]:
        name = self.arguments[0]
        cmds = _commands()
        if name not in cmds:
            raise self.error(f"gonio-command {name!r}: not a gonio subcommand {sorted(cmds)}")
        self.env.note_dependency(inspect.getsourcefile(cmds[name]))
        if not hasattr(self.env, "gonio_commands"):
            self.env.gonio_commands = {}
        self.env.gonio_commands[name] = self.env.docname
        mod = cmds[name]
        path = name
        sub = _subparser_choices(name)
        rst = [mod.HELP[0].upper() + mod.HELP[1:] + ".", "", *_docstring_body(mod), ""]
        rst += [f"Source: ``{mod.__name__.replace('.', '/')}.py``.", ""]
        for p in [path] if not sub else [f"{name} {s}" for s in sub]:
            rst += [
                ".. argparse::",
                "   :module: gonio.cli",
                "   :func: build_parser",
                "   :prog: gonio",
                f"   :path: {p}",
                "   :nodescription:",
                "",
            ]
        return self.parse_text_to_nodes("\n".join(rst))

    def parse_text_to_nodes(self, text: str) -> list[nodes.Node]:
        node = nodes.container()
        self.state.nested_parse(StringList(text.splitlines(), source=self.get_source_info()[0]),
                                self.content_offset, node, match_titles=True)  # fmt: skip
        return node.children


def _subparser_choices(name: str) -> list[str]:
    """Names of a subcommand's own subcommands (``gonio devices serve``), else ``[]``."""
    import argparse

    from gonio.cli import build_parser

    top = build_parser()
    for action in top._actions:
        if isinstance(action, argparse._SubParsersAction):
            parser = action.choices[name]
            for a in parser._actions:
                if isinstance(a, argparse._SubParsersAction):
                    return list(a.choices)
    return []


def _shorten(obj: Any, n: int, depth: int) -> Any:
    """``obj`` with lists and dicts longer than ``n`` cut to ``n`` items (and a count of the
    rest), and containers nested deeper than ``depth`` replaced by a count of their items."""
    if isinstance(obj, dict | list) and depth <= 0:
        return f"... {len(obj)} {'keys' if isinstance(obj, dict) else 'items'}"
    if isinstance(obj, dict):
        items = list(obj.items())
        out = {k: _shorten(v, n, depth - 1) for k, v in items[:n]}
        if len(items) > n:
            out["..."] = f"{len(items) - n} more keys: " + ", ".join(k for k, _ in items[n:])
        return out
    if isinstance(obj, list):
        head = [_shorten(v, n, depth - 1) for v in obj[:n]]
        return head + ([f"... {len(obj) - n} more"] if len(obj) > n else [])
    return obj


def _before(text: str) -> list[list[str]]:
    return [shlex.split(c) for c in text.split(";") if c.strip()]


class GonioJSON(SphinxDirective):
    """Run ``gonio ARGS --json PATH`` now and show the JSON written to PATH."""

    required_arguments = 1
    final_argument_whitespace = True
    option_spec: ClassVar[dict[str, Any]] = {
        "max-items": directives.positive_int,
        "depth": directives.positive_int,
        "keys": directives.unchanged,
        "before": directives.unchanged,
    }

    def run(self) -> list[nodes.Node]:
        from gonio.cli import main

        args = shlex.split(self.arguments[0])
        cwd = os.getcwd()
        with tempfile.TemporaryDirectory() as tmp:
            os.chdir(tmp)
            out = io.StringIO()
            try:
                with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
                    for pre in _before(self.options.get("before", "")):
                        if main(pre) != 0:
                            raise RuntimeError(f"gonio {shlex.join(pre)} failed")
                    code = main([*args, "--json", "out.json"])
                with open("out.json", encoding="utf-8") as f:
                    data = json.load(f)
            except Exception as exc:  # any failure becomes a build error naming the command
                msg = f"gonio {shlex.join(args)} failed: {exc!r}\n{out.getvalue()}"
                raise self.error(msg) from exc
            finally:
                os.chdir(cwd)
        if code != 0:
            raise self.error(f"gonio {' '.join(args)} exited {code}:\n{out.getvalue()}")
        keys = self.options.get("keys")
        if keys:
            data = {k: data[k] for k in keys.split(",") if k in data}
        text = json.dumps(
            _shorten(data, self.options.get("max-items", 30), self.options.get("depth", 6)),
            indent=2,
        )
        shown = [f"$ gonio {shlex.join(c)}" for c in _before(self.options.get("before", ""))]
        shown.append(f"$ gonio {shlex.join(args)} --json out.json")
        cmd = nodes.literal_block(text="\n".join(shown))
        cmd["language"] = "console"
        block = nodes.literal_block(text=text)
        block["language"] = "json"
        return [cmd, block]


def _check_pages(app: Any, env: Any) -> None:
    seen = getattr(env, "gonio_commands", {})
    for name in sorted(set(_commands()) - set(seen)):
        logger.warning("gonio subcommand %r has no page with a gonio-command directive", name)


def _purge(app: Any, env: Any, docname: str) -> None:
    pages = getattr(env, "gonio_commands", {})
    for name in [n for n, d in pages.items() if d == docname]:
        del pages[name]


def setup(app: Any) -> dict[str, Any]:
    importlib.import_module("sphinxarg.ext")
    app.add_directive("gonio-command", GonioCommand)
    app.add_directive("gonio-json", GonioJSON)
    app.connect("env-purge-doc", _purge)
    app.connect("env-check-consistency", _check_pages)
    return {"parallel_read_safe": False, "parallel_write_safe": True}
