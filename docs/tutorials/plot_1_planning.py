"""
Planning a measurement
======================

You are about to measure a sample on an imaging gonioreflectometer and have to decide how:
which incidence angles, whether to rotate the sample, how long it will take and how well the
result will pin down the model you want to fit. gonio answers these questions before you book
the instrument: it runs the whole campaign — calibration, captures, eq. 2 reduction, fit,
uncertainty budget, report — on a simulated instrument whose truth is known, so every plan
can be judged by what it recovers and by the uncertainty it would let you quote.

This tutorial chooses an instrument and a material, runs a small campaign on the realistic
default instrument, reads its uncertainty budget and its comparison with the truth, then
compares two plans and the time each would take on the real instrument.
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
import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from gonio.simulator import effects
from gonio.simulator.lbl_timing import TIMINGS, estimate_run_time

from gonio import campaign, materials
from gonio.campaign.folder import group_key
from gonio.campaign.sweep import run_sweep, spec_from_dict

print(materials.names("ward"))
print(materials.info("rolled_brass"))

# %%
# The instrument is built to a *preset*: every imperfection of the real device (the dome's
# figure, the lens's veiling glare, the f-stops' errors, the lamp's drift, the standard's
# departure from Lambert, ...) is a named effect whose magnitude the preset gives as a
# distribution over instruments built to that specification. ``"modern"`` (the default) is
# a realistic present-day build, ``"ward1992"`` Ward's prototype, ``"ideal"`` the perfect
# instrument. One physical instrument is one draw of every magnitude, chosen by an
# instrument seed, so **different seeds are different physical instruments** built to the
# same specification — a few of their magnitudes:
print("presets:", list(effects.PRESETS))
shown = ("dome_slope_error", "veiling_glare", "fstop_error", "sample_tilt", "lamp_drift")
inst0, inst1 = effects.realise("modern", 0), effects.realise("modern", 1)
for name in shown:
    unit = effects.EFFECTS[name].unit
    print(f"{name:18s} seed 0: {inst0[name]:.3g}   seed 1: {inst1[name]:.3g}   ({unit})")

# %%
# A first campaign
# ----------------
# A :class:`~gonio.campaign.plan.Plan` says what is measured and how; every field has a
# default (Ward's protocol of incidence angles, printed below; the sample measured at more
# than one rotation when it is anisotropic; the ``"modern"`` instrument; seed 0). Three
# angles are enough to see what a campaign reports. ``workers=1`` keeps the run in this
# process; the results folder goes to a temporary directory. The campaign first calibrates
# its instrument as a laboratory would (lens from ChArUco views, dome from mirror spots,
# f-stops from overlapping exposures; once per physical instrument), then captures the
# sample, the diffuse standard and the background at every angle, reduces them with that
# calibration and the standard's certificate only, fits the preset's model and builds the
# uncertainty budget. The printed report holds the fit against the truth, then the budget.
default = campaign.default_plan().resolved()
print(f"default: {len(default.theta_i_deg)} angles from {min(default.theta_i_deg):g}°"
      f" to {max(default.theta_i_deg):g}°, rotations {default.rotations_deg},"
      f" preset {default.preset!r}, seed {default.seed}")  # fmt: skip
work = Path(tempfile.mkdtemp(prefix="gonio-plan-"))
plan = campaign.Plan(material="rolled_brass", theta_i_deg=(10, 40, 70))
res = campaign.run(plan, work / "first", workers=1)
s = res.summary
print(campaign.summary_table(s))
print("instrument:", s["instrument"]["preset"], "seed", s["instrument"]["instrument_seed"])
print("resolved rotations:", res.plan.rotations_deg)

# %%
# Reading the uncertainty budget
# ------------------------------
# The budget follows the GUM (JCGM 100:2008). Its first row is the fit's **statistical**
# standard error (a Type A evaluation: the sensor noise seen through the fit). Every other
# row is one imperfection of the instrument (a Type B evaluation): ``u (effect)`` is the
# standard uncertainty of the effect *after* the laboratory's correction, in the effect's
# unit, and each parameter's column is the contribution it makes to that parameter — the
# parameter's sensitivity to the effect (the effect's perturbation of the samples pushed
# through the fit's Jacobian) times ``u``. Rows marked ``(uncorr.)`` are effects the
# laboratory does not correct, so their whole magnitude stays in the data; an effect with
# several independent shapes or axes has one row per component (``[0]``, ``[1]``, ...).
# The contributions combine by the law of propagation of uncertainty into the combined
# standard uncertainty ``u_c`` (root sum of squares, with the correlations the shared
# effects produce), and ``U = k u_c`` with ``k = 2`` is the expanded uncertainty (about 95 %
# coverage) to quote with the result. All of it is in the summary (and ``summary.json``)
# under ``"budget"``:
b = s["budget"]
print(b["method"])
print("keys:", sorted(b))
for p in b["params"]:
    terms = b["terms"]
    top = max(terms, key=lambda t: abs(terms[t]["contribution"][p]))
    print(
        f"{p:8s} statistical {b['statistical'][p]:.2e}  u_c {b['combined'][p]:.2e}"
        f" ({b['combined'][p] / b['statistical'][p]:.1f} × statistical)"
        f"  U {b['expanded'][p]:.2e};  largest term: {top}"
    )

# %%
# The campaign draws the same budget as ``plots/budget.png``: one panel per parameter, a
# bar per source (components of one effect combined), on a logarithmic axis of relative
# standard uncertainty; the vertical lines are ``u_c`` (solid) and ``U`` (dashed), hatched
# bars the uncorrected effects.
print(sorted(p.name for p in (work / "first" / "plots").iterdir()))
png = plt.imread(work / "first" / "plots" / "budget.png")
fig, ax = plt.subplots(figsize=(12, 12 * png.shape[0] / png.shape[1]))
ax.imshow(png)
ax.axis("off")
fig.tight_layout(pad=0)

# %%
# The truth comparison
# --------------------
# Only a simulation knows the truth, and the summary is the one place where it meets the
# result: ``truth`` is the preset, ``fit`` what the laboratory got from its captures (the
# report's ``pull`` column is ``(fit − truth) / s.e.``). The check that matters for planning
# is whether each parameter's actual error lies within the uncertainty the laboratory would
# quote. Against the statistical standard error alone (``within_3_sigma``) it need not hold
# on a realistic instrument: more pixels shrink the noise, but not the instrument's
# systematic errors. Against the budget's expanded uncertainty (``within_expanded``:
# ``|fit − truth| ≤ U``) it should hold about 95 times in 100. The counts printed last are
# this campaign's.
print("param    |fit-truth|  3 × s.e.   U (k=2)    within 3 s.e.  within U")
for p in s["fit"]:
    err = abs(s["fit"][p] - s["truth"][p])
    print(
        f"{p:8s} {err:.3e}    {3 * s['stderr'][p]:.3e}  {b['expanded'][p]:.3e}"
        f"  {s['within_3_sigma'][p]!s:13s}  {s['within_expanded'][p]}"
    )
n = len(s["fit"])
print(
    f"within 3 s.e.: {sum(s['within_3_sigma'].values())} of {n};"
    f" within U: {sum(s['within_expanded'].values())} of {n}"
)

# %%
# This comparison is one instrument and one noise draw. Re-running with ``seed=1`` measures
# with *another* physical instrument (``instrument_seed`` defaults to the seed), so its
# errors differ by amounts the budget's ``u_c`` describes, not only by the statistical
# error; to repeat a measurement on the same instrument, fix ``instrument_seed`` and vary
# ``seed``. Judging a plan on many instruments is what ``gonio sweep`` over seeds is for.

# %%
# Two plans, compared with a sweep
# --------------------------------
# Plan A measures three incidence angles, plan B five; both measure the anisotropic brass at
# two rotations, 0° and 90°, so that both principal directions lie in the plane of incidence
# once (the default rotations, printed for the first campaign above, may add more). A
# sweep (:mod:`gonio.campaign.sweep`, the Python side of ``gonio sweep``) runs one campaign
# per grid point, each into its own folder ``tasks/<id>``, and gathers a results table.
plans = {"A": [10, 40, 70], "B": [10, 25, 40, 55, 70]}
spec = spec_from_dict(
    {
        "name": "two-plans",
        "task": "campaign",
        "materials": ["rolled_brass"],
        "seeds": [0],
        "settings": {"theta_i_deg": list(plans.values())},
        "fixed": {"rotations_deg": [0, 90]},
        "raw": "keep",  # (a sweep keeps no raw frames unless asked: their side-cars are read below)
    }
)
sweep = run_sweep(spec, work / "sweep", plot=False)
for row in sweep.rows:
    err = row["max_rel_err"]
    print(f"θi {row['theta_i_deg']}: {row['n_samples']} samples, max |rel. error| {err:.2e}")


# %%
# Each task's folder is a complete campaign folder, with its ``summary.json`` (and budget)
# and, as the spec asked (``"raw": "keep"``), its raw frames. The time a plan costs on the
# real instrument is estimated by
# :func:`gonio.simulator.lbl_timing.estimate_run_time`: the source arm's moves and settling,
# each frame's exposure and read-out, the iris changes between the frames of a bracket, and
# the manual steps (swapping the standard, the empty holder and the sample, rotating the
# sample by hand), with the ``"modern"`` build's assumed speeds. The frames of each capture
# are read from the side-cars the campaign wrote (the automatic bracket decides how many a
# capture needs, and at which f-stops: the iris is changed wherever the next frame's stop
# differs from the one set).
def bracket_exposures(folder: Path, plan: campaign.Plan) -> dict:
    """``{(kind, θi, rotation): [(exposure_s, f_number), ...]}`` of every capture, from its
    side-cars."""
    out = {}
    for th in plan.theta_i_deg:
        groups = [("standard", None), ("background", None)]
        groups += [("measured", r) for r in plan.rotations_deg]
        for kind, rot in groups:
            key = group_key(th, None if kind != "measured" else rot)
            cars = sorted((folder / "raw" / key).glob(f"{kind}_*.json"))
            metas = [json.loads(c.read_text()) for c in cars]
            out[(kind, th, rot)] = [(m["exposure_s"], m["f_number"]) for m in metas]
    return out


costs = {}
tasks_dir = work / "sweep" / "tasks"
for label, row in zip(plans, sweep.rows, strict=True):
    folder = tasks_dir / row["task_id"]
    summ = json.loads((folder / "summary.json").read_text())
    p = campaign.Plan.from_dict(summ["plan"])
    est = estimate_run_time(
        p.theta_i_deg, p.rotations_deg, bracket_exposures(folder, p), TIMINGS["modern"]
    )
    costs[label] = (summ, est)
    print(
        f"plan {label}: {len(p.theta_i_deg)} angles × {len(p.rotations_deg)} rotations,"
        f" {est['n_frames']:.0f} frames, {est['total_s'] / 60:.1f} min on the instrument"
        f" (moves {est['move_s']:.0f} s, exposures {est['exposure_s']:.1f} s,"
        f" iris {est['stop_change_s']:.1f} s, by hand {est['manual_s']:.0f} s);"
        f" simulated in {summ['timings_s']['total']:.1f} s"
    )

# %%
# What the extra angles buy, and what they cost: the expanded uncertainty ``U`` of every
# parameter relative to its value (the statistical part as a black tick), and the estimated
# instrument time by part.
params = list(s["fit"])
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), width_ratios=(2, 1))
x = np.arange(len(params))
for k, (label, (summ, est)) in enumerate(costs.items()):
    bb = summ["budget"]
    rel_u = [100 * bb["expanded"][q] / abs(bb["params"][q]) for q in params]
    rel_stat = [100 * 2 * bb["statistical"][q] / abs(bb["params"][q]) for q in params]
    xs = x + 0.38 * (k - 0.5)
    ax1.bar(xs, rel_u, 0.38, label=f"plan {label}: {len(plans[label])} angles")
    ax1.plot(xs, rel_stat, "k_", ms=14, mew=2, label="statistical part (k = 2)" if k else None)
    parts = {"move_s": "arm moves", "exposure_s": "exposures", "stop_change_s": "iris changes",
             "manual_s": "by hand"}  # fmt: skip
    bottom = 0.0
    for j, (part, name) in enumerate(parts.items()):
        ax2.bar(k, est[part] / 60, 0.6, bottom=bottom, color=f"C{j + 2}",
                label=name if k == 0 else None)  # fmt: skip
        bottom += est[part] / 60
ax1.set_xticks(x, params)
ax1.set_yscale("log")
ax1.set(ylabel="expanded uncertainty U / value (%)", title="uncertainty (k = 2)")
ax1.legend(fontsize=8)
ax2.set_xticks(range(len(costs)), [f"plan {lab}\n{len(plans[lab])} angles" for lab in costs])
top = max(est["total_s"] for _, est in costs.values()) / 60
ax2.set(ylim=(0, 1.5 * top), ylabel="estimated time on the instrument (min)",
        title="time (modern build)")  # fmt: skip
ax2.legend(fontsize=8, ncol=2, loc="upper center")
fig.suptitle("rolled brass, Ward fit, modern instrument: two plans")
fig.tight_layout()

# %%
# Read the two panels together: the ratio of the two plans' uncertainties and times.
(sa, ea), (sb, eb) = costs["A"], costs["B"]
for q in params:
    ratio = sb["budget"]["expanded"][q] / sa["budget"]["expanded"][q]
    share = sb["budget"]["statistical"][q] / sb["budget"]["combined"][q]
    print(f"{q:8s} U(B)/U(A) = {ratio:.2f}   statistical / u_c in plan B: {share:.2f}")
print(f"time B / time A = {eb['total_s'] / ea['total_s']:.2f}")

# %%
# Where the statistical part is a small share of ``u_c``, the budget is dominated by the
# instrument's systematic terms, which more angles do not average away: the extra angles
# then buy little, the cheaper plan is the one to prefer, and a better instrument (or a
# correction the laboratory does not yet make) is what lowers the uncertainty. A grid of
# plans over many instrument seeds, with its results table, is ``gonio sweep``
# (:doc:`../commands/sweep`); a single campaign from the command line is ``gonio campaign``
# (:doc:`../commands/campaign`), whose ``--preset``, ``--seed`` and ``--corrections``
# options set the fields used here.

# %%
# The temporary folder (the campaign, its raw frames and the sweep: tens of megabytes) is
# removed at the end, so that running the tutorial leaves nothing behind.
shutil.rmtree(work, ignore_errors=True)
print("removed", work.name, "->", work.exists())
