"""What a campaign can and cannot determine, said plainly.

Three checks that make "undetermined" an answer instead of a crash or a silent number:

* before any capture, :func:`check_plan` asks whether the plan's geometries separate the
  fitted model's parameters (:func:`gonio.fit.identify.unseparated`, the fit's own rank
  test at the model's start values): a plan that cannot separate what a full hemispherical
  plan separates is refused (:class:`PlanError`, naming the parameters); a model whose
  parameters no geometry separates (a sum of two Lambert terms) is run, with a warning;
* after the fit, :func:`undetermined` names each parameter the data did not determine
  (infinite statistical error or budget) with the reason, which the summary keeps
  (``summary["undetermined"]``, ``null`` for its uncertainty) and the report prints;
* :func:`finite` turns every non-finite float of a summary into ``None`` (JSON ``null``):
  never ``inf`` in a file.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "PlanError",
    "budget_warnings",
    "check_plan",
    "cornell_preflight",
    "finite",
    "fit_status",
    "hemisphere_geometries",
    "lbl_preflight",
    "undetermined",
]


class PlanError(ValueError):
    """A plan whose geometries cannot determine the fitted model (refused before capture)."""


# ----------------------------------------------------------------------------- geometries
def hemisphere_geometries(
    theta_i_deg: Sequence[float], rotations_deg: Sequence[float] = (0.0,),
    theta_o_max_deg: float = 80.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Nominal ``(wi, wo)`` of an imaging instrument that sees the whole reflected
    hemisphere at each incidence angle and sample rotation: ``wo`` on a 5° .. ``theta_o_max``
    grid of 6 polar by 12 azimuthal directions plus the normal; ``wi`` at azimuth ``-rot``
    in the sample frame (the sample turned by ``rot``)."""
    from gonio.geometry import to_vector

    to = np.radians(np.linspace(5.0, theta_o_max_deg, 6))
    po = np.radians(np.arange(0.0, 360.0, 30.0))
    tt, pp = np.meshgrid(to, po, indexing="ij")
    wo = np.concatenate([to_vector(tt.ravel(), pp.ravel()), [[0.0, 0.0, 1.0]]])
    wis, wos = [], []
    for th in theta_i_deg:
        for rot in rotations_deg:
            wi = to_vector(math.radians(th), -math.radians(rot))
            wis.append(np.broadcast_to(wi, wo.shape))
            wos.append(wo)
    return np.concatenate(wis), np.concatenate(wos)


#: The reference plan a model's own identifiability is judged on: incidence 0-80° in 10°
#: steps, four sample rotations, the whole hemisphere seen at each.
_FULL_THETA_I = tuple(range(0, 81, 10))
_FULL_ROTATIONS = (0.0, 45.0, 90.0, 135.0)


