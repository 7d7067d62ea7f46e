"""
Planning a measurement
======================

You are about to measure a sample on an imaging gonioreflectometer and have to decide how:
which incidence angles, whether to rotate the sample, how long it will take and how well the
result will pin down the model you want to fit. gonio answers these questions before you book
the instrument: it runs the whole campaign — captures, eq. 2 reduction, fit, report — on a
simulated instrument whose truth is known, so every plan can be judged by what it recovers.

This tutorial chooses an instrument and a material, runs a small campaign, reads its summary,
then compares two plans and what each costs.
"""

# %%
# The instrument and the material
# -------------------------------
# The campaign instrument is the LBL imaging gonioreflectometer (Ward 1992): a half-silvered
# dome images the whole reflected hemisphere into a fisheye camera, so one exposure bracket
# per incidence angle measures every outgoing direction at once. Its dome is an ellipsoid
# (default) or a hemisphere. The material is a preset from the papers' tables; its model and
# parameters are the truth the campaign is judged against.
import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from gonio import campaign, materials

print(materials.names("ward"))
print(materials.info("rolled_brass"))

# %%
# A first campaign
# ----------------
# A :class:`~gonio.campaign.plan.Plan` says what is measured and how; every field has a
# default (Ward's protocol: 21 incidence angles from 0° to 80°, the sample measured at two
# rotations when it is anisotropic). Three angles are enough to see what a summary holds.
# ``workers=1`` keeps the run in this process, ``plots=False`` skips the campaign's own PNG
# plots (we draw our own below), and the results folder goes to a temporary directory.
work = Path(tempfile.mkdtemp(prefix="gonio-plan-"))
plan = campaign.Plan(material="rolled_brass", theta_i_deg=(10, 40, 70), plots=False)
res = campaign.run(plan, work / "first", workers=1)
print(campaign.summary_table(res.summary))

# %%
# The summary is a plain dictionary (the campaign also writes it as ``summary.json``). It is
# the one place where the simulator's truth and the measured result meet: ``fit`` and
# ``stderr`` are what a laboratory would get from its captures, ``truth`` is what the
# simulator knows, and ``within_3_sigma`` says whether each parameter's error is consistent
# with its standard error.
s = res.summary
for name in s["fit"]:
    print(
        f"{name:8s} truth {s['truth'][name]:.4f}  fit {s['fit'][name]:.5f}"
        f" ± {s['stderr'][name]:.1e}  within 3σ: {s['within_3_sigma'][name]}"
    )
print("resolved rotations:", res.plan.rotations_deg, " chi2/dof:", round(s["chi2_dof"], 3))

# %%
# Two plans and what each costs
# -----------------------------
# Plan A is quick: three angles, one sample rotation. Plan B measures five angles at two
# rotations, the way Ward measured anisotropic samples so that both principal directions lie
# in the plane of incidence once. The cost of a plan on the real instrument is its number of
# exposures (each a stage move and a frame) and the shutter-open time; both are read back from
# the side-cars in the results folder. On a real instrument the stage moves and the frame
# read-outs dominate the shutter time; the LBL campaign does not model them, so the number of
# frames is the figure to scale (the Cornell campaign's summary does estimate its real
# instrument time, ``estimated_real_instrument_h``). The simulation's own compute time is in
# ``timings_s``.
plans = {
    "A: 3 angles, 1 rotation": campaign.Plan(
        material="rolled_brass", theta_i_deg=(10, 40, 70), rotations_deg=(0,), plots=False
    ),
    "B: 5 angles, 2 rotations": campaign.Plan(
        material="rolled_brass",
        theta_i_deg=(10, 25, 40, 55, 70),
        rotations_deg=(0, 90),
        plots=False,
    ),
}


def frames_and_exposure(folder: Path) -> tuple[int, float]:
    """Number of raw frames and their summed exposure time, from the JSON side-cars."""
    cars = [p for p in (folder / "raw").rglob("*.json") if p.name != "done.json"]
    return len(cars), sum(json.loads(p.read_text())["exposure_s"] for p in cars)


results = {}
for label, p in plans.items():
    r = campaign.run(p, work / label[0], workers=1)
    n_frames, shutter_s = frames_and_exposure(work / label[0])
    results[label] = (r, n_frames, shutter_s)
    print(
        f"{label}: {r.summary['n_samples']} samples from {n_frames} frames, "
        f"shutter open {shutter_s:.2f} s, simulated in {r.timings_s['total']:.2f} s"
    )

# %%
# What the extra captures buy: the standard error of every parameter, relative to its value,
# and the actual error against the truth (both from the summaries).
params = list(s["fit"])
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
x = np.arange(len(params))
for k, (label, (r, n_frames, _)) in enumerate(results.items()):
    rel_se = [r.summary["stderr"][q] / abs(r.summary["fit"][q]) for q in params]
    rel_err = [r.summary["relative_error"][q] for q in params]
    ax1.bar(x + 0.38 * (k - 0.5), rel_se, 0.38, label=f"{label} ({n_frames} frames)")
    ax2.bar(x + 0.38 * (k - 0.5), rel_err, 0.38, label=label)
for ax, title in ((ax1, "relative standard error"), (ax2, "|fit − truth| / truth")):
    ax.set_xticks(x, params)
    ax.set_yscale("log")
    ax.set_title(title)
ax1.legend(fontsize=8)
fig.suptitle("rolled brass, Ward fit: two plans")
fig.tight_layout()

# %%
# What plan B adds is margin (smaller standard errors) and the second rotation, which matters
# as soon as the model has separate x and y coefficients that one rotation cannot separate
# (Lafortune's lobes, see :class:`~gonio.campaign.plan.Plan`). To run a whole grid of plans
# (materials × settings × seeds) with a results table, use ``gonio sweep``
# (:doc:`../commands/sweep`); the command line for a single campaign is ``gonio campaign``
# (:doc:`../commands/campaign`).
