"""A campaign's report: the summary (truth against fit), the text table, plots, Radiance.

The summary is the one place where the simulator's truth and the campaign's result meet
(``docs/architecture.md``, Truth and knowledge): everything before it works from the captures.
"""

from __future__ import annotations

import math
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign.plan import Plan
from gonio.samples import BRDFSamples

__all__ = [
    "PLOTS",
    "CampaignResult",
    "add_budget",
    "draw",
    "draw_budget",
    "draw_preview",
    "summarise",
    "summary_table",
    "write_report",
]


@dataclass
class CampaignResult:
    """What :func:`run` returns: the plan, the samples, the fits and the summary."""

    plan: Plan
    out: Path | None
    samples: BRDFSamples
    fit: Any
    compare: dict[str, Any]
    summary: dict[str, Any]
    timings_s: dict[str, float] = field(default_factory=dict)


#: The campaign's plots (``OUT/plots/<name>.png``).
PLOTS = ("incidence_plane", "hemisphere", "residuals")


def draw(name: str, samples: BRDFSamples, model: Any, folder: Path, title: str) -> None:
    from gonio import plots

    path = folder / f"{name}.png"
    if name == "hemisphere":
        plots.plot_hemisphere(samples, path, title=title, max_panels=12)
    elif name == "incidence_plane":
        plots.plot_incidence_plane(samples, model, path, title=title)
    else:
        plots.plot_residuals(samples, model, path, title=title)


def draw_budget(name: str, budget: Mapping[str, Any], folder: Path, title: str) -> None:
    """``plots/budget.png``: the uncertainty budget (:func:`gonio.plots.budget.plot_budget`)."""
    from gonio.plots.budget import plot_budget

    plot_budget(budget, folder / f"{name}.png", title=title)


def draw_preview(
    name: str, truth: Any, result: Any, plan: Plan, info: Mapping[str, Any], folder: Path,
    title: str,
) -> None:  # fmt: skip
    """``plots/preview.png``: the truth and the fit rendered by Radiance on a sphere, the fit
    from the material written as ``material.rad`` (:func:`radiance`), and their difference
    (:func:`gonio.plots.preview.plot_preview`). A failure of the renderer (a Radiance
    program that exits with an error, a material it cannot read) costs the preview only:
    the campaign's measured results are written, and the reason is printed on stderr."""
    import sys

    from gonio.plots.preview import plot_preview

    try:
        plot_preview(truth, result.model, folder / f"{name}.png", title=title,
                     material_class=str(info.get("class") or "dielectric"),
                     fit_material=radiance(plan, info, result))  # fmt: skip
    except (OSError, RuntimeError, ValueError, subprocess.CalledProcessError) as exc:
        print(f"warning: plots/{name}.png not drawn: {type(exc).__name__}: {exc}",
              file=sys.stderr)  # fmt: skip


def add_budget(summary: dict[str, Any], budget: Any) -> None:
    """The budget (``summary["budget"]``) and, for each fitted parameter with a truth,
    whether the truth lies within the expanded uncertainty (``within_expanded``; ``None``
    for an undetermined parameter) — the budget's check against the truth. A parameter
    whose budget is not finite joins ``summary["undetermined"]``, and the budget's
    warnings join ``summary["warnings"]``."""
    from gonio.campaign.determined import budget_warnings

    b = budget.to_dict()
    summary["budget"] = b
    truth = _compared(summary)
    within = {}
    for k, u in b["expanded"].items():
        if k in truth:
            within[k] = None if u is None else bool(abs(summary["fit"][k] - truth[k]) <= u)
    summary["within_expanded"] = within
    und = summary.setdefault("undetermined", {})
    for k, u in b["combined"].items():
        if u is None and k not in und:
            und[k] = "its uncertainty budget is not finite"
    summary.setdefault("warnings", []).extend(budget_warnings(b, und))


def _compared(summary: Mapping[str, Any]) -> dict[str, float]:
    """What the fit is compared with: the truth's parameters for the truth's own model,
    else the reference's (the model's best approximation of the truth), else nothing."""
    if summary.get("model") == summary.get("truth_model"):
        return dict(summary.get("truth", {}))
    return dict((summary.get("reference") or {}).get("params") or {})


def _truth_params(truth: Any) -> dict[str, float]:
    """Float parameters of the truth; per-band arrays by their band mean (what a grey
    camera sees of a spectral coefficient that enters the BRDF linearly)."""
    out = {}
    for k, v in truth.params.items():
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, int | float) and math.isfinite(v):
            out[k] = float(v)
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f" and v.ndim == 1:
            out[k] = float(np.mean(v))
    return out


