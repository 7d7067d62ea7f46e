"""glibc malloc's thresholds for processes that make and drop full-image arrays.

:func:`keep_freed` is called where a process's life is gonio's own: the ``gonio`` command
(:func:`gonio.cli.console_main`) and a campaign's forked children
(:mod:`gonio.campaign.executor`), never in a process that imports gonio as a library.

References
----------
.. [mallopt] The GNU C Library, ``mallopt(3)``: ``M_MMAP_THRESHOLD``, ``M_TRIM_THRESHOLD``
   and their dynamic adjustment.
"""

from __future__ import annotations

import sys

__all__ = ["MALLOC_MMAP_THRESHOLD", "MALLOC_TRIM_THRESHOLD", "keep_freed"]

#: glibc malloc's thresholds (bytes): blocks up to 32 MiB (as far as its adaptive threshold
#: goes on 64-bit systems) come from the heap, and up to 256 MiB of freed heap is kept
MALLOC_MMAP_THRESHOLD = 32 << 20
MALLOC_TRIM_THRESHOLD = 256 << 20


def keep_freed() -> None:
    """glibc's malloc in this process keeps freed image-sized blocks for the next ones.

    Its default thresholds adapt: a block freed from ``mmap`` raises the threshold to its
    size, but the heap is given back to the kernel as soon as its free top exceeds twice
    that, so a process making and dropping a few full-image temporaries a frame (640 x 480
    float64 arrays, 2.4 MB) faults the same pages in again and again, each zeroed by the
    kernel. Fixed thresholds (:data:`MALLOC_MMAP_THRESHOLD`, :data:`MALLOC_TRIM_THRESHOLD`)
    keep them: 50 such frames took 240 ms and 118400 page faults here, with these
    thresholds 38 ms and none (``tests/test_malloc.py``). A no-op where there is no glibc
    ``mallopt``. It cannot be undone (set thresholds end glibc's adaptation), hence only in
    processes whose life is gonio's.
    """
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - no libc mallopt
        return
    mallopt(-3, MALLOC_MMAP_THRESHOLD)  # M_MMAP_THRESHOLD
    mallopt(-1, MALLOC_TRIM_THRESHOLD)  # M_TRIM_THRESHOLD
