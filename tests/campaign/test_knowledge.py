"""The truth-free reduction (campaign/knowledge.py): the laboratory's side-cars, bit
identity on the ideal instrument, and a reduction that never reaches the simulator's
instrument, sensor or bench."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gonio.campaign import Plan, run
from gonio.campaign.knowledge import (
    SENSOR_FIELDS,
    SIDECAR_FIELDS,
    check_corrections,
    laboratory_view,
    reduce_incidence,
)

sim = pytest.importorskip("gonio.simulator")

#: the simulator's own modules a reduction must never import (instruments, sensor truth,
#: bench, source, effects, the true standard)
FORBIDDEN = (
    "gonio.simulator.lbl", "gonio.simulator.sensor", "gonio.simulator.bench",
    "gonio.simulator.source", "gonio.simulator.cornell", "gonio.simulator.effects",
    "gonio.simulator.lbl_effects", "gonio.simulator.standard", "gonio.simulator._kernels",
)  # fmt: skip


def test_laboratory_view_keeps_what_an_instrument_writes():
    inst = sim.LBLInstrument(width=160, height=120)
    img, meta = inst.capture("standard", 0.3, 0.0, noise=False)
    ((_, m),) = laboratory_view([(img, meta)])
    assert set(m) <= SIDECAR_FIELDS | {"sensor"}
    assert set(m["sensor"]) <= SENSOR_FIELDS
    for truth in ("full_lens", "source", "background", "brdf", "sample_radius"):
        assert truth in meta and truth not in m
    assert m["f_number"] == meta["f_number"] and m["sensor"]["gain_e_per_dn"] > 0


def test_the_laboratory_saturation_replaces_the_side_cars_of_frames_read_out_alike():
    inst = sim.LBLInstrument(width=160, height=120)
    img, meta = inst.capture("standard", 0.3, 0.0, noise=False)
    rec = {"saturation_dn": 4040.0, "binning": None}
    ((_, m),) = laboratory_view([(img, meta)], rec)
    assert m["sensor"]["saturation_dn"] == 4040.0 != meta["sensor"]["saturation_dn"]
    ((_, m),) = laboratory_view([(img, meta)], {**rec, "binning": [108, 80]})
    assert m["sensor"]["saturation_dn"] == meta["sensor"]["saturation_dn"]


def test_corrections_are_checked():
    assert check_corrections(None) == (
        "geometry", "standard", "exposure", "glare", "saturation", "drift",
    )  # fmt: skip
    assert check_corrections(["glare"]) == ("glare",)
    with pytest.raises(ValueError, match="unknown"):
        check_corrections(["flatfield"])
    with pytest.raises(ValueError, match="unknown"):
        Plan(corrections=("nope",)).resolved()


def test_ideal_reduction_is_bit_identical_to_the_side_car_reduction():
    from gonio.calibration.reduce import Capture, reduce_selected

    inst = sim.LBLInstrument()
    ti = math.radians(40.0)
    std = inst.bracket("standard", ti, 0.0, rng=1)
    bg = inst.bracket(None, ti, 0.0, rng=2)
    meas = inst.bracket("rolled_brass", ti, 0.0, rng=3)
    ((new, info),) = reduce_incidence(std, bg, {0.0: meas}, None, seeds={0.0: 5}, debias=True)
    old = reduce_selected(Capture(meas), Capture(std), Capture(bg), rng=5, debias=True).samples
    for col in ("theta_i", "phi_i", "theta_o", "phi_o", "value", "sigma"):
        assert np.array_equal(getattr(new, col), getattr(old, col)), col
    assert info["n_frames"] == len(meas)


_CHILD = textwrap.dedent(
    """
    import importlib.abc, json, sys
    FORBIDDEN = tuple(json.loads(sys.argv[2]))

    class Guard(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.startswith(FORBIDDEN):
                raise ImportError(f"the reduction imported {name}")
            return None

    sys.meta_path.insert(0, Guard())
    for m in list(sys.modules):
        if m.startswith(FORBIDDEN):
            del sys.modules[m]

    class SideCar(dict):
        # a side-car whose simulator-only fields raise when read
        def __init__(self, d, allowed):
            super().__init__(d)
            self.allowed = allowed
        def __getitem__(self, k):
            if k not in self.allowed:
                raise AssertionError(f"the reduction read the side-car's {k!r}")
            v = super().__getitem__(k)
            return SideCar(v, SENSOR) if k == "sensor" else v
        def get(self, k, default=None):
            return self[k] if k in self else default
        def items(self):
            raise AssertionError("the reduction read every side-car field")
        values = items

    from pathlib import Path
    from gonio.campaign.folder import group_key, load_group as _load

    def load_group(folder):  # the group as the campaign recorded it
        return _load(folder, json.loads((folder / "done.json").read_text())["made_by"])
    from gonio.campaign.knowledge import SENSOR_FIELDS as SENSOR, SIDECAR_FIELDS as KEPT
    from gonio.campaign.knowledge import reduce_incidence
    from gonio.campaign.plan import Plan, capture_seed
    from gonio.samples import BRDFSamples
    from gonio import fit

    out = Path(sys.argv[1])
    # plan.json holds the resolved plan (resolving again would check the preset against
    # the simulator's effects, which this process must not import)
    plan = Plan.from_dict(json.loads((out / "plan.json").read_text()))
    lab = None
    if (out / "calibration" / "calibration.json").is_file():
        from gonio.calibration.laboratory import read_calibration
        lab = read_calibration(out / "calibration")
    guard = lambda frames: [(img, SideCar(m, KEPT | {"sensor"})) for img, m in frames]
    tables = []
    for th in plan.theta_i_deg:
        ref = load_group(out / "raw" / group_key(th))
        meas = {r: guard(load_group(out / "raw" / group_key(th, r))["measured"])
                for r in plan.rotations_deg}
        seeds = {r: capture_seed(plan.seed, group_key(th, r) + "/select") for r in meas}
        for t, _ in reduce_incidence(guard(ref["standard"]), guard(ref["background"]), meas,
                                     lab, corrections=plan.corrections, seeds=seeds,
                                     debias=plan.debias and plan.noise > 0,
                                     select=dict(plan.thinning)):
            tables.append(t)
    res = fit.fit(BRDFSamples.concatenate(tables), plan.model)
    bad = sorted(m for m in sys.modules if m.startswith(FORBIDDEN))
    print(json.dumps({"params": res.params, "imported": bad}))
    """
)


def _reduce_in_guarded_process(out) -> dict:
    p = subprocess.run([sys.executable, "-P", "-c", _CHILD, str(out), json.dumps(FORBIDDEN)],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def _check_same_fit(result, child) -> None:
    assert child["imported"] == []
    for k in result.fit.free:
        assert child["params"][k] == pytest.approx(result.fit.params[k], rel=1e-9, abs=1e-12)


def test_reduction_never_reaches_the_simulator_truth(tmp_path):
    """The saved captures reduced in a process where the simulator's instruments, sensor,
    bench, source and effects cannot be imported, with side-cars whose simulator-only
    fields raise when read, give the campaign's fit exactly."""
    plan = Plan(theta_i_deg=(20.0, 50.0), plots=False, seed=2)
    result = run(plan, tmp_path / "ideal", workers=1)
    _check_same_fit(result, _reduce_in_guarded_process(tmp_path / "ideal"))


@pytest.mark.slow
def test_realistic_reduction_never_reaches_the_simulator_truth(tmp_path):
    """The same for a realistic instrument, with its laboratory calibration folder."""
    pytest.importorskip("gonio.simulator.effects")
    plan = Plan(theta_i_deg=(20.0, 50.0), plots=False, seed=2, preset="modern")
    result = run(plan, tmp_path / "modern", workers=1)
    assert (tmp_path / "modern" / "calibration" / "calibration.json").is_file()
    _check_same_fit(result, _reduce_in_guarded_process(tmp_path / "modern"))


def test_a_digitised_peak_near_saturation_is_left_out_and_a_flat_field_kept():
    """Ward's digitiser averages boxes of camera pixels (Ward 1992 §3): a lobe's peak whose
    box holds a clipped camera pixel reads below the top code. Such a pixel (high, on a
    slope) is set to the saturation level so that the merge leaves it out; a flat field
    (the standard) at the same level is kept, and a frame without a level is unchanged."""
    from gonio.campaign.knowledge import DIGITISED_USABLE, digitised_clipping

    sat = 4000.0
    flat = np.full((8, 10), 0.9 * sat, dtype=np.uint16)
    assert digitised_clipping(flat, sat) is flat
    peak = np.full((8, 10), 0.2 * sat, dtype=np.uint16)
    peak[4, 5] = 0.95 * sat  # a lobe's top, far above its neighbours
    peak[4, 6] = 0.5 * sat  # on the slope, below the usable fraction
    got = digitised_clipping(peak, sat)
    assert got[4, 5] == sat and got[4, 6] == peak[4, 6]
    assert np.array_equal(np.delete(got.ravel(), 4 * 10 + 5), np.delete(peak.ravel(), 45))
    assert DIGITISED_USABLE * sat < 0.95 * sat
    assert digitised_clipping(peak, None) is peak
