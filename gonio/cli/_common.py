"""Helpers shared by the subcommands: output-path checks, option types and help.

JSON output (:func:`gonio.io.jsonfile.to_json`), the console's tables
(:func:`gonio.console.format_table`), the worker bound
and the model-sum bound (:func:`gonio._validate.max_workers`,
:func:`gonio._validate.check_model_terms`) live with the code they serve and are
imported here for the subcommands."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

# re-exported for the subcommands (the explicit ``as`` form)
from gonio._validate import MAX_MODEL_TERMS as MAX_MODEL_TERMS
from gonio._validate import WORKERS_PER_CPU as WORKERS_PER_CPU
from gonio._validate import check_model_terms as check_model_terms
from gonio._validate import max_workers as max_workers
from gonio.console import format_table as format_table
from gonio.io.jsonfile import to_json as to_json
from gonio.io.jsonfile import write_json as write_json


class HelpFormatter(argparse.HelpFormatter):
    """Help that shows every option's default: ``(default: X)`` appended where the help text
    does not already say its default and the default is a value (not ``None``, ``False`` or
    an empty list)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        d = action.default
        if (
            "default" in text
            or d is argparse.SUPPRESS
            or d is None
            or d is False
            or (action.const is not None and action.nargs == 0)
            or (isinstance(d, list) and not d)
            or not (action.option_strings or action.nargs in ("?", "*"))
        ):
            return text
        shown = " ".join(map(str, d)) if isinstance(d, tuple | list) else "%(default)s"
        return f"{text} (default: {shown})" if text else f"default: {shown}"


def name_value_pairs(items: Sequence[str], option: str, need_value: bool = True) -> dict:
    """``NAME=VALUE`` options (repeatable) as ``{name: float}`` (``None`` for a bare ``NAME``
    when ``need_value`` is false); a name given twice is refused, never "last wins"."""
    out: dict = {}
    for it in items:
        name, sep, val = it.partition("=")
        name = name.strip()
        if not name or (need_value and not sep):
            raise ValueError(f"{option} {it!r}: expected NAME=VALUE")
        if name in out:
            raise ValueError(f"{option} {name} is given twice ({it!r}); give each name once")
        if sep:
            try:
                out[name] = float(val)
            except ValueError:
                raise ValueError(f"{option} {it!r}: value {val!r} is not a number") from None
        else:
            out[name] = None
    return out


def _absolute(p: Path) -> Path:
    """``p`` made absolute; ``ValueError`` if it is relative and the working directory is
    gone (deleted under the shell that runs gonio)."""
    try:
        return p.absolute()
    except FileNotFoundError:
        raise argparse.ArgumentTypeError(
            f"{str(p)!r} is relative but the working directory no longer exists; give an "
            "absolute path or change to an existing folder"
        ) from None


def _existing_ancestor(p: Path) -> Path:
    """The nearest existing ancestor of ``p`` (``p`` itself if it exists)."""
    q = _absolute(p)
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def _writable_parent(p: Path, text: str) -> None:
    anc = _existing_ancestor(p.parent)
    if not anc.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: {str(anc)!r} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{text!r}: folder {str(anc)!r} is not writable")


def output_file(text: str) -> str:
    """``argparse`` type of an output file option: checked before any work starts.

    The path must not be a folder, and its nearest existing ancestor must be a writable
    folder (missing folders are created when the file is written). Returns ``text``.
    """
    p = Path(text)
    _absolute(p)
    if not text or text.endswith(("/", os.sep)) or p.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, expected a file path")
    _writable_parent(p, text)
    return text


def output_dir(text: str) -> str:
    """``argparse`` type of an output folder option (see :func:`output_file`). Returns ``text``."""
    p = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("empty path, expected a folder")
    _absolute(p)
    if p.exists() and not p.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a folder")
    _writable_parent(p, text)
    return text


def port_number(text: str) -> int:
    """``argparse`` type of a TCP port option: an integer in [0, 65535] (0 = any free port)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer port number") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"{v} is outside the port range [0, 65535]")
    return v


def int_in(lower: int, upper: int, why: str = ""):
    """``argparse`` type: an integer in ``[lower, upper]``; ``why`` explains the bound."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lower <= v <= upper:
            raise argparse.ArgumentTypeError(
                f"{v} is outside [{lower}, {upper}]" + (f" ({why})" if why else "")
            )
        return v

    return parse


