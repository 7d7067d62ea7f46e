"""The uncertainty budget of a campaign's fitted parameters, in the way of the GUM.

For every fitted parameter ``p`` the budget lists the statistical standard error of the fit
(a Type A evaluation) beside one contribution per imperfection of the instrument (Type B
evaluations): the parameter's *sensitivity* to the effect times the *standard uncertainty of
the effect after the laboratory's correction*. The contributions are combined by the law of
propagation of uncertainty (root sum of squares, with the correlations the propagation
itself produces) into the combined standard uncertainty ``u_c(p)``, and expanded with the
coverage factor ``k = 2`` into ``U(p) = k u_c(p)`` (GUM §5.1.2, §6.2.1, §6.3.3).

Sensitivities are linearised, not re-measured: an effect's perturbation ``δy`` of the reduced
samples (computed on the samples' own geometries from the effect's physical model) is pushed
through the fit's Jacobian ``J`` (weights ``W = diag(1/σ²)``)::

    δp = (Jᵀ W J)⁻¹ Jᵀ W δy

which is the first-order change of the weighted least-squares solution. One Jacobian serves
every effect, so a budget costs a few model evaluations over the samples instead of one
campaign per effect (:class:`Sensitivity`; ``tests/campaign/test_budget.py`` checks it
against brute-force re-fits).

Two kinds of contribution:

``systematic``
    One realisation shared by all samples (the standard's certificate, the mirror geometry):
    ``δy`` per unit of the effect; the contribution is ``u · δp`` (signed, so correlations
    between parameters follow from it).
``random``
    An independent realisation per group of samples (one capture's exposure, one lamp
    reading): ``δy_g`` per group; the covariance is ``u² Σ_g δp_g δp_gᵀ``.

References
----------
JCGM 100:2008, Evaluation of measurement data — Guide to the expression of uncertainty in
measurement (GUM), §4.2-4.3 (Type A and B), §5.1-5.2 (law of propagation, correlated input
quantities), §6 (expanded uncertainty).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "COVERAGE_FACTOR",
    "Budget",
    "Perturbation",
    "Sensitivity",
    "Term",
    "budget_table",
    "build_budget",
    "effect_u",
]

#: GUM coverage factor of the expanded uncertainty (about 95 % for a normal distribution)
COVERAGE_FACTOR = 2.0

KINDS = ("systematic", "random")


# ----------------------------------------------------------------------------- sensitivity
class Sensitivity:
    """The fit's linear response to a change of the sample values.

    Parameters
    ----------
    result : FitResult
        The fit (:func:`gonio.fit.fit`); its model, free parameters and residual kind.
    samples : BRDFSamples
        The samples it was fitted to (same rows, same order).

    Notes
    -----
    With residuals ``r = s (f(p) − y)`` (``s = 1/σ`` for ``"absolute"`` and ``"relative"``
    with known σ, ``√cos θi / σ`` for ``"li_torrance"``) the Gauss-Newton step of a change
    ``δy`` is ``δp = (J_rᵀ J_r)⁻¹ J_rᵀ s δy`` with ``J_r = s ∂f/∂p``; for ``"log"``
    residuals ``s`` is ``y/σ`` and the model enters as ``log f``. ``∂f/∂p`` is a central
    difference over the samples (two model evaluations per free parameter).
    """

    def __init__(self, result: Any, samples: Any) -> None:
        from gonio.fit import predict

        self.names = list(result.free)
        self.result = result
        if len(samples) != result.n_samples + result.n_excluded:
            raise ValueError(
                f"samples has {len(samples)} rows but the fit used "
                f"{result.n_samples + result.n_excluded}"
            )
        y = samples.value
        sig = samples.sigma if samples.has_sigma else np.ones_like(y)
        sig = np.where(sig > 0, sig, np.inf)
        kind = result.residual
        if kind in ("absolute", "relative"):
            s = 1.0 / sig
        elif kind == "li_torrance":
            s = np.sqrt(np.clip(np.cos(samples.theta_i), 0.0, None)) / sig
        elif kind == "log":
            s = np.where(y > 0, 1.0 / sig, 0.0)
        else:
            raise ValueError(f"residual {kind!r} has no linear response")
        f0 = predict(result.model, samples)
        cols = []
        for k in self.names:
            cols.append(self._column(result, samples, k, predict))
        jf = np.stack(cols, axis=1) if cols else np.zeros((len(y), 0))
        if kind == "log":
            jf = jf / np.maximum(f0, 1e-300)[:, None] * np.where(y > 0, y, 0.0)[:, None]
        jr = s[:, None] * jf
        jtj = jr.T @ jr
        self._gain = np.linalg.pinv(jtj) @ (jr.T * s[None, :])  # (n_free, n)
        self.f0 = f0

    @staticmethod
    def _column(result: Any, samples: Any, name: str, predict: Any) -> NDArray[np.float64]:
        from gonio.fit.core import _rebuild

        flat = dict(result.params)
        v = flat[name]
        lo, hi = result.bounds.get(name, (-math.inf, math.inf))
        h = 1e-5 * max(abs(v), 1e-6)
        up, dn = min(v + h, hi), max(v - h, lo)
        fu = predict(_rebuild(result.model, {**flat, name: up}), samples)
        fd = predict(_rebuild(result.model, {**flat, name: dn}), samples)
        return (fu - fd) / (up - dn)

    @property
    def gain(self) -> NDArray[np.float64]:
        """``(Jᵀ W J)⁻¹ Jᵀ W``, shape ``(n_free, n_samples)``."""
        return self._gain

    def shift(self, dy: ArrayLike) -> NDArray[np.float64]:
        """``δp`` of a change ``dy`` of every sample value (n_free,)."""
        d = np.asarray(dy, dtype=np.float64)
        if d.shape != (self._gain.shape[1],):
            raise ValueError(f"dy must have shape ({self._gain.shape[1]},), got {d.shape}")
        return self._gain @ d

    def shift_groups(self, dy: ArrayLike, groups: ArrayLike) -> NDArray[np.float64]:
        """``δp`` of each group's share of ``dy`` alone: shape ``(n_groups, n_free)``.

        ``groups`` holds a non-negative group index per sample (e.g. its capture).
        """
        d = np.asarray(dy, dtype=np.float64)
        g = np.asarray(groups)
        if g.shape != d.shape or (g.size and g.min() < 0):
            raise ValueError("groups must be non-negative indices, one per sample")
        n_g = int(g.max()) + 1 if g.size else 0
        out = np.zeros((n_g, len(self.names)))
        for j in range(len(self.names)):
            out[:, j] = np.bincount(g, weights=self._gain[j] * d, minlength=n_g)
        return out


# ----------------------------------------------------------------------------- terms
@dataclass(frozen=True)
class Perturbation:
    """An effect's change of the reduced samples per unit of the effect.

    Parameters
    ----------
    name : str
        The effect (e.g. ``"standard_certificate"``).
    u : float
        Standard uncertainty of the effect after correction, in ``unit`` (>= 0).
    unit : str
    dy : ndarray (n_samples,)
        Change of each sample value (sr⁻¹) per unit of the effect.
    kind : {"systematic", "random"}
    groups : ndarray of int, optional
        For ``"random"``: the group (independent realisation) of each sample.
    note : str
        Where ``u`` comes from (certificate, calibration, specification).
    corrected : bool
        Whether the laboratory corrected the effect (``u`` is then what remains).
    row : str, optional
        The budget's row it is reported in (None: a row of its own): the realisations of
        one Monte Carlo term (each with its own share of ``u``) share a row, whose
        contribution is their root sum of squares and whose ``u`` theirs.
    """

    name: str
    u: float
    unit: str
    dy: NDArray[np.float64]
    kind: str = "systematic"
    groups: NDArray[np.int64] | None = None
    note: str = ""
    corrected: bool = True
    row: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind {self.kind!r}; expected one of {KINDS}")
        if not (math.isfinite(self.u) and self.u >= 0):
            raise ValueError(f"u of {self.name!r} must be finite and >= 0, got {self.u!r}")
        if self.kind == "random" and self.groups is None:
            raise ValueError(f"random perturbation {self.name!r} needs groups")


@dataclass(frozen=True)
class Term:
    """One line of the budget: an effect's standard-uncertainty contribution per parameter."""

    name: str
    u: float
    unit: str
    kind: str
    contribution: dict[str, float]
    note: str = ""
    corrected: bool = True

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "u": self.u,
            "unit": self.unit,
            "kind": self.kind,
            "corrected": self.corrected,
            "note": self.note,
            "contribution": dict(self.contribution),
        }


