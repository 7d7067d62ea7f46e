"""The ``gonio`` command line.

Each subcommand is a module in this package defining ``COMMAND`` (its name), ``HELP`` (one
line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules import their heavy
dependencies inside ``run`` so that ``gonio --help`` and small commands start fast.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import sys
from collections.abc import Iterator, Sequence

from gonio import __version__
from gonio.cli._common import HelpFormatter


def _subcommand_modules():
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "COMMAND") and hasattr(mod, "run"):
            yield mod


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="gonio", description="gonio: a virtual gonioreflectometer"
    )
    parser.add_argument("--version", action="version", version=f"gonio {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _subcommand_modules():
        p = sub.add_parser(
            mod.COMMAND,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            formatter_class=HelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _parser=p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gonio`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with _terminate_as_interrupt():
            return int(args._run(args) or 0)
    except ValueError as exc:
        from gonio.cli._common import cli_text

        print(f"gonio {args.command}: error: {cli_text(str(exc), args)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file, a folder, a port, a host: one line naming it
        print(f"gonio {args.command}: error: {os_error_text(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"gonio {args.command}: interrupted", file=sys.stderr)
        return 130


_AT_FORK = False


def _interrupt(signum: int, frame: object) -> None:
    import signal

    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def _default_sigterm_in_child() -> None:
    """A process forked while a command runs (a sweep's workers) dies of SIGTERM as before:
    the interrupt is the command's, not its children's."""
    import signal

    if signal.getsignal(signal.SIGTERM) is _interrupt:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM raises ``KeyboardInterrupt`` while a command runs, as Ctrl-C does: every
    command's ``with``/``finally`` blocks then remove its temporaries and ``subprocess.run``
    kills its running child (``export bsdf``'s ``pabopto2bsdf``), as the campaign does."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    global _AT_FORK
    if not _AT_FORK:
        os.register_at_fork(after_in_child=_default_sigterm_in_child)
        _AT_FORK = True
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def os_error_text(exc: OSError) -> str:
    """One line for an ``OSError``: the path(s) it names and the system's reason.

    ``IsADirectoryError: [Errno 21] Is a directory: '/x/.j.tmp' -> '/x/j'`` becomes
    ``'/x/j': Is a directory``; an error without a path (a port in use, a host that does not
    answer) keeps its own text.
    """
    reason = exc.strerror or str(exc) or type(exc).__name__
    path = exc.filename2 if exc.filename2 is not None else exc.filename
    if path is None:
        return exc.strerror or str(exc) or type(exc).__name__
    return f"{str(path)!r}: {reason}"


def console_main() -> None:
    """The ``gonio`` console script: :func:`main`, then a quick exit with its status.

    Once the command has returned, the exit handlers have run and the output is flushed,
    the process ends with ``os._exit``: the interpreter's own teardown does nothing a
    finished command needs and, after numba has loaded compiled kernels, takes ~0.2 s
    (measured here: 0.66 s vs 0.44 s for a process that loads one kernel and exits).
    Its malloc keeps freed image-sized blocks, as a campaign's children do
    (:func:`gonio.malloc.keep_freed`).
    """
    import atexit
    import os

    from gonio.malloc import keep_freed

    keep_freed()  # this process is the command's alone (see keep_freed)
    code = main()
    atexit._run_exitfuncs()  # what a normal exit runs first (logging, multiprocessing, ...)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BrokenPipeError:  # a reader that went away (``gonio ... | head``)
        code = code or 1
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    console_main()
