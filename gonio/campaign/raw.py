"""What a campaign keeps of its raw frames on the disk, and the folder's footprint.

A campaign writes its raw 16-bit frames uncompressed (:func:`gonio.campaign.folder`: speed
over size; the default campaign's 146 frames are 85 MB of its 107 MB). Once it is done,
``keep`` leaves them as they are, ``compressed`` re-encodes each frame with LZW — lossless:
:func:`gonio.io.images.read_image` reads back the same pixels, bit for bit, and the side-cars
are untouched, so ``--resume`` and a later reduction use them as before — and ``none``
removes the ``raw`` folder (a re-run then captures again).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

__all__ = ["RAW_CHOICES", "disk_usage", "keep_raw"]

#: what :func:`keep_raw` can keep of the raw frames
RAW_CHOICES = ("keep", "compressed", "none")


def disk_usage(folder: str | os.PathLike) -> dict[str, int]:
    """Bytes of the files under ``folder``: ``{"total": ..., "raw": ...}`` (``raw``: its
    ``raw`` sub-folder)."""
    folder = Path(folder)

    def size(root: Path) -> int:
        return sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) if root.is_dir() else 0

    return {"total": size(folder), "raw": size(folder / "raw")}


def keep_raw(folder: str | os.PathLike, raw: str) -> None:
    """Keep the raw frames of the campaign folder ``folder`` as ``raw`` says (one of
    :data:`RAW_CHOICES`, see the module docstring)."""
    if raw not in RAW_CHOICES:
        raise ValueError(f"raw {raw!r}; expected one of {', '.join(RAW_CHOICES)}")
    root = Path(folder) / "raw"
    if raw == "keep" or not root.is_dir():
        return
    if raw == "none":
        shutil.rmtree(root)
        return
    from gonio.campaign.folder import flush_raw
    from gonio.io.images import read_image, write_image

    for path in sorted(root.rglob("*.tif")):
        img, _ = read_image(path)
        # metadata None: the side-car is left as it is; the write is atomic (a frame is
        # either the old file or the new one), flushed to the disk with the others below
        # (one fsync per frame took 6.7 s of wall time for the default campaign's 146)
        write_image(path, img, None, compress=True, durable=False)
    flush_raw(root)
