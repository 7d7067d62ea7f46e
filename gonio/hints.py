"""Hints in messages that name an option, written once and read in either interface's syntax.

A library message that tells its reader what to pass writes the hint with :func:`keyword`,
in Python keyword syntax (``negative='clip' or 'drop'``, ``n_starts=``): what a Python user
types. The command line, whose options have other names (``--negative clip``,
``--starts``), renders the same message with :func:`as_options` and the map from keyword to
option of the command that printed it, so each interface speaks its own syntax.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

__all__ = ["as_options", "keyword"]

#: a hint as :func:`keyword` writes it: ``name=`` alone (before a space, a closing bracket,
#: a comma, a semicolon or the end) or followed by quoted values joined by `` or ``
_HINT = re.compile(r"\b([A-Za-z_]\w*)=((?:'[^']*'(?: or '[^']*')*)|(?=[\s),;]|$))")


def keyword(name: str, *values: str) -> str:
    """A hint to pass ``name`` (with one of ``values``), in Python keyword syntax.

    >>> keyword("negative", "clip", "drop")
    "negative='clip' or 'drop'"
    >>> keyword("n_starts")
    'n_starts='
    """
    return f"{name}=" + " or ".join(repr(str(v)) for v in values)


def as_options(text: str, options: Mapping[str, str]) -> str:
    """``text`` with each :func:`keyword` hint whose name is in ``options`` (keyword ->
    option, e.g. ``{"n_starts": "--starts"}``) written in option syntax.

    ``negative='clip' or 'drop'`` becomes ``--negative clip or drop``, ``n_starts=`` becomes
    ``--starts``; names not in ``options`` and other text are left as they are.

    >>> as_options("pass negative='clip' or 'drop'", {"negative": "--negative"})
    'pass --negative clip or drop'
    """

    def sub(m: re.Match) -> str:
        opt = options.get(m.group(1))
        if opt is None:
            return m.group(0)
        values = re.findall(r"'([^']*)'", m.group(2))
        return opt + (" " + " or ".join(values) if values else "")

    return _HINT.sub(sub, text)
