"""Atomic and durable file writes: a file holds its old content or all of the new, never a part.

Every writer in gonio goes through :func:`atomic_write_bytes` (a temporary file in the same
folder, renamed into place), so a killed process, a full disk or a read-only folder never
leaves a half-written result.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

__all__ = ["atomic_write_bytes", "fsync_files"]


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and rename.

    The rename makes the write atomic: ``path`` holds its old content or all of ``data``,
    never a part, whatever happens to the process. ``durable`` also flushes the file to the
    disk (``fsync``) before the rename, so that it survives a power failure; bulk files
    written in a burst (a campaign's raw frames) pass ``False`` and are flushed together
    afterwards (:func:`fsync_files`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def fsync_files(paths: Iterable[str | os.PathLike]) -> int:
    """Flush files (and then their folders) to the disk; return how many files.

    One pass after a burst of ``durable=False`` writes: the disk writes of all of them are
    then in flight together, instead of one ``fsync`` waiting per file.
    """
    folders = set()
    n = 0
    for p in paths:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        folders.add(os.path.dirname(os.path.abspath(p)))
        n += 1
    for d in sorted(folders):
        try:
            fd = os.open(d, os.O_RDONLY)
        except OSError:  # (a platform that cannot open folders)
            continue
        try:
            os.fsync(fd)
        except OSError:
            pass
        finally:
            os.close(fd)
    return n


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
