"""Reading back the JSON and TOML files gonio writes: parsed with a depth limit, shape-checked.

Every file gonio reads back (a calibration folder's ``calibration.json``, a raw group's
``done.json``, ``fit.json``, ``plan.json``, a sweep's spec, a lens calibration, an image's
side-car) goes through :func:`read_json` (or :func:`read_toml`) and the field accessors below,
so that a file of the wrong shape — valid JSON, but a list where an object belongs, a missing
key, a string where a number belongs, 900 levels of nesting — is a one-line
:class:`FileFormatError` (a ``ValueError``) naming the file and the field, never an
``AttributeError``, ``KeyError``, ``TypeError`` or ``RecursionError`` from deep inside.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MAX_DEPTH",
    "FileFormatError",
    "check_depth",
    "get",
    "get_mapping",
    "get_number",
    "get_str",
    "loads",
    "read_document",
    "read_json",
    "read_toml",
    "require_mapping",
    "to_json",
    "write_json",
]

#: Deepest nesting of arrays and objects accepted in a file gonio reads back (its own files
#: nest at most a few levels; Python's parser recurses and fails near 1000).
MAX_DEPTH = 32

#: Largest file read back (bytes): gonio's own side-cars, plans and calibrations are kB.
MAX_BYTES = 64 * 1024 * 1024


class FileFormatError(ValueError):
    """A file gonio reads back is not of the shape it expects (names the file and the field)."""


_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')


def check_depth(text: str, source: str, max_depth: int = MAX_DEPTH) -> None:
    """Refuse JSON ``text`` whose arrays/objects nest deeper than ``max_depth``, before
    parsing it (strings skipped, so brackets inside them do not count)."""
    depth = 0
    for m in _TOKENS.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > max_depth:
                raise FileFormatError(f"{source}: nested deeper than {max_depth} levels")
        elif c in "]}":
            depth -= 1


def _plain_float(text: str) -> float:
    raise FileFormatError(f"non-standard number {text!r}")


def loads(text: str, source: str, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads`` with the depth limit; NaN/Infinity refused; errors name ``source``."""
    check_depth(text, source, max_depth)
    try:
        return json.loads(text, parse_constant=_plain_float)
    except FileFormatError as exc:
        raise FileFormatError(f"{source}: {exc}") from None
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise FileFormatError(f"{source}: not valid JSON ({exc})") from None


def _read_text(path: str | os.PathLike, kind: str = "JSON") -> str:
    p = Path(path)
    size = p.stat().st_size
    if size > MAX_BYTES:
        raise FileFormatError(f"{str(p)!r}: {size} bytes, larger than {MAX_BYTES} expected")
    try:
        return p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{str(p)!r}: not valid {kind} (not UTF-8: {exc.reason})") from None


