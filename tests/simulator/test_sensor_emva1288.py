"""The sensor against the EMVA 1288 reference implementation (the ``emva1288`` package).

Photon-transfer captures (a dark and a bright pair at each exposure of an exposure-time
series at constant irradiance, and a dark and a bright stack for the spatial figures) come
from the sensor-level API :meth:`Sensor.frames`; the figures are computed by emva1288's own
code (``Data1288``, ``Results1288``) and compared with the configured sensor.
"""

from __future__ import annotations

import numpy as np
import pytest
from gonio.simulator import Sensor

emva = pytest.importorskip("emva1288.process")
routines = pytest.importorskip("emva1288.process.routines")

SHAPE = (480, 640)


@pytest.fixture(autouse=True)
def _numpy2_alias(monkeypatch):
    """emva1288 1.0.2 (the newest release) calls ``np.asfarray``, which NumPy 2.0 removed;
    give it back as what it was (``asarray`` to float) for these tests only."""
    if not hasattr(np, "asfarray"):
        monkeypatch.setattr(np, "asfarray", lambda a, dtype=float: np.asarray(a, dtype=dtype),
                            raising=False)  # fmt: skip


def _pair_stats(frames: np.ndarray) -> dict:
    """What emva1288's image loader keeps of a temporal pair (sum, pseudo-variance and mean
    difference summed over the pixels)."""
    d = routines.get_int_imgs(list(frames))
    return {"sum": np.sum(d["sum"]), "pvar": np.sum(d["pvar"]), "dmean": d["dmean"]}


def _photon_transfer(sensor: Sensor, rate: float, exposures_s, spatial: tuple, n_stack: int):
    """emva1288's results for a sensor lit at ``rate`` photons per pixel per second
    (exposure-time series; exposure times in ns, emva1288's unit) and the spatial stacks
    at ``spatial = (exposure_s, photons per pixel)``."""
    gen = np.random.default_rng(20260)
    temporal: dict = {}
    for t in exposures_s:
        ns = float(t * 1e9)
        dark = sensor.frames(np.zeros(SHAPE), t, 2, gen)
        bright = sensor.frames(np.full(SHAPE, rate * t), t, 2, gen)
        temporal[ns] = {0.0: _pair_stats(dark), float(rate * t): _pair_stats(bright)}
    t, p = spatial
    dark = sensor.frames(np.zeros(SHAPE), t, n_stack, gen)
    bright = sensor.frames(np.full(SHAPE, p), t, n_stack, gen)
    stacks = {
        float(t * 1e9): {
            0.0: routines.get_int_imgs(list(dark)),
            float(p): routines.get_int_imgs(list(bright)),
        }
    }
    data = {"temporal": temporal, "spatial": stacks, "height": SHAPE[0], "width": SHAPE[1]}
    return emva.Results1288(emva.Data1288(data).data, loglevel=40)


@pytest.mark.parametrize("kind", ["today", "realistic"])
def test_emva1288_recovers_gain_read_noise_prnu_dark_current_and_qe(kind):
    # today's sensor: gain 10 e-/DN (K = 0.1 DN/e-), read noise 8 e-, PRNU 0.5 %, dark
    # current 20 e-/s, QE 0.5; the realistic one adds the charge clip before the read noise,
    # blooming, smear, offsets and hot pixels (dark current 20.2 e-/s on average). 16
    # exposures from 0.5 to 10 s at 10 000 photons/s per pixel (saturation at ~8 s), the
    # spatial stacks of 16 at 50 % fill and 10 ms (where the hot pixels' dark charge is small,
    # as in a laboratory's measurement at the working exposure)
    s = Sensor() if kind == "today" else Sensor.realistic(array_shape=SHAPE)
    rate = 10_000.0
    exposures = np.linspace(0.5, 10.0, 16)
    r = _photon_transfer(s, rate, exposures, spatial=(0.01, 40_000.0), n_stack=16)
    fig = s.emva1288(0.01)
    got = {
        "K": r.K,
        "sigma_d": r.sigma_d,
        "PRNU": r.PRNU1288,
        "dark_current": r.u_I_mean,
        "QE": r.QE / 100.0,
    }
    want = {"K": fig["system_gain_dn_per_e"], "sigma_d": s.read_noise,
            "PRNU": fig["prnu_percent"], "dark_current": fig["dark_current_e_s"],
            "QE": fig["quantum_efficiency"]}  # fmt: skip
    rel = {k: got[k] / want[k] - 1.0 for k in want}
    print(kind, {k: f"{v:+.4%}" for k, v in rel.items()})
    for k, v in rel.items():
        assert abs(v) < 0.01, (k, got[k], want[k])
    # the saturation capacity emva1288 finds (the photon level of the largest variance)
    # lies within one exposure step of the figure the sensor reports
    step = rate * (exposures[1] - exposures[0]) * s.qe
    assert abs(r.u_e_sat - fig["saturation_capacity_e"]) <= step


def test_emva1288_splits_the_offset_patterns_into_row_column_and_pixel():
    # offsets large enough to measure with a stack of 16 (the temporal noise of the mean
    # image is 8 e- / 4): pixel 20 e-, rows 10 e-, columns 15 e-; EMVA 1288 R4.0 Sec. 4
    # splits the dark signal's spatial variance into exactly these parts
    s = Sensor(offset_dsnu=20.0, row_dsnu=10.0, column_dsnu=15.0, dark_current=0.0,
               charge_clip=True, array_shape=SHAPE)  # fmt: skip
    r = _photon_transfer(s, 10_000.0, np.linspace(0.5, 10.0, 4), (0.5, 5000.0), n_stack=16)
    off = s.offset_map(*SHAPE)
    # the realised pattern's parts (what the emva1288 estimators aim at)
    rows = off.mean(axis=1) - off.mean()
    cols = off.mean(axis=0) - off.mean()
    pix = off - off.mean(axis=1, keepdims=True) - off.mean(axis=0, keepdims=True) + off.mean()
    real = {"row": rows.std(), "col": cols.std(), "pixel": pix.std()}
    got = {"row": r.DSNU1288_row, "col": r.DSNU1288_col, "pixel": r.DSNU1288_pixel}
    print({k: (round(got[k], 3), round(real[k], 3)) for k in got})
    for k in got:
        assert got[k] == pytest.approx(real[k], rel=0.03), k
    assert real["row"] == pytest.approx(10.0, rel=0.1)
    assert real["col"] == pytest.approx(15.0, rel=0.1)
    assert real["pixel"] == pytest.approx(20.0, rel=0.02)