def worker_count(text: str) -> int:
    """``argparse`` type of a worker/process count: an integer in [1, :func:`max_workers`]."""
    return int_in(1, max_workers(), f"at most {WORKERS_PER_CPU} per CPU")(text)


def check_output_dir(text: str, option: str) -> str:
    """:func:`output_dir` for a path computed after parsing; ``ValueError`` naming ``option``."""
    try:
        return output_dir(text)
    except argparse.ArgumentTypeError as exc:
        raise ValueError(f"{option}: {exc}") from None


def _same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name one file: ``os.path.samefile`` when both exist (hard and
    symbolic links), else their resolved paths."""
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
        return Path(a).resolve() == Path(b).resolve()
    except (OSError, RuntimeError):  # unreadable, or a symlink loop: compare as written
        return os.path.abspath(a) == os.path.abspath(b)


def _named(paths: Any) -> list[tuple[str, str]]:
    out = []
    for label, value in paths.items():
        vals = value if isinstance(value, list | tuple) else [value]
        out += [(label, str(v)) for v in vals if v is not None and str(v) != ""]
    return out


def check_outputs(inputs: dict[str, Any], outputs: dict[str, Any]) -> None:
    """The output-path rule of every command, checked before its work: an output is none of
    the command's inputs and no two outputs are the same file (``ValueError`` naming both).

    ``inputs`` and ``outputs`` map an option's name (``"--json"``, ``"samples"``) to a
    path, a list of paths or ``None`` (not given).
    """
    ins, outs = _named(inputs), _named(outputs)
    for k, (olabel, opath) in enumerate(outs):
        for ilabel, ipath in ins:
            if _same_path(opath, ipath):
                raise ValueError(
                    f"{olabel} {opath!r} is the input {ilabel} {ipath!r}: writing it would "
                    "replace that input; choose another path"
                )
        for olabel2, opath2 in outs[k + 1 :]:
            if _same_path(opath, opath2):
                raise ValueError(
                    f"{olabel} {opath!r} and {olabel2} {opath2!r} are the same file; "
                    "choose different paths"
                )


#: every instrument preset the command line accepts (LBL and Cornell builds)
PRESET_CHOICES = ("modern", "ward1992", "cornell2005", "ideal")


def add_preset_option(parser, help: str) -> None:
    """``--preset`` (alias ``--instrument-preset``, its older name) with ``help``: the
    instrument's build, one of :data:`PRESET_CHOICES`, default None (the instrument's own)."""
    parser.add_argument("--preset", "--instrument-preset", dest="preset", default=None,
                        choices=list(PRESET_CHOICES), help=help)  # fmt: skip


def add_json_option(parser) -> None:
    """The ``--json PATH`` option every result-producing subcommand has."""
    parser.add_argument(
        "--json", metavar="PATH", type=output_file, help="also write the results as JSON to PATH"
    )


#: library keywords whose option has another name (keyword -> the option's ``dest``)
KEYWORD_DESTS = {"n_starts": "starts"}


def option_map(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Python keyword -> the option of ``parser`` that sets it (``{"negative": "--negative",
    "n_starts": "--starts"}``): each option's first long name, by its ``dest``, and the
    keywords of :data:`KEYWORD_DESTS` whose ``dest`` the parser has."""
    by_dest: dict[str, str] = {}
    for action in parser._actions:
        longs = [s for s in action.option_strings if s.startswith("--")]
        if longs and action.dest not in by_dest:
            by_dest[action.dest] = longs[0]
    out = dict(by_dest)
    out.update({k: by_dest[d] for k, d in KEYWORD_DESTS.items() if d in by_dest})
    return out


def cli_text(text: str, args: argparse.Namespace) -> str:
    """A library message in the syntax of the command that prints it: its keyword hints
    (:func:`gonio.hints.keyword`) written as the command's options (``n_starts=`` ->
    ``--starts``); ``text`` unchanged without a subcommand's parser in ``args``."""
    from gonio.hints import as_options

    parser = getattr(args, "_parser", None)
    return as_options(text, option_map(parser)) if parser is not None else text
