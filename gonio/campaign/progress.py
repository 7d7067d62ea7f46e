"""The campaign's terminal progress bars: a thin layer over ``tqdm``.

A bar appears only on a terminal, only once a task has run longer than ``min_time`` (1 s
by default), and never with ``quiet=True``; it clears its line when it closes, so short runs
and logs stay clean. ``tqdm`` draws it (``delay``, ``leave=False``) and is imported only
when a bar can appear: its import (~70 ms measured here) is 4 % of a default campaign, which
on a pipe or with ``--quiet`` draws nothing.

>>> with Progress(3, "capture", quiet=True) as bar:
...     for _ in range(3):
...         bar.update()
>>> bar.count
3
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

__all__ = ["Progress"]


class Progress:
    """Progress of ``total`` steps, drawn as ``label [#####.....] 12/21 3.4 s``.

    Parameters
    ----------
    total : int
        Number of steps (>= 0).
    label : str
        Text in front of the bar (may be changed per :meth:`update`).
    stream : text stream, optional
        Where to draw (default ``sys.stderr``).
    quiet : bool
        Never draw.
    min_time : float
        Seconds of work before the bar first appears.
    force : bool
        Draw even when ``stream`` is not a terminal (tests).
    width : int
        Characters of the bar itself.
    note : str, optional
        Text after the time (e.g. an estimate of the time left; see :meth:`update`).
    """

    def __init__(
        self,
        total: int,
        label: str = "",
        *,
        stream: TextIO | None = None,
        quiet: bool = False,
        min_time: float = 1.0,
        force: bool = False,
        width: int = 30,
        note: str | None = None,
    ) -> None:
        if int(total) < 0:
            raise ValueError(f"total must be >= 0, got {total!r}")
        self.total = int(total)
        self.label = label
        self.count = 0
        self.start = time.perf_counter()
        stream = stream if stream is not None else sys.stderr
        self._stream = stream
        tty = bool(getattr(stream, "isatty", lambda: False)())
        self._bar: Any = None
        if not quiet and (tty or force):
            from tqdm import tqdm

            self._bar = tqdm(
                total=self.total, desc=label, file=stream, delay=float(min_time), leave=False,
                ascii=".#", mininterval=0.1, dynamic_ncols=False, postfix=note,
                bar_format="{desc} [{bar:WIDTH}] {n_fmt}/{total_fmt} {elapsed_s:.1f} s{postfix}"
                .replace("WIDTH", str(int(width))),
            )  # fmt: skip

    @property
    def enabled(self) -> bool:
        """Whether the bar can appear."""
        return self._bar is not None

    def update(self, n: int = 1, label: str | None = None, note: str | None = None) -> None:
        """Advance by ``n`` steps (and optionally change the label, or the ``note`` after
        the time, e.g. an estimate of the time left)."""
        self.count += int(n)
        if label is not None:
            self.label = label
        if self._bar is not None:
            if label is not None:
                self._bar.set_description_str(label, refresh=False)
            if note is not None:
                self._bar.set_postfix_str(note, refresh=False)
            self._bar.update(int(n))
            if self.count >= self.total and self.elapsed >= self._bar.delay:
                self._bar.refresh()  # the last step is always shown (tqdm may skip it)

    def write(self, line: str) -> None:
        """Print ``line`` to the stream above the bar (which is redrawn below it)."""
        if self._bar is not None:
            self._bar.write(line, file=self._stream)
        else:
            print(line, file=self._stream)

    def close(self) -> None:
        """Clear the bar's line (if it was drawn)."""
        if self._bar is not None:
            self._bar.close()

    @property
    def elapsed(self) -> float:
        """Seconds since the bar was created."""
        return time.perf_counter() - self.start

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
