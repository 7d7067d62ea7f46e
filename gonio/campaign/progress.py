"""A small terminal progress bar for long stages (campaign captures, reductions, fits).

The bar appears only on a terminal, only once a task has run longer than ``min_time``
(1 s by default), and never with ``quiet=True``; it redraws at most ten times a second and
clears its line when it closes, so short runs and logs stay clean.

>>> with Progress(3, "capture", quiet=True) as bar:
...     for _ in range(3):
...         bar.update()
>>> bar.count
3
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

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
    ) -> None:
        if int(total) < 0:
            raise ValueError(f"total must be >= 0, got {total!r}")
        self.total = int(total)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = not quiet and (tty or force)
        self.min_time = float(min_time)
        self.width = int(width)
        self.count = 0
        self.start = time.perf_counter()
        self._last = 0.0
        self._drawn = False

    def update(self, n: int = 1, label: str | None = None) -> None:
        """Advance by ``n`` steps (and optionally change the label)."""
        self.count += int(n)
        if label is not None:
            self.label = label
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.start < self.min_time:
            return
        if self._drawn and now - self._last < 0.1 and self.count < self.total:
            return
        self._draw(now)

    def _draw(self, now: float) -> None:
        frac = min(self.count / self.total, 1.0) if self.total else 1.0
        filled = round(frac * self.width)
        bar = "#" * filled + "." * (self.width - filled)
        text = f"\r{self.label} [{bar}] {self.count}/{self.total} {now - self.start:.1f} s"
        self.stream.write(text)
        self.stream.flush()
        self._drawn = True
        self._last = now

    def close(self) -> None:
        """Clear the bar's line (if it was drawn)."""
        if self._drawn:
            self.stream.write("\r" + " " * (self.width + len(self.label) + 30) + "\r")
            self.stream.flush()
            self._drawn = False

    @property
    def elapsed(self) -> float:
        """Seconds since the bar was created."""
        return time.perf_counter() - self.start

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