def read_json(path: str | os.PathLike, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON document in ``path`` (``OSError`` if unreadable, :class:`FileFormatError` if
    not JSON or nested deeper than ``max_depth``)."""
    return loads(_read_text(path), repr(str(path)), max_depth)


def read_toml(path: str | os.PathLike, max_depth: int = MAX_DEPTH) -> dict[str, Any]:
    """The TOML document in ``path`` (depth-limited as :func:`read_json`)."""
    import tomllib

    text = _read_text(path, "TOML")
    source = repr(str(path))
    try:
        doc = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise FileFormatError(f"{source}: not valid TOML ({exc})") from None
    stack: list[tuple[Any, int]] = [(doc, 1)]
    while stack:  # the depth of what was parsed (TOML's tables and arrays)
        obj, depth = stack.pop()
        if depth > max_depth:
            raise FileFormatError(f"{source}: nested deeper than {max_depth} levels")
        items = obj.values() if isinstance(obj, dict) else obj if isinstance(obj, list) else ()
        stack.extend((v, depth + 1) for v in items if isinstance(v, dict | list))
    return doc


def read_document(
    path: str | os.PathLike, build: Callable[[Mapping[str, Any]], Any] | None = None,
    *, what: str = "", max_depth: int = MAX_DEPTH,
) -> Any:  # fmt: skip
    """A JSON (``.json``) or TOML (``.toml``) object read back from ``path`` and built into
    a value by ``build`` (the document itself without one): the one entry of every reader.

    Whatever ``build`` raises on a document of the wrong shape (a ``ValueError`` of its own
    checks, or a ``TypeError``/``KeyError``/``AttributeError``/``IndexError`` from a field of
    another type than it expects) becomes a one-line :class:`FileFormatError` naming the file
    (and ``what`` it should hold); ``OSError`` (unreadable file) passes through.
    """
    src = f"{what} {str(path)!r}" if what else repr(str(path))
    reader = read_toml if str(path).lower().endswith(".toml") else read_json
    try:
        doc = reader(path, max_depth)
    except FileFormatError as exc:
        raise FileFormatError(f"{what} {exc}" if what else str(exc)) from None
    require_mapping(doc, src)
    if build is None:
        return doc
    try:
        return build(doc)
    except ValueError as exc:  # (its own FileFormatError too)
        text = str(exc) if str(path) in str(exc) else f"{src}: {exc}"
        raise FileFormatError(_one_line(text)) from None
    except (TypeError, KeyError, AttributeError, IndexError, OverflowError, RecursionError) as exc:
        raise FileFormatError(
            _one_line(f"{src}: a field of the wrong shape ({type(exc).__name__}: {exc})")
        ) from None


def _one_line(text: str, limit: int = 400) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ----------------------------------------------------------------------------- shape checks
def _kind(v: Any) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if v is None:
        return "null"
    return {dict: "an object", list: "a list", str: "a string", int: "an integer",
            float: "a number"}.get(type(v), type(v).__name__)  # fmt: skip


def require_mapping(doc: Any, source: str, field: str = "") -> Mapping[str, Any]:
    """``doc`` if it is a JSON object, else :class:`FileFormatError` naming ``source``."""
    if not isinstance(doc, Mapping):
        where = f"field {field!r}" if field else "the document"
        raise FileFormatError(f"{source}: {where} is {_kind(doc)}, expected an object")
    return doc


_MISSING = object()


def get(
    doc: Mapping[str, Any], key: str, source: str, types: type | tuple[type, ...],
    *, default: Any = _MISSING, what: str = "", check: Callable[[Any], bool] | None = None,
) -> Any:  # fmt: skip
    """``doc[key]``, of one of ``types`` (a boolean is never a number) and passing ``check``.

    A missing key gives ``default`` if one is given, else :class:`FileFormatError`; so does
    a value of another type or one that fails ``check`` (``what`` describes the expected
    value in the message).
    """
    if key not in doc:
        if default is not _MISSING:
            return default
        raise FileFormatError(f"{source}: field {key!r} is missing")
    v = doc[key]
    tt = types if isinstance(types, tuple) else (types,)
    ok = isinstance(v, tt) and not (isinstance(v, bool) and bool not in tt)
    if ok and check is not None:
        try:
            ok = bool(check(v))
        except (TypeError, ValueError, OverflowError):
            ok = False
    if not ok:
        expected = what or " or ".join(_kind(t()) if t is not type(None) else "null" for t in tt)
        raise FileFormatError(f"{source}: field {key!r} is {v!r:.60}, expected {expected}")
    return v


def get_number(
    doc: Mapping[str, Any], key: str, source: str, *, lo: float = -math.inf,
    hi: float = math.inf, default: Any = _MISSING, integer: bool = False,
) -> Any:  # fmt: skip
    """A finite number (an integer if ``integer``) in ``[lo, hi]`` (never a boolean)."""
    types: tuple[type, ...] = (int,) if integer else (int, float)
    what = f"{'an integer' if integer else 'a number'} in [{lo:g}, {hi:g}]"
    return get(doc, key, source, types, default=default, what=what,
               check=lambda v: math.isfinite(v) and lo <= v <= hi)  # fmt: skip


def get_str(
    doc: Mapping[str, Any], key: str, source: str, *, choices: Any = None,
    default: Any = _MISSING,
) -> Any:  # fmt: skip
    """A string (one of ``choices`` if given)."""
    what = "a string" if choices is None else f"one of {sorted(choices)}"
    return get(doc, key, source, str, default=default, what=what,
               check=None if choices is None else (lambda v: v in choices))  # fmt: skip


def get_mapping(doc: Mapping[str, Any], key: str, source: str, *, default: Any = _MISSING) -> Any:
    """An object (a ``dict``)."""
    return get(doc, key, source, dict, default=default, what="an object")


def _default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"value of type {type(o).__name__} is not JSON serialisable")


def to_json(obj: Any) -> str:
    """``json.dumps`` that understands numpy scalars and arrays and paths."""
    return json.dumps(obj, indent=2, default=_default, allow_nan=False)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (temporary file + rename)."""
    from gonio.io.atomic import atomic_write_bytes

    return atomic_write_bytes(path, (to_json(obj) + "\n").encode())