def _lobe_truth(truth: Any, model: Any) -> dict[str, float]:
    """The true Lafortune lobes under the fitted model's parameter names
    (``lobes[i].c_x`` ...), each fitted lobe matched to the true lobe of the same rank of
    exponent ``n`` (a sum of lobes has no order of its own); empty unless both are Lafortune
    models with as many lobes."""
    if truth.name != "lafortune" or model.name != "lafortune":
        return {}
    t, f = list(truth.params["lobes"]), list(model.params["lobes"])
    if len(t) != len(f):
        return {}
    t_order = sorted(range(len(t)), key=lambda i: float(t[i][3]))
    f_order = sorted(range(len(f)), key=lambda i: float(f[i][3]))
    out = {}
    for ti, fi in zip(t_order, f_order):
        for j, nm in enumerate(("c_x", "c_y", "c_z", "n")):
            out[f"lobes[{fi}].{nm}"] = float(t[ti][j])
    return out


def summarise(plan, info, truth, result, compare, samples, n_pixels, n_loaded) -> dict:
    """The summary of a campaign: the fit beside the truth, the undetermined parameters
    with their reasons (``undetermined``), the fit's warnings (``warnings``) and how the
    fit ended (``fit_status``); every non-finite number is ``None``."""
    from gonio.campaign.determined import finite, fit_status, undetermined

    all_truth = {**_truth_params(truth), **_lobe_truth(truth, result.model)}
    truth_p = all_truth if plan.model == truth.name else {}
    fitp = {k: float(v) for k, v in result.params.items()}
    stderr = {k: (float(v) if math.isfinite(v) else None) for k, v in result.stderr.items()}
    rel = {}
    within = {}
    for k, tv in truth_p.items():
        if k in fitp and k in result.free:
            rel[k] = abs(fitp[k] - tv) / abs(tv) if tv != 0 else abs(fitp[k])
            s = result.stderr[k]
            within[k] = bool(abs(fitp[k] - tv) <= 3 * s) if math.isfinite(s) else None
    comp = {}
    for k, v in compare.items():
        if isinstance(v, Exception):
            comp[k] = {"error": str(v)}
        else:
            comp[k] = {
                "rms": v.rms,
                "chi2_dof": v.chi2_dof,
                "converged": v.converged,
                "params": v.params,
            }
    extra = {}
    if truth.name == "lafortune" and result.model.name == "lafortune":
        # lobes are an object parameter: list them (sorted by exponent n) side by side
        def lobes(m: Any) -> list[list[float]]:
            return sorted(([float(x) for x in lb[:4]] for lb in m.params["lobes"]),
                          key=lambda lb: lb[3])  # fmt: skip

        extra["lobes"] = {"truth": lobes(truth), "fit": lobes(result.model)}
    return finite(
        {
            **extra,
            "material": plan.material,
            "class": info.get("class"),
            "model": plan.model,
            "truth_model": truth.name,
            "truth": all_truth,
            "fit": fitp,
            "stderr": stderr,
            "relative_error": rel,
            "within_3_sigma": within,
            "rms": result.rms,
            "rms_relative": result.rms_relative,
            "chi2_dof": result.chi2_dof if math.isfinite(result.chi2_dof) else None,
            "converged": result.converged,
            "n_samples": len(samples),
            "n_pixels": n_pixels,
            "n_captures": {
                "incidence_angles": len(plan.theta_i_deg),
                "rotations": len(plan.rotations_deg),
                "resumed_groups": n_loaded,
            },
            "compare": comp,
            "seed": plan.seed,
            "noise": plan.noise,
            "plan": plan.to_dict(),
            "files": {"samples": "samples.csv", "fit": "fit.json"},
            "fit_status": fit_status(result),
            "undetermined": undetermined(result),
            "warnings": list(getattr(result, "warnings", [])),
            **_reference(plan, truth, result, samples),
        }
    )


def _reference(plan: Plan, truth: Any, result: Any, samples: BRDFSamples) -> dict[str, Any]:
    """For a model other than the truth's family, ``{"reference": ...}``: the model's best
    approximation of the truth on the campaign's directions and weights
    (:func:`gonio.campaign.reference.model_reference`), each parameter's relative error
    against it; nothing when the model is the truth's."""
    if plan.model == truth.name:
        return {}
    from gonio.campaign.reference import model_reference

    try:
        ref = model_reference(truth, result, samples)
    except ValueError as exc:  # a truth the model cannot be fitted to: said, not raised
        return {"reference": {"error": str(exc)}}
    ref["relative_error"] = {
        k: abs(result.params[k] - v) / abs(v) if v else abs(result.params[k])
        for k, v in ref["params"].items()
    }
    return {"reference": ref}


def radiance(plan: Plan, info: Mapping[str, Any], result: Any) -> Any:
    """The Radiance material that renders the fit as fitted
    (:func:`gonio.io.radiance.model_material`: ``plastic2``/``metal2`` for ``ward_gmd``, a
    ``BRTDfunc`` + ``.cal`` for the other translatable models), or ``None`` for a model
    Radiance cannot render exactly."""
    from gonio.io.radiance import model_material

    params = ", ".join(f"{k} {v:.5g}" for k, v in result.params.items())
    try:
        return model_material(
            result.model,
            str(info.get("class", "dielectric")),
            name=f"gonio_{plan.material}",
            comment=f"gonio campaign fit of {plan.material} ({plan.model}, seed {plan.seed})\n"
            + params,
        )
    except ValueError:
        return None