def check_plan(
    model: Any, wi: NDArray[np.float64], wo: NDArray[np.float64], *,
    fixed: Iterable[str] | Mapping[str, Any] | None = None,
    wavelength_nm: Any = None, what: str = "the plan",
) -> list[str]:  # fmt: skip
    """Refuse a plan whose geometries cannot separate the parameters of ``model``.

    Parameters
    ----------
    model : str or BRDF
        The model to be fitted, at its start values.
    wi, wo : ndarray (n, 3)
        The plan's geometries (sample frame).
    fixed : names or mapping, optional
        Parameters the fit will hold.
    wavelength_nm : array_like, optional
        The bands of a spectral instrument (each geometry is one row per band).
    what : str
        How the plan is named in the messages.

    Returns
    -------
    list of str
        Warnings: the parameters that no geometry separates (the model's own degeneracy;
        the campaign runs and reports them as undetermined).

    Raises
    ------
    PlanError
        The plan separates none of the free parameters (those it leaves unseparated
        that a full hemispherical plan separates, with the model's own degeneracies, are
        all of them); a plan that leaves some unseparated runs, with a warning.
    """
    from gonio.fit.identify import distinct_geometries, free_parameters, unseparated

    kw = {"fixed": fixed, "wavelength_nm": wavelength_nm}

    def both(wi: NDArray, wo: NDArray) -> list[str]:
        # at the start values and at a jittered copy: a degeneracy of the start alone (a
        # symmetric start, a zero amplitude) is not one of the model or the plan
        first = unseparated(model, wi, wo, **kw)
        return (
            [n for n in unseparated(model, wi, wo, jitter=0.3, **kw) if n in first] if first else []
        )

    try:
        in_plan = both(wi, wo)
        if not in_plan:
            return []
        wi_f, wo_f = hemisphere_geometries(_FULL_THETA_I, _FULL_ROTATIONS)
        in_model = both(wi_f, wo_f)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return [f"whether {what} determines the model is not known: {exc}"]
    extra = [n for n in in_plan if n not in in_model]
    out = []
    if extra and len(extra) + len(in_model) >= len(free_parameters(model, fixed)):
        n_geo = distinct_geometries(wi, wo)
        raise PlanError(
            f"{what} cannot determine the model at all: its {n_geo} distinct geometr"
            f"{'y does' if n_geo == 1 else 'ies do'} not separate {_names(extra)}, which a "
            "hemispherical plan separates; measure more (different) geometries"
        )
    if extra:
        out.append(
            f"{what} does not separate {_names(extra)} (a hemispherical plan would): "
            "they will be reported as undetermined"
        )
    if in_model:
        out.append(
            f"the model's parameters {_names(in_model)} are not separated by any geometry "
            "(only a combination of them is determined): they will be reported as undetermined"
        )
    return out


def _names(names: Sequence[str], most: int = 6) -> str:
    """A short list of parameter names (per-band names counted, not listed)."""
    base: dict[str, int] = {}
    for n in names:
        b = n.split("[", 1)[0] if n.endswith("]") else n
        base[b] = base.get(b, 0) + 1
    parts = [b if c == 1 else f"{b} ({c} bands)" for b, c in base.items()]
    return ", ".join(parts[:most]) + (f" and {len(parts) - most} more" if len(parts) > most else "")


# ----------------------------------------------------------------------------- after the fit
def undetermined(result: Any, budget: Mapping[str, Any] | None = None) -> dict[str, str]:
    """Each free parameter the data did not determine, with the reason.

    Parameters
    ----------
    result : FitResult
    budget : mapping, optional
        The budget's dict (:meth:`gonio.campaign.budget.Budget.to_dict`): a parameter whose
        combined uncertainty is not finite is undetermined too.

    Returns
    -------
    dict
        Parameter -> reason (empty when every free parameter is determined).
    """
    out: dict[str, str] = {}
    stat_inf = [k for k in result.free if not math.isfinite(result.stderr.get(k, math.nan))]
    zero_at_bound = [k for k in result.at_bounds if abs(result.params.get(k, 1.0)) < 1e-12]
    for k in stat_inf:
        others = [n for n in stat_inf if n != k]
        if zero_at_bound and k not in zero_at_bound:
            why = (f"the samples do not constrain it: {_names(zero_at_bound)} fitted to 0 "
                   "(at its bound), which removes its effect")  # fmt: skip
        elif others:
            why = (
                f"the samples do not constrain it: only a combination with {_names(others)} "
                "is determined (the fit's Jacobian is rank-deficient)"
            )
        else:
            why = "the samples do not constrain it (the fit's Jacobian is rank-deficient)"
        out[k] = why
    if budget is not None:
        for k, v in (budget.get("combined") or {}).items():
            if k not in out and (v is None or not math.isfinite(v)):
                out[k] = "its uncertainty budget is not finite"
    return out


def finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (and numpy float) replaced by ``None``, through
    dicts, lists and tuples: what a JSON file may hold."""
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite(v) for v in obj]
    return obj


def fit_status(result: Any) -> str:
    """How the fit ended, in words: ``"converged"`` only when the optimiser stopped on a
    tolerance *and* the misfit is one the samples' σ can explain; a χ²/dof above
    :data:`gonio.fit.core.CHI2_NOTE` says the model does not describe the data within
    their noise."""
    from gonio.fit.core import CHI2_NOTE

    if not result.converged:
        return "NOT converged"
    c = result.chi2_dof
    if math.isfinite(c) and c > CHI2_NOTE and any("chi2/dof" in w for w in result.warnings):
        return (
            f"converged, but chi2/dof = {c:.3g}: the model does not describe the data within "
            "their noise (a model that cannot describe them, instrument effects the "
            "reduction left, or a local minimum); the budget holds only the effects it "
            "names, so its U may not cover this misfit's cause: read it as a lower bound"
        )
    return "converged"


def budget_warnings(budget: Mapping[str, Any], undetermined: Mapping[str, str]) -> list[str]:
    """The budget's warnings: each parameter whose expanded uncertainty is as large as its
    value (bounded, not measured). Undetermined parameters are reported on their own."""
    out = []
    k = budget.get("k", 2.0)
    for n, u in budget.get("expanded", {}).items():
        v = budget["params"].get(n)
        if n in undetermined or u is None or v is None:
            continue
        if u >= abs(v):
            out.append(f"{n}: U (k={k:g}) = {u:.3g} is as large as its value {v:.3g}: "
                       "the data bound it rather than measure it")  # fmt: skip
    return out


# ----------------------------------------------------------------------------- the campaigns
def lbl_preflight(
    plan: Any, template: Any, fit_kw: Mapping[str, Any], truth: Any = None, instrument: Any = None
) -> list[str]:
    """Before an LBL campaign's captures: :func:`check_plan` on the hemisphere seen at each
    of the plan's incidence angles and sample rotations (:func:`hemisphere_geometries`), for
    the model the campaign fits (``template`` and ``fit_kw`` of
    :func:`gonio.campaign.lbl._fit_setup`), then the material's lobe (``truth``) against
    the instrument's angular resolution
    (:func:`gonio.campaign.resolution.resolution_warnings`). Returns the warnings."""
    from gonio.brdf._jit import interpreted
    from gonio.campaign.resolution import lbl_resolution, resolution_warnings

    wi, wo = hemisphere_geometries(plan.theta_i_deg, plan.rotations_deg)
    angles = ", ".join(f"{a:g}" for a in plan.theta_i_deg)
    # a few thousand evaluations: numpy, no numba import on the campaign's serial path
    with interpreted():
        out = check_plan(template, wi, wo, fixed=fit_kw.get("fixed"),
                         what=f"the plan (incidence {angles} deg)")  # fmt: skip
        res = lbl_resolution(plan, instrument) if truth is not None else None
        if res is not None:
            theta = math.radians(float(np.median(plan.theta_i_deg)))
            out += resolution_warnings(truth, template, res, theta)
    return out


def cornell_preflight(plan: Any, material: str, config: Any) -> list[str]:
    """:func:`check_plan` for a Cornell plan (its geometries through the kinematics) and the
    Li-Torrance fit of ``material`` with σ held (the fewest free parameters the campaign
    fits). The per-band coefficients enter the model linearly, one set per band over the
    same geometries, so the bands' grey mean is checked: a plan that separates it
    separates every band."""
    from gonio import brdf
    from gonio.campaign.cornell import _truth_and_template
    from gonio.simulator.cornell import forward

    _truth, template, fixed, *_ = _truth_and_template(material, "sigma_fixed")
    grey = {k: (float(np.mean(v)) if isinstance(v, np.ndarray) else v)
            for k, v in template.params.items()}  # fmt: skip
    wi, wo = forward(plan.angles, config.kinematics)
    grey_model = brdf.create("li_torrance", **grey)
    try:
        return check_plan(grey_model, wi, wo, fixed=list(fixed), what="the Cornell plan")
    except PlanError:
        # the grey mean is sufficient, not necessary: tau enters each band through tau /
        # lambda, so the bands together can separate what one band cannot; a plan the
        # bands separate runs, any other is refused as the grey check said
        from gonio.simulator.cornell import BANDS_NM

        try:
            if not check_plan(template, wi, wo, fixed=list(fixed), wavelength_nm=BANDS_NM):
                return []
        except PlanError:
            pass
        raise
