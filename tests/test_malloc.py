"""keep_freed: a process making and dropping full-image temporaries stops faulting them in."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc")

FRAMES = """
import json, resource, sys
import numpy as np
from gonio.malloc import keep_freed
if sys.argv[1] == "keep":
    keep_freed()
img = np.random.default_rng(0).random((480, 640))
def frame(x):  # four full-image temporaries, as a capture's passes make them
    a = x * 2.0; b = np.sqrt(a); c = (b - 1.0) / 3.0; d = np.clip(c, 0, 1)
    return float(d.sum())
sums = [frame(img) for _ in range(3)]
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
sums += [frame(img) for _ in range(50)]
print(json.dumps([resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0, sums]))
"""


def _faults(mode: str) -> tuple[int, list[float]]:
    r = subprocess.run([sys.executable, "-c", FRAMES, mode], capture_output=True, text=True,
                       timeout=60, check=True)  # fmt: skip
    return tuple(json.loads(r.stdout))


def test_kept_blocks_are_not_faulted_in_again_and_the_sums_are_the_same():
    default, kept = _faults("default"), _faults("keep")
    pages = 480 * 640 * 8 // 4096  # one temporary
    assert default[0] > 50 * pages  # glibc's adaptive thresholds give the heap back each frame
    assert kept[0] < pages  # the freed blocks are reused: (almost) no new page
    assert kept[1] == default[1]