@dataclass
class Budget:
    """The budget of one fit: statistical error, terms, combined and expanded uncertainty.

    Attributes
    ----------
    params : dict
        Fitted value of each free parameter.
    statistical : dict
        The fit's standard error (Type A).
    terms : list of Term
    combined : dict
        ``u_c``: root of the diagonal of the combined covariance.
    expanded : dict
        ``U = k u_c``.
    k : float
        Coverage factor.
    correlation : ndarray
        Correlation matrix of the combined covariance (parameters in ``params`` order).
    """

    params: dict[str, float]
    statistical: dict[str, float]
    terms: list[Term]
    combined: dict[str, float]
    expanded: dict[str, float]
    k: float = COVERAGE_FACTOR
    correlation: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (the ``budget`` entry of a campaign's ``summary.json``); an
        undetermined parameter's infinite uncertainties (and NaN correlations) are ``None``."""
        from gonio.campaign.determined import finite

        return finite(
            {
                "method": f"GUM (JCGM 100:2008) linearised propagation, k = {self.k:g}",
                "k": self.k,
                "params": dict(self.params),
                "statistical": dict(self.statistical),
                "terms": {t.name: t.to_dict() for t in self.terms},
                "combined": dict(self.combined),
                "expanded": dict(self.expanded),
                "correlation": {
                    "params": list(self.params),
                    "matrix": np.round(self.correlation, 6).tolist(),
                },
            }
        )


def build_budget(
    result: Any,
    samples: Any,
    perturbations: Sequence[Perturbation] = (),
    *,
    sensitivity: Sensitivity | None = None,
    k: float = COVERAGE_FACTOR,
) -> Budget:
    """Combine the fit's statistical covariance with every effect's propagated contribution.

    Parameters
    ----------
    result : FitResult
    samples : BRDFSamples
        The fitted samples.
    perturbations : sequence of Perturbation
    sensitivity : Sensitivity, optional
        Reused if given (it holds the Jacobian).
    k : float
        Coverage factor (> 0).

    Returns
    -------
    Budget
    """
    if not (math.isfinite(k) and k > 0):
        raise ValueError(f"k must be a finite positive coverage factor, got {k!r}")
    names = list(result.free)
    stat_cov = np.asarray(result.covariance, dtype=np.float64)
    if stat_cov.shape != (len(names), len(names)):
        raise ValueError(f"fit covariance has shape {stat_cov.shape}, expected {len(names)}^2")
    stat_cov = np.where(np.isfinite(stat_cov), stat_cov, 0.0)
    cov = stat_cov.copy()
    sens = sensitivity
    terms: list[Term] = []
    for p in perturbations:
        if sens is None:
            sens = Sensitivity(result, samples)
        if p.dy.shape != (len(samples),):
            raise ValueError(
                f"perturbation {p.name!r}: dy has shape {p.dy.shape}, expected ({len(samples)},)"
            )
        if p.kind == "systematic":
            c = p.u * sens.shift(p.dy)
            cov_t = np.outer(c, c)
            contrib = c
        else:
            dp = p.u * sens.shift_groups(p.dy, p.groups)
            cov_t = dp.T @ dp
            contrib = np.sqrt(np.diag(cov_t))
        cov += cov_t
        terms.append(
            Term(p.name if p.row is None else p.row, float(p.u), p.unit, p.kind,
                 {n: float(abs(c)) for n, c in zip(names, contrib)}, p.note, p.corrected)
        )  # fmt: skip
    terms = _rows(terms)
    stat = {n: float(result.stderr[n]) for n in names}
    uc = {n: float(math.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
    for n in names:  # an unidentifiable parameter stays unbounded
        if not math.isfinite(stat[n]):
            uc[n] = math.inf
    d = np.sqrt(np.maximum(np.diag(cov), 0.0))
    dd = np.where(d > 0, d, 1.0)
    corr = cov / np.outer(dd, dd)
    return Budget(
        params={n: float(result.params[n]) for n in names},
        statistical=stat,
        terms=terms,
        combined=uc,
        expanded={n: k * v for n, v in uc.items()},
        k=float(k),
        correlation=corr,
    )


def _rows(terms: list[Term]) -> list[Term]:
    """Terms of one name merged into one row (in the place of the first): ``u`` and each
    contribution the root sum of squares (the realisations of a Monte Carlo term,
    :attr:`Perturbation.row`)."""
    out: dict[str, Term] = {}
    for t in terms:
        got = out.get(t.name)
        if got is None:
            out[t.name] = t
            continue
        out[t.name] = dataclasses.replace(
            got, u=math.hypot(got.u, t.u),
            contribution={n: math.hypot(v, t.contribution[n]) for n, v in got.contribution.items()},
        )  # fmt: skip
    return list(out.values())


def budget_table(budget: Mapping[str, Any]) -> str:
    """The printed budget: one row per source, one column per parameter (relative, %).

    Every row but the last is a standard uncertainty (k = 1); the last is the expanded
    uncertainty ``U = k u_c``. An undetermined parameter (its uncertainty ``None`` or not
    finite) reads "undetermined"."""
    from gonio.console import format_table

    params = budget["params"]
    names = list(params)

    def rel(v: float | None, n: str) -> str:
        if v is None or not math.isfinite(v):
            return "undetermined"
        p = params[n]
        return f"{100 * v / abs(p):.3g}%" if p else f"{v:.3g}"

    rows = [("statistical (fit)", "", *[rel(budget["statistical"][n], n) for n in names])]
    for tname, t in budget["terms"].items():
        tag = effect_u(t["u"], t["unit"]) + ("" if t.get("corrected", True) else " (uncorr.)")
        rows.append((tname, tag, *[rel(t["contribution"][n], n) for n in names]))
    rows.append(("combined u_c (k=1)", "", *[rel(budget["combined"][n], n) for n in names]))
    k = budget.get("k", COVERAGE_FACTOR)
    rows.append((f"expanded U (k={k:g})", "", *[rel(budget["expanded"][n], n) for n in names]))
    return format_table(("source (u: k=1)", "u (effect)", *names), rows)


def effect_u(u: float, unit: str) -> str:
    """An effect's standard uncertainty with a readable unit: a relative one (unit ``"1"``)
    in per cent, angles in mrad, a variance of angle (``"rad²"``) as its root in mrad,
    others as given."""
    if unit in ("1", ""):
        return f"{100 * u:.3g} %"
    if unit == "1/h":
        return f"{100 * u:.3g} %/h"
    if unit == "rad":
        return f"{1e3 * u:.3g} mrad"
    if unit in ("rad²", "rad^2"):
        return f"({1e3 * math.sqrt(u):.3g} mrad)²"
    if unit == "σ":
        return f"{u:.3g} σ (calibration)"
    return f"{u:.3g} {unit}"
