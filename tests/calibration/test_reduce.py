"""End-to-end reduction on simulated LBL captures (reduced form of benchmarks/bench_reduce.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gonio.calibration import Capture, reduce_capture

from gonio import materials

sim = pytest.importorskip("gonio.simulator")


def _triple(inst, name, ti, noise, seed):
    kw = {"noise": noise, "rng": np.random.default_rng(seed)}
    meas = Capture(inst.bracket(name, ti, 0.0, min_signal_dn=400, **kw))
    std = Capture(inst.bracket("standard", ti, 0.0, **kw))
    bg = Capture(
        [inst.capture(None, ti, 0.0, exposure=m["exposure_s"], f_number=m["f_number"], **kw)
         for _, m in std.frames]
    )  # fmt: skip
    return meas, std, bg


@pytest.mark.parametrize(("mirror", "method"), [("ellipsoid", "eq3"), ("hemisphere", "exact")])
def test_noise_off_accuracy(mirror, method):
    inst = sim.LBLInstrument(mirror=mirror, radius=0.15, half_separation=0.0075,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    r = reduce_capture(*_triple(inst, "rolled_brass", np.radians(30), False, 0), method=method)
    s = r.samples
    rel = np.abs(s.value / materials.get("rolled_brass")(s.wi, s.wo) - 1)
    assert np.median(rel) <= 0.005 and np.percentile(rel, 95) <= 0.02
    assert r.stats["n_after"] < r.stats["n_before"]


def test_noise_on_normalised_residuals():
    inst = sim.LBLInstrument(mirror="ellipsoid", radius=0.15, half_separation=0.01,
                             lens="equidistant", width=320, height=240)  # fmt: skip
    r = reduce_capture(*_triple(inst, "glossy_grey_paper", np.radians(50), True, 7))
    s = r.samples
    z = (s.value - materials.get("glossy_grey_paper")(s.wi, s.wo)) / s.sigma
    assert 0.8 <= z.std() <= 1.25


def test_rejects_non_capture():
    with pytest.raises(ValueError, match="Capture"):
        reduce_capture(None, None, None)
