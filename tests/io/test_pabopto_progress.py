"""The BSDF build's progress: Radiance's own progress bar read while the tool runs."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import brdf
from gonio.io import pabopto
from gonio.samples import BRDFSamples


def test_bar_fraction_reads_bsdf2klems_progress_bar():
    # bsdf2klems' stderr (Radiance 6.0, prog_show): '\r', '*' done, a spinner, '-' to do
    bar = "\r" + "-" * 79 + "\r*\\" + "-" * 77 + "\r" + "*" * 39 + "|" + "-" * 39 + "\r**"
    assert pabopto._bar_fraction("bsdf2klems: Interpolating...\n" + bar) == 39 / 78
    assert pabopto._bar_fraction("no bar here\n") is None
    assert pabopto._bar_fraction("\r" + "*" * 78 + "-\r" + " " * 79 + "\r") == 1.0


def test_build_reports_each_program_and_the_klems_bar(tmp_path):
    pytest.importorskip("pyradiance")
    m = brdf.create("ward_gmd", rho_d=0.3, rho_s=0.05, alpha_x=0.15, alpha_y=0.15)
    to, po = np.meshgrid(np.radians(np.linspace(5, 85, 9)), np.radians(np.arange(0, 360, 30)))
    n = to.size
    ti = np.repeat(np.radians([10.0, 50.0]), n)
    s = BRDFSamples(ti, np.zeros(2 * n), np.tile(to.ravel(), 2), np.tile(po.ravel(), 2),
                    np.zeros(2 * n), np.full(2 * n, np.nan))  # fmt: skip
    s.value = m(s.wi, s.wo)
    lines: list[str] = []
    b = pabopto.build_bsdf(s, tmp_path, "tile", samples_per_patch=4, progress=lines.append)
    assert b.xml.exists()
    assert lines[0].startswith("pabopto2bsdf: 2 incident directions") and "about" in lines[0]
    assert any(x.startswith("bsdf2klems: -n 4") for x in lines)
    done = [x.split(":")[0] for x in lines if x.endswith(" s") and "done in" in x]
    assert done == ["pabopto2bsdf", "bsdf2klems"]
    pct = [x for x in lines if x.startswith("bsdf2klems:") and "% (" in x]
    assert pct and all("s left)" in x for x in pct)