#: The parameter table's columns (the expanded uncertainty's is inserted after the fourth).
_COLUMNS = ("param", "truth", "fit", "rel.err", "|err|/U", "stderr", "pull (err/stderr)")


def summary_table(summary: Mapping[str, Any]) -> str:
    """The short text report: true vs fitted parameters, each error against the expanded
    uncertainty U (within U or not) beside the statistical pull, the undetermined
    parameters and every warning, counts, the budget, stage times."""
    from gonio.console import format_table

    rows = []
    truth = _compared(summary)
    ref = summary.get("reference") or {}
    rel_err = summary["relative_error"] or ref.get("relative_error") or {}
    und = summary.get("undetermined") or {}
    big_u = (summary.get("budget") or {}).get("expanded", {})
    k = (summary.get("budget") or {}).get("k", 2.0)
    for name, v in summary["fit"].items():
        t = truth.get(name)
        s = summary["stderr"].get(name)
        rel = rel_err.get(name)
        u = big_u.get(name)
        if name in und:
            u_txt, vs_u = "undetermined", ""
        elif u is None:
            u_txt, vs_u = "", ""
        else:
            u_txt = f"{u:.2g}"
            vs_u = (
                ""
                if t is None or u <= 0
                else (f"{abs(v - t) / u:.2f} " + ("within" if abs(v - t) <= u else "OUTSIDE"))
            )
        rows.append(
            (
                name,
                "" if t is None else f"{t:.5g}",
                f"{v:.5g}",
                "" if rel is None else f"{100 * rel:.2f}%",
                u_txt,
                vs_u,
                "" if s is None else f"{s:.2g}",
                "" if t is None or s in (None, 0) else f"{(v - t) / s:+.2f}",
            )
        )
    status = summary.get("fit_status") or ("converged" if summary["converged"]
                                           else "NOT converged")  # fmt: skip
    lines = [
        f"{summary['material']} fitted with {summary['model']}: {status}, "
        f"{summary['n_samples']} samples from {summary['n_pixels']} pixels, "
        f"rms {summary['rms']:.4g} sr^-1",
        format_table(
            _COLUMNS[:1]
            + (("reference",) if ref.get("params") else _COLUMNS[1:2])
            + _COLUMNS[2:4]
            + (f"U (k={k:g})",)
            + _COLUMNS[4:],
            rows,
        ),
    ]
    if ref.get("params"):
        ina = ref["inadequacy"]["fit"]
        lines.append(
            f"reference: {summary['model']}'s best approximation of the truth "
            f"({summary.get('truth_model')}) on these directions and weights; the fitted "
            f"BRDF against the true one: rms {100 * (ina['rms_relative'] or 0):.3g} %, worst "
            f"{100 * (ina['worst_relative'] or 0):.3g} % over {ina['n_directions']} directions"
        )
    elif ref.get("error"):
        lines.append(f"reference: none ({ref['error']})")
    for name, why in und.items():
        lines.append(f"undetermined: {name}: {why}")
    for w in summary.get("warnings") or []:
        lines.append(f"warning: {w}")
    if summary.get("compare"):
        crow = [(summary["model"], f"{summary['rms']:.4g}", summary.get("chi2_dof") or "")]
        for name, v in summary["compare"].items():
            crow.append(
                (
                    name,
                    f"{v['rms']:.4g}" if "rms" in v else v.get("error", ""),
                    v.get("chi2_dof") or "",
                )
            )
        lines.append(format_table(("model", "rms (sr^-1)", "chi2/dof"), crow))
    if summary.get("budget"):
        from gonio.campaign.budget import budget_table

        b = summary["budget"]
        lines.append(
            "uncertainty budget, relative to each fitted value: every row a standard "
            f"uncertainty (k = 1) but the last, the expanded uncertainty U = {b['k']:g} u_c:"
        )
        lines.append(budget_table(b))
    tm = summary.get("timings_s", {})
    lines.append("time (s): " + ", ".join(f"{k} {v:.2f}" for k, v in tm.items()))
    return "\n".join(lines)


def write_report(
    outp: Path | None,
    plan: Plan,
    info: Mapping[str, Any],
    result: Any,
    compare: Mapping[str, Any],
    summary: dict[str, Any],
) -> None:
    """Write ``fit.json`` (the fit and the compared models) and, for a fit Radiance can
    render, ``material.rad`` (recorded in ``summary["files"]``); nothing without ``outp``."""
    if outp is None:
        return
    from gonio.campaign.folder import write_json

    fitd = result.to_dict()
    fitd["compare"] = {
        k: (v.to_dict() if not isinstance(v, Exception) else {"error": str(v)})
        for k, v in compare.items()
    }
    write_json(outp / "fit.json", fitd)
    mat = radiance(plan, info, result)
    if mat is not None:
        from gonio.io.radiance import write_material_files

        write_material_files(outp, mat)
        summary["files"]["radiance"] = "material.rad"
        if mat.cal_name is not None:
            summary["files"]["radiance_cal"] = mat.cal_name
