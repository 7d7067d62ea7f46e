"""Fitting reflectance models to BRDF sample tables (``gonio.fit``).

:func:`fit` adjusts the parameters of any registered model, of a sum of models
(``"lambert + ward"``) or of a template model instance to a :class:`~gonio.samples.BRDFSamples`
table with :func:`scipy.optimize.least_squares` (trust-region reflective) under the bounds
that ``brdf.spec`` declares, and returns a :class:`FitResult` with the fitted model, parameter
standard errors from the Jacobian, RMS and χ²/dof, and a ``converged`` flag.

Parameter vector
----------------
Every fitted quantity is one named float (a *flat* parameter):

- a scalar float parameter keeps its name (``"rho_d"``; in a sum ``"ward.rho_d"``);
- element ``k`` of a spectral (per-band) parameter is ``"name[k]"`` (``"k_dd[3]"``);
- a grey model fitted to spectral data with ``per_band`` parameters gets one copy of each
  such parameter per data band, also named ``"name[k]"`` (``k`` indexes
  :attr:`FitResult.wavelengths_nm`); the other parameters are shared by all bands, the way
  Li and Torrance fit one σ, τ and per-band k's (Li and Torrance 2005, §5);
- object-kind parameters (Lafortune's lobes) are flattened by a codec registered with
  :func:`register_codec` (the model class may instead define the class methods
  ``fit_encode(params) -> list[(name, value, lower, upper)]`` and
  ``fit_decode(params, flat) -> params``); object parameters without a codec are held fixed.

Residuals
---------
``residual=`` chooses the misfit of one sample (``f`` model, ``y`` measured, ``σ`` its
standard error when the table has one; the vector handed to the optimiser):

- ``"absolute"``: ``(f − y) / σ`` (``f − y`` without σ);
- ``"relative"``: ``(f − y) / max(|y|, floor)``; with σ it is ``((f − y)/y) / (σ/y)``,
  identical to ``"absolute"`` — the standard error of a relative difference is σ/y;
- ``"log"``: ``ln f − ln y`` divided by ``σ/y`` (the propagated error of ``ln y``); samples
  with ``y ≤ 0`` cannot enter a log misfit and are excluded (counted in
  :attr:`FitResult.n_excluded`);
- ``"li_torrance"``: ``sqrt(cos θi) (f − y) [/σ]``, so that the sum of squares is Li and
  Torrance's cosine-weighted L2 error, eq. 15 of Li and Torrance 2005. Eq. 15 as printed
  puts the sum over reflection directions *inside* ``|·|²``, which would let errors of
  opposite sign cancel; the text calls it "an L2 norm weighted with the cosine of the
  incidence angle", which is what is implemented (one squared term per sample).

Standard errors come from ``cov = (JᵀJ)⁻¹`` of the weighted residuals at the solution
(central differences). Without σ the covariance is scaled by χ²/dof (the scatter about the
fit sets the error). With σ it is scaled by ``max(1, χ²/dof)`` (the Birge ratio): honest σ
give χ²/dof ≈ 1 and no change, while a misfit or underestimated σ widen the errors instead
of hiding behind them. ``absolute_sigma=True`` never scales (``curve_fit`` semantics),
``False`` always scales by χ²/dof. Parameters the data do not constrain (a rank-deficient
Jacobian) get an infinite standard error, reported as ``None`` in JSON, and
``identifiable=False``. :attr:`FitResult.cov_scale` is the factor applied.

Linear parameters
-----------------
``linear=["k_dd", ...]`` names parameters that enter the model as pure scale factors; they
are then solved exactly (bounded linear least squares, :mod:`gonio.fit.linear`) for every
trial of the others (variable projection): the same minimum and standard errors as the joint
fit with far fewer model evaluations (a Cornell Li-Torrance fit with 93 per-band k's: 0.9 s
instead of 74 s). Spectral models are evaluated once per distinct direction pair.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
   §4: least-squares fitting of eq. 5a to the reduced data.
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   §5, eq. 15: the cosine-weighted fitting error, one roughness shared by all bands.
.. [Lafortune1997] E. P. F. Lafortune, S.-C. Foo, K. E. Torrance and D. P. Greenberg, "Non-linear
   approximation of reflectance functions", Proc. SIGGRAPH '97, 117-126, 1997.
   https://doi.org/10.1145/258734.258801
   §5: non-linear (Levenberg-Marquardt) fitting of lobe sums.

Examples
--------
>>> import numpy as np
>>> from gonio import brdf, fit
>>> from gonio.samples import BRDFSamples
>>> true = brdf.create("ward", rho_d=0.1, rho_s=0.2, alpha_x=0.08, alpha_y=0.08)
>>> t = np.radians(np.linspace(0, 80, 17))
>>> ti, to, po = np.meshgrid(t, t, [0.0, np.pi / 2, np.pi], indexing="ij")
>>> s = BRDFSamples(ti.ravel(), 0 * ti.ravel(), to.ravel(), po.ravel(),
...                 np.zeros(ti.size), np.full(ti.size, np.nan))
>>> s.value = true(s.wi, s.wo)
>>> r = fit.fit(s, "ward")
>>> r.converged, round(r.params["alpha_x"], 6)
(True, 0.08)
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gonio import brdf as _brdf
from gonio._validate import check_scalar
from gonio.brdf.base import BRDF
from gonio.brdf.composite import Sum
from gonio.fit.linear import solve_bounded
from gonio.hints import keyword
from gonio.samples import BRDFSamples

__all__ = [
    "RESIDUALS",
    "FitResult",
    "fit",
    "initial_guess",
    "parse_model",
    "predict",
    "register_codec",
    "register_guesser",
]

RESIDUALS = ("absolute", "relative", "log", "li_torrance")

#: Parameters held at their template values unless named in ``free=`` (model name -> names):
#: band centres, refractive indices and the like are properties of the set-up, not of the
#: fit (Li and Torrance fix n = 1.5, Li and Torrance 2005, §5).
DEFAULT_FIXED: dict[str, tuple[str, ...]] = {
    "lafortune": ("r_m",),  # the mirror fraction only feeds delta(), invisible to samples
    "li_torrance": ("wavelength_nm", "n_ior", "f0", "d_omega_i"),
    "metal_neumann": ("wavelength_nm",),
    "plastic_neumann": ("wavelength_nm",),
}
_ALWAYS_FIXED = ("wavelength_nm", "wavelengths_nm")

#: Rows used to screen the starts of a multi-start fit (all rows polish the best one).
SCREEN_ROWS = 20000

#: Extra random starts by model name when ``n_starts`` is not given (models whose misfit
#: has several local minima: lobe sums).
DEFAULT_STARTS: dict[str, int] = {"lafortune": 6}

Entry = tuple[str, float, float, float]  # flat name, value, lower, upper


# ----------------------------------------------------------------------------- codecs
_CODECS: dict[str, tuple[Callable, Callable]] = {}
_GUESSERS: dict[str, Callable] = {}


def register_codec(
    model_name: str,
    encode: Callable[[Mapping[str, Any]], list[Entry]],
    decode: Callable[[Mapping[str, Any], Mapping[str, float]], dict[str, Any]],
) -> None:
    """Register how a model's object-kind parameters become flat floats and back.

    Parameters
    ----------
    model_name : str
        Registered model name.
    encode : callable
        ``encode(params) -> [(flat_name, value, lower, upper), ...]`` for the parameters the
        codec handles (float parameters it does not list are handled by the default rule).
    decode : callable
        ``decode(params, flat) -> params``: a full parameter dict for the model, given the
        template's ``params`` and ``flat`` (flat name -> value, all entries of ``encode``).
    """
    _CODECS[model_name] = (encode, decode)


def register_guesser(
    model_name: str, guesser: Callable[[BRDFSamples, Mapping[str, Any]], dict[str, Any]]
) -> None:
    """Register a data-driven initial guess ``guesser(samples, params) -> params`` for a model."""
    _GUESSERS[model_name] = guesser


def _codec_for(model: BRDF) -> tuple[Callable, Callable] | None:
    cls = type(model)
    if hasattr(cls, "fit_encode") and hasattr(cls, "fit_decode"):
        return cls.fit_encode, cls.fit_decode
    return _CODECS.get(model.name)


def _encode(model: BRDF) -> list[Entry]:
    """Flat entries of one (non-sum) model."""
    codec = _codec_for(model)
    out: list[Entry] = []
    covered: set[str] = set()
    if codec is not None:
        for name, v, lo, hi in codec[0](model.params):
            out.append((name, float(v), float(lo), float(hi)))
            covered.add(name.split("[", 1)[0].split(".", 1)[0])
    for p in type(model).PARAMS:
        if p.name in covered or p.kind != "float":
            continue
        v = model.params[p.name]
        if v is None:  # optional float left at "None" (e.g. "the maximum"): held fixed
            continue
        arr = np.asarray(v, dtype=np.float64)
        if arr.ndim == 0:
            out.append((p.name, float(arr), p.lower, p.upper))
        else:
            out.extend((f"{p.name}[{k}]", float(x), p.lower, p.upper) for k, x in enumerate(arr))
    return out


def _decode(model: BRDF, flat: Mapping[str, float]) -> dict[str, Any]:
    """Parameters of one (non-sum) model from its flat values (missing ones: the template's)."""
    params = dict(model.params)
    codec = _codec_for(model)
    covered: set[str] = set()
    if codec is not None:
        entries = codec[0](model.params)
        names = {e[0] for e in entries}
        sub = {k: flat.get(k, e[1]) for e in entries for k in [e[0]]}
        params = dict(codec[1](params, sub))
        covered = {n.split("[", 1)[0].split(".", 1)[0] for n in names}
    for p in type(model).PARAMS:
        if p.name in covered or p.kind != "float" or params[p.name] is None:
            continue
        v = params[p.name]
        arr = np.asarray(v, dtype=np.float64)
        if arr.ndim == 0:
            if p.name in flat:
                params[p.name] = float(flat[p.name])
        else:
            new = arr.copy()
            for k in range(arr.size):
                key = f"{p.name}[{k}]"
                if key in flat:
                    new[k] = flat[key]
            params[p.name] = new
    return params


def _components(model: BRDF) -> list[tuple[str, BRDF]]:
    if isinstance(model, Sum):
        return list(zip(model.prefixes, model.models))
    return [("", model)]


def _model_entries(model: BRDF) -> list[Entry]:
    out = []
    for pre, m in _components(model):
        for name, v, lo, hi in _encode(m):
            out.append((f"{pre}.{name}" if pre else name, v, lo, hi))
    return out


def _rebuild(model: BRDF, flat: Mapping[str, float]) -> BRDF:
    comps = _components(model)
    if not isinstance(model, Sum):
        return type(model)(**_decode(model, flat))
    new = []
    for pre, m in comps:
        sub = {k[len(pre) + 1 :]: v for k, v in flat.items() if k.startswith(pre + ".")}
        new.append(type(m)(**_decode(m, sub)))
    return Sum(new)


def _base_name(flat_name: str) -> str:
    return flat_name.split("[", 1)[0]


# ----------------------------------------------------------------------------- model parsing
def parse_model(model: str | BRDF, **params: Any) -> BRDF:
    """A model instance from a registered name, a sum ``"lambert + ward"`` or an instance.

    ``params`` (for a name) are passed to the constructor; in a sum use ``"ward.rho_d"``-style
    keys. An unknown name raises ``ValueError`` listing the registered models.
    """
    if isinstance(model, BRDF):
        if params:
            return _with_params(model, params)
        return model
    if not isinstance(model, str) or not model.strip():
        raise ValueError(f"model must be a model name, a sum 'a + b' or a BRDF, got {model!r}")
    parts = [p.strip() for p in model.split("+")]
    if any(not p for p in parts):
        raise ValueError(f"model {model!r} has an empty term; expected e.g. 'lambert + ward'")
    if len(parts) == 1:
        return _brdf.create(parts[0], **params)
    s = Sum([_brdf.create(p) for p in parts])
    return s.with_params(**params) if params else s


def _with_params(model: BRDF, params: Mapping[str, Any]) -> BRDF:
    if isinstance(model, Sum):
        return model.with_params(**params)
    return type(model)(**{**model.params, **params})


def _label(model: BRDF) -> str:
    return model.label if isinstance(model, Sum) else model.name


# ----------------------------------------------------------------------------- data
@dataclass
class _Data:
    wi: NDArray[np.float64]
    wo: NDArray[np.float64]
    y: NDArray[np.float64]
    sigma: NDArray[np.float64] | None
    cos_i: NDArray[np.float64]
    band: NDArray[np.intp] | None  # index into wavelengths, per row
    wavelengths: NDArray[np.float64] | None
    geometry: tuple[NDArray, NDArray, NDArray] | None = None  # see _unique_geometry


def _unique_geometry(d: _Data) -> tuple[NDArray, NDArray, NDArray]:
    """``(wi_u, wo_u, inverse)``: the distinct direction pairs of ``d`` (cached).

    A spectral model returns every band per direction pair, and spectral tables repeat each
    geometry once per band: evaluating the distinct pairs only is exact and n_bands times
    cheaper.
    """
    if d.geometry is None or d.geometry[2].shape[0] != d.wi.shape[0]:
        key = np.concatenate([d.wi, d.wo], axis=1)
        _u, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inv = np.asarray(inv).reshape(-1)
        d.geometry = (d.wi[first], d.wo[first], inv)
    return d.geometry


def _prepare(samples: BRDFSamples) -> _Data:
    if not isinstance(samples, BRDFSamples):
        raise ValueError(f"samples must be a BRDFSamples table, got {type(samples).__name__}")
    if len(samples) == 0:
        raise ValueError("samples is empty; expected at least one row to fit")
    sigma = samples.sigma if samples.has_sigma else None
    if sigma is not None and (sigma <= 0).any():
        n = int(np.count_nonzero(sigma <= 0))
        raise ValueError(
            f"samples.sigma has {n} zero standard error(s); expected σ > 0 for every row "
            "(or an all-NaN column when errors are unknown)"
        )
    band = wl = None
    if samples.wavelength_nm is not None:
        wl, band = np.unique(samples.wavelength_nm, return_inverse=True)
    return _Data(samples.wi, samples.wo, samples.value, sigma, np.cos(samples.theta_i), band, wl)


# ----------------------------------------------------------------------------- layout
@dataclass
class _Layout:
    """How the flat parameter vector maps onto one model per band (or one model)."""

    template: BRDF
    n_groups: int  # 1, or number of data bands for a grey model with per-band params
    entries: list[Entry]  # all flat entries (free and fixed) in order
    per_band: set[str]  # base names replicated per band (grey model, spectral data)
    band_index: NDArray[np.intp] | None  # model band for each data band (spectral model)

    def group_flat(self, values: Mapping[str, float], g: int) -> dict[str, float]:
        out = {}
        for name, *_ in self.entries:
            base = _base_name(name)
            if base in self.per_band:
                if name == f"{base}[{g}]":
                    out[base] = values[name]
            else:
                out[name] = values[name]
        return out

    def models(self, values: Mapping[str, float]) -> list[BRDF]:
        return [_rebuild(self.template, self.group_flat(values, g)) for g in range(self.n_groups)]


def _make_layout(template: BRDF, data: _Data, per_band: Sequence[str] | None) -> _Layout:
    base_entries = _model_entries(template)
    nb_model = template.n_bands
    if nb_model is not None:
        if data.wavelengths is None:
            raise ValueError(
                f"model {_label(template)!r} is spectral ({nb_model} bands) but the samples "
                "have no wavelength_nm column; expected spectral samples"
            )
        mwl = np.asarray(template.wavelengths_nm, dtype=np.float64)
        idx = np.abs(data.wavelengths[:, None] - mwl[None, :]).argmin(axis=1)
        off = np.abs(mwl[idx] - data.wavelengths)
        if (off > 0.5).any():
            bad = data.wavelengths[off > 0.5]
            raise ValueError(
                f"samples wavelength(s) {bad.tolist()} nm are not bands of the model "
                f"(bands {mwl.tolist()} nm); expected matches within 0.5 nm"
            )
        if per_band:
            raise ValueError(
                f"per_band={list(per_band)!r} applies to grey models; model "
                f"{_label(template)!r} already has per-band parameters"
            )
        return _Layout(template, 1, base_entries, set(), idx)
    if data.wavelengths is None or len(data.wavelengths) == 1:
        if per_band:
            raise ValueError(f"per_band={list(per_band)!r} needs samples with several wavelengths")
        return _Layout(template, 1, base_entries, set(), None)
    names = {_base_name(e[0]) for e in base_entries}
    if per_band is None:
        per_band = [n for n in names if n.rpartition(".")[2].startswith("rho")]
    unknown = sorted(set(per_band) - names)
    if unknown:
        raise ValueError(
            f"per_band names {unknown} are not parameters; expected some of {sorted(names)}"
        )
    nb = len(data.wavelengths)
    entries: list[Entry] = []
    for name, v, lo, hi in base_entries:
        if name in per_band:
            entries.extend((f"{name}[{g}]", v, lo, hi) for g in range(nb))
        else:
            entries.append((name, v, lo, hi))
    return _Layout(template, nb, entries, set(per_band), None)


def _predict_layout(layout: _Layout, data: _Data, values: Mapping[str, float]) -> NDArray:
    models = layout.models(values)
    if layout.band_index is not None:  # spectral model
        wi_u, wo_u, inv = _unique_geometry(data)
        v = np.asarray(models[0].evaluate_unchecked(wi_u, wo_u))
        col = layout.band_index[data.band]
        out = v[inv, col]
    elif layout.n_groups == 1:
        out = np.asarray(models[0].evaluate_unchecked(data.wi, data.wo), dtype=np.float64)
        if out.ndim != 1:
            raise ValueError(f"model {_label(layout.template)!r} returned shape {out.shape}")
    else:
        out = np.empty(data.y.shape)
        for g, m in enumerate(models):
            sel = data.band == g
            out[sel] = m.evaluate_unchecked(data.wi[sel], data.wo[sel])
    if not np.isfinite(out).all():
        raise ValueError(
            f"model {_label(layout.template)!r} returned non-finite values for parameters "
            f"{dict(values)}"
        )
    return out


def predict(model: BRDF, samples: BRDFSamples) -> NDArray[np.float64]:
    """Model values at the sample geometries (the band of each row for spectral data)."""
    data = _prepare(samples)
    if model.n_bands is None:
        return np.asarray(model(data.wi, data.wo), dtype=np.float64)
    layout = _make_layout(model, data, None)
    return _predict_layout(layout, data, {e[0]: e[1] for e in layout.entries})


# ----------------------------------------------------------------------------- residuals
class _Residual:
    def __init__(self, kind: str, data: _Data) -> None:
        if kind not in RESIDUALS:
            raise ValueError(f"unknown residual {kind!r}; expected one of {list(RESIDUALS)}")
        self.kind = kind
        y = data.y
        self.mask = np.ones(y.shape, bool)
        if kind == "log":
            self.mask = y > 0
            if not self.mask.any():
                raise ValueError("residual 'log' needs positive sample values; none are > 0")
        ym = y[self.mask]
        self.y = ym
        sig = None if data.sigma is None else data.sigma[self.mask]
        if kind == "absolute":
            self.scale = 1.0 / sig if sig is not None else np.ones_like(ym)
        elif kind == "relative":
            floor = 1e-6 * max(float(np.max(np.abs(ym))), 1e-300)
            self.scale = 1.0 / (sig if sig is not None else np.maximum(np.abs(ym), floor))
        elif kind == "li_torrance":
            w = np.sqrt(np.clip(data.cos_i[self.mask], 0.0, None))
            self.scale = w / sig if sig is not None else w
        else:  # log
            self.scale = ym / sig if sig is not None else np.ones_like(ym)
            self.logy = np.log(ym)
            self.tiny = 1e-12 * float(np.max(ym))

    def __call__(self, f: NDArray) -> NDArray:
        f = f[self.mask]
        if self.kind == "log":
            return (np.log(np.maximum(f, self.tiny)) - self.logy) * self.scale
        return (f - self.y) * self.scale


# ----------------------------------------------------------------------------- result
@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    model : BRDF
        The fitted model (for a grey model fitted per band: the model of the first band;
        all are in ``models``).
    models : list of BRDF
        One fitted model per data band when parameters were fitted per band, else ``[model]``.
    model_name : str
        ``"ward"`` or ``"lambert + ward"``.
    params, stderr : dict
        Flat parameter name -> fitted value / standard error (``inf`` when the data do not
        constrain it). Fixed parameters appear in ``params`` with ``stderr`` 0.
    free, fixed : list of str
        Names of the fitted and the held parameters.
    converged : bool
        The optimiser stopped on a tolerance (not on the evaluation budget) and every value
        is finite.
    identifiable : bool
        The Jacobian has full rank at the solution.
    rms : float
        RMS of ``f − y`` in sr⁻¹ over the fitted samples.
    rms_relative : float
        RMS of ``(f − y)/y`` over samples with ``y > 0``.
    chi2, dof, chi2_dof : float, int, float
        Sum of squared weighted residuals, degrees of freedom (samples − free parameters),
        and their ratio.
    warnings : list of str
        The notes appended to ``message`` (a misfit its σ cannot explain, a rank-deficient
        Jacobian, repeated rows), one sentence each; not in :meth:`to_dict` (they are in
        ``message``).
    """

    model: BRDF
    models: list[BRDF]
    model_name: str
    residual: str
    params: dict[str, float]
    stderr: dict[str, float]
    free: list[str]
    fixed: list[str]
    bounds: dict[str, tuple[float, float]]
    converged: bool
    identifiable: bool
    message: str
    rms: float
    rms_relative: float
    chi2: float
    dof: int
    chi2_dof: float
    n_samples: int
    n_excluded: int
    nfev: int
    n_starts: int
    absolute_sigma: bool
    covariance: NDArray[np.float64]
    cov_scale: float = 1.0
    at_bounds: list[str] = field(default_factory=list)
    wavelengths_nm: list[float] | None = None
    time_s: float = 0.0
    warnings: list[str] = field(default_factory=list)

    @property
    def relative_stderr(self) -> dict[str, float]:
        """``stderr / |value|`` per flat parameter (inf for a zero value)."""
        return {
            k: (self.stderr[k] / abs(v) if v != 0 else math.inf) for k, v in self.params.items()
        }

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (infinite standard errors become ``None``)."""

        def fin(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "model": self.model_name,
            "residual": self.residual,
            "params": {k: float(v) for k, v in self.params.items()},
            "stderr": {k: fin(v) for k, v in self.stderr.items()},
            "free": list(self.free),
            "fixed": list(self.fixed),
            "bounds": {k: [fin(lo), fin(hi)] for k, (lo, hi) in self.bounds.items()},
            "at_bounds": list(self.at_bounds),
            "converged": bool(self.converged),
            "identifiable": bool(self.identifiable),
            "message": self.message,
            "rms": float(self.rms),
            "rms_relative": fin(self.rms_relative),
            "chi2": float(self.chi2),
            "dof": int(self.dof),
            "chi2_dof": fin(self.chi2_dof),
            "n_samples": int(self.n_samples),
            "n_excluded": int(self.n_excluded),
            "nfev": int(self.nfev),
            "n_starts": int(self.n_starts),
            "absolute_sigma": bool(self.absolute_sigma),
            "cov_scale": float(self.cov_scale),
            "wavelengths_nm": self.wavelengths_nm,
            "time_s": float(self.time_s),
        }

    def summary(self) -> str:
        """A few lines of text: parameters ± standard errors and the fit statistics."""
        lines = [
            f"model {self.model_name} ({self.residual} residual): "
            f"{'converged' if self.converged else 'NOT converged'}, {self.message}"
        ]
        for k, v in self.params.items():
            s = self.stderr[k]
            tag = " (fixed)" if k in self.fixed else (" (at bound)" if k in self.at_bounds else "")
            lines.append(f"  {k} = {v:.6g} ± {s:.2g}{tag}")
        lines.append(
            f"  rms {self.rms:.4g} sr^-1, chi2/dof {self.chi2_dof:.4g}, n = {self.n_samples}"
        )
        return "\n".join(lines)


# ----------------------------------------------------------------------------- guesses
def initial_guess(samples: BRDFSamples, model: str | BRDF) -> BRDF:
    """A starting model from the data: diffuse level from a low percentile, lobe from the peak.

    Uses a guesser registered for the model (see :func:`register_guesser`; built in for
    ``lambert``, ``ward``, ``ward_approx``, ``oren_nayar`` and ``lafortune``); other models
    start from their template values. For a sum, the diffuse level goes to the first
    diffuse-like term.
    """
    template = parse_model(model)
    data = _prepare(samples)
    return _guess(template, samples, data)


def _guess(template: BRDF, samples: BRDFSamples, data: _Data) -> BRDF:
    comps = _components(template)
    if len(comps) == 1:
        g = _GUESSERS.get(template.name)
        if g is None:
            return template
        try:
            return type(template)(**g(samples, template.params))
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return template
    # a sum: the diffuse level goes to the first term that has a diffuse guess, lobes to all
    new = []
    diffuse_done = False
    for _, m in comps:
        g = _GUESSERS.get(m.name)
        if g is None:
            new.append(m)
            continue
        try:
            p = g(samples, m.params)
            if diffuse_done:
                for k in ("rho_d", "rho", "k_d"):
                    if k in p and k in m.params and isinstance(p[k], float):
                        p[k] = _spec_lower(m, k)
            new.append(type(m)(**p))
            diffuse_done = diffuse_done or any(k in p for k in ("rho_d", "rho", "k_d"))
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            new.append(m)
    return Sum(new)


def _spec_lower(m: BRDF, k: str) -> float:
    lo = type(m).spec().params[k].lower
    return lo if math.isfinite(lo) else 0.0


def _clip(v: float, m_params: Mapping[str, Any], cls_name: str, k: str) -> float:
    p = _brdf.spec(cls_name).params[k]
    lo = p.lower if math.isfinite(p.lower) else -1e300
    hi = p.upper if math.isfinite(p.upper) else 1e300
    return float(min(max(v, lo), hi))


def _diffuse_level(samples: BRDFSamples, q: float = 5.0) -> float:
    """Low percentile of the cosine-free values: the diffuse BRDF level (sr⁻¹)."""
    return max(float(np.percentile(samples.value, q)), 0.0)


def _guess_lambert(samples: BRDFSamples, params: Mapping[str, Any]) -> dict[str, Any]:
    return {
        **params,
        "rho": _clip(np.pi * float(np.median(samples.value)), params, "lambert", "rho"),
    }


def _guess_ward(samples: BRDFSamples, params: Mapping[str, Any], name: str = "ward") -> dict:
    """Ward eq. 5a linearised: ``ln((f − ρd/π) sqrt(cos θi cos θo)) = ln A − a X − b Y``.

    ``X = (h_x/h_z)², Y = (h_y/h_z)²`` (h = wi + wo), ``a = 1/αx², b = 1/αy²``,
    ``A = ρs/(4π αx αy)``; a weighted linear least-squares fit over the samples above a tenth
    of the peak excess gives all four parameters (Ward 1992, eq. 5a).
    """
    y = samples.value
    level = _diffuse_level(samples)
    out = dict(params)
    out["rho_d"] = _clip(np.pi * level, params, name, "rho_d")
    wi, wo = samples.wi, samples.wo
    h = wi + wo
    ci, co = wi[:, 2], wo[:, 2]
    ex = y - level
    ok = (ci > 1e-3) & (co > 1e-3) & (ex > 0)
    if ok.sum() < 3:
        return out
    peak = float(ex[ok].max())
    sel = ok & (ex > 0.1 * peak)
    if sel.sum() < 3:
        return out
    X = (h[sel, 0] / h[sel, 2]) ** 2
    Y = (h[sel, 1] / h[sel, 2]) ** 2
    t = np.log(ex[sel] * np.sqrt(ci[sel] * co[sel]))
    w = ex[sel] / peak
    sx, sy = float(np.ptp(X)), float(np.ptp(Y))
    scale = max(sx, sy, 1e-12)
    aniso = min(sx, sy) > 0.05 * scale
    if aniso:
        A = np.stack([np.ones_like(X), -X, -Y], axis=1)
    else:
        A = np.stack([np.ones_like(X), -(X + Y)], axis=1)
    coef, *_ = np.linalg.lstsq(A * w[:, None], t * w, rcond=None)
    a = coef[1]
    b = coef[2] if aniso else coef[1]
    if not (np.isfinite(coef).all() and a > 0 and b > 0):
        return out
    ax = _clip(1.0 / math.sqrt(a), params, name, "alpha_x")
    ay = _clip(1.0 / math.sqrt(b), params, name, "alpha_y")
    rho_s = math.exp(coef[0]) * 4.0 * math.pi * ax * ay
    out.update(alpha_x=ax, alpha_y=ay, rho_s=_clip(rho_s, params, name, "rho_s"))
    return out


def _guess_oren_nayar(samples: BRDFSamples, params: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(params)
    key = "rho" if "rho" in params else None
    if key is not None:
        out[key] = _clip(np.pi * float(np.median(samples.value)), params, "oren_nayar", key)
    return out


# ----------------------------------------------------------------------------- Lafortune
#: Bounds of the flattened Lafortune lobe coefficients (the model itself only bounds n).
LAFORTUNE_C_BOUNDS = (-5.0, 5.0)
LAFORTUNE_N_BOUNDS = (0.0, 500.0)


def _lafortune_encode(params: Mapping[str, Any]) -> list[Entry]:
    """``lobes[i].c_x, .c_y, .c_z, .n`` per lobe (Lafortune et al. 1997, eq. 8); p held."""
    out: list[Entry] = []
    lo, hi = LAFORTUNE_C_BOUNDS
    for i, lobe in enumerate(params["lobes"]):
        for j, nm in enumerate(("c_x", "c_y", "c_z")):
            out.append((f"lobes[{i}].{nm}", float(lobe[j]), lo, hi))
        out.append((f"lobes[{i}].n", float(lobe[3]), *LAFORTUNE_N_BOUNDS))
    return out


def _lafortune_decode(params: Mapping[str, Any], flat: Mapping[str, float]) -> dict[str, Any]:
    lobes = []
    for i, lobe in enumerate(params["lobes"]):
        p = float(lobe[4]) if len(lobe) > 4 else 0.0
        vals = [
            flat.get(f"lobes[{i}].{nm}", lobe[j]) for j, nm in enumerate(("c_x", "c_y", "c_z", "n"))
        ]
        lobes.append((*[float(v) for v in vals], p))
    return {**params, "lobes": tuple(lobes)}


def _lafortune_lobe(n: float, albedo: float, retro: bool = False) -> tuple[float, ...]:
    """A classical cosine lobe of exponent ``n`` and peak albedo (Lafortune §4.2, eq. 1)."""
    c = (max(albedo, 1e-6) * (n + 2.0) / (2.0 * math.pi)) ** (1.0 / n)
    return (c, c, c, n) if retro else (-c, -c, c, n)


def _guess_lafortune(samples: BRDFSamples, params: Mapping[str, Any]) -> dict[str, Any]:
    """Diffuse level from the low percentile; lobes: a specular one whose exponent matches
    the Ward-style width of the peak (n ≈ 2/α² for a cosine lobe about the mirror direction),
    further lobes broader forward and retro-reflective ones."""
    level = _diffuse_level(samples)
    ward = _guess_ward(samples, {"rho_d": 0.1, "rho_s": 0.05, "alpha_x": 0.1, "alpha_y": 0.1})
    a = math.sqrt(ward["alpha_x"] * ward["alpha_y"])
    n0 = min(max(2.0 / a**2, 1.0), LAFORTUNE_N_BOUNDS[1] / 2)
    lobes = []
    for i, lobe in enumerate(params["lobes"]):
        p = float(lobe[4]) if len(lobe) > 4 else 0.0
        if i == 0:
            new = _lafortune_lobe(n0, ward["rho_s"])
        elif i % 2 == 1:
            new = _lafortune_lobe(max(n0 / 8.0, 1.0), 0.05, retro=True)
        else:
            new = _lafortune_lobe(max(n0 / 4.0, 1.0), 0.05)
        lobes.append((*new, p))
    return {**params, "lobes": tuple(lobes), "rho_d": min(math.pi * level, 1.0)}


def _start_lafortune(
    params: Mapping[str, Any], rng: np.random.Generator, k: int = 0
) -> dict[str, Any]:
    """Random start number ``k``: one exponent drawn in each of equal log strata of
    [1, 200] (sorted, so the lobes span narrow to broad), and which lobes are
    retro-reflective cycles with ``k`` through no lobe, each single lobe, then each pair
    (Lafortune §4.2: a sum of forward and retro cosine lobes). Random retro choices (each
    lobe with probability 0.3) missed blue paint's retro lobe in all 6 starts for one
    noise draw (seed 0: chi2/dof 35, ρd 16 % off); the cycle puts a single retro lobe at
    each exponent rank in starts 1-3."""
    from itertools import combinations

    nl = len(params["lobes"])
    patterns: list[tuple[int, ...]] = [()]
    for r in range(1, nl + 1):
        patterns += list(combinations(range(nl), r))
    retro = set(patterns[k % len(patterns)])
    edges = np.linspace(0.0, math.log(200.0), nl + 1)
    ns = sorted(math.exp(rng.uniform(edges[i], edges[i + 1])) for i in range(nl))
    lobes = []
    for i, lobe in enumerate(params["lobes"]):
        p = float(lobe[4]) if len(lobe) > 4 else 0.0
        albedo = math.exp(rng.uniform(math.log(0.01), math.log(1.0)))
        lobes.append((*_lafortune_lobe(ns[i], albedo, retro=i in retro), p))
    return {**params, "lobes": tuple(lobes), "rho_d": float(rng.uniform(0.0, 0.5))}


register_codec("lafortune", _lafortune_encode, _lafortune_decode)
register_guesser("lafortune", _guess_lafortune)
_STARTERS: dict[str, Callable] = {"lafortune": _start_lafortune}

register_guesser("lambert", _guess_lambert)
register_guesser("ward", _guess_ward)
register_guesser("ward_approx", lambda s, p: _guess_ward(s, p, "ward_approx"))
register_guesser("oren_nayar", _guess_oren_nayar)


def _guess_exponent(model_name: str) -> Callable:
    """A guesser for a model whose lobe is a power ``n`` of a cosine (Phong, Blinn, the
    Neumann metals and plastics): ``n`` from a scan of 41 values from 0.5 to 10⁶ (log
    spaced), each scored by the weighted misfit of the model times its best scale factor
    (the amplitudes held at the template's values), over at most :data:`SCREEN_ROWS` rows.

    The template's ``n`` is a guess of the lobe's width that may be wrong by orders of
    magnitude; from ``n = 20`` the fit of a near-perfect mirror (Neumann's silver mirror,
    ``n = 5000``) went downhill to ``n = 0.33`` at χ²/dof 3·10⁶, from the scan's start to
    ``n = 4909`` at χ²/dof 40 (measured on a modern LBL campaign's samples)."""

    def guess(samples: BRDFSamples, params: Mapping[str, Any]) -> dict[str, Any]:
        rows = np.arange(len(samples))
        if rows.size > SCREEN_ROWS:
            rows = np.random.default_rng(0).choice(rows, SCREEN_ROWS, replace=False)
        sub = samples.subset(rows)
        y = sub.value
        w = 1.0 / sub.sigma**2 if sub.has_sigma else np.ones_like(y)
        best, best_n = math.inf, params["n"]
        for n in np.geomspace(0.5, 1e6, 41):
            try:
                f = predict(_brdf.create(model_name, **{**params, "n": float(n)}), sub)
            except (ValueError, FloatingPointError):
                continue
            fw = float(np.sum(w * f * f))
            if not (fw > 0 and np.isfinite(fw)):
                continue
            scale = float(np.sum(w * f * y)) / fw
            cost = float(np.sum(w * (scale * f - y) ** 2))
            if cost < best:
                best, best_n = cost, float(n)
        return {**params, "n": best_n}

    return guess


for _name in ("metal_neumann", "plastic_neumann", "phong", "blinn_phong", "phong_neumann",
              "blinn_neumann"):  # fmt: skip
    register_guesser(_name, _guess_exponent(_name))


def _random_start(
    entries: list[Entry], free_idx: list[int], x0: NDArray, rng: np.random.Generator
) -> NDArray:
    x = x0.copy()
    for j, i in enumerate(free_idx):
        _, v, lo, hi = entries[i]
        if math.isfinite(lo) and math.isfinite(hi):
            if lo > 0 and hi / lo > 50:
                x[j] = math.exp(rng.uniform(math.log(lo), math.log(hi)))
            else:
                x[j] = rng.uniform(lo, hi)
        else:
            span = max(abs(v), 1.0)
            x[j] = np.clip(v + span * rng.normal(), lo, hi)
    return x


# ----------------------------------------------------------------------------- the fit
def fit(
    samples: BRDFSamples,
    model: str | BRDF,
    *,
    residual: str = "absolute",
    fixed: Iterable[str] | Mapping[str, Any] | None = None,
    free: Iterable[str] | None = None,
    init: Mapping[str, float] | None = None,
    per_band: Sequence[str] | None = None,
    n_starts: int | None = None,
    rng: int | np.random.Generator | None = 0,
    absolute_sigma: bool | None = None,
    guess: bool = True,
    max_nfev: int | None = None,
    linear: Iterable[str] | None = None,
) -> FitResult:
    """Fit ``model`` to ``samples`` by bounded non-linear least squares.

    Parameters
    ----------
    samples : BRDFSamples
        The measured table (grey, or spectral with ``wavelength_nm``).
    model : str or BRDF
        A registered name, a sum ``"lambert + ward"``, or an instance used as template: its
        values are the start (unless ``guess``), and its non-fitted parameters (object
        parameters without a codec, band wavelengths) are kept.
    residual : {"absolute", "relative", "log", "li_torrance"}
        Misfit of one sample (module docstring); each weighted by 1/σ when σ is known.
    fixed : names or mapping, optional
        Parameters held constant: names (held at their start value) or name -> value. A base
        name fixes all its bands/elements.
    free : names, optional
        Parameters to fit although :data:`DEFAULT_FIXED` holds them by default.
    init : mapping, optional
        Start values (flat or base names) overriding the data-driven guess.
    per_band : sequence of str, optional
        For a grey model on spectral data: parameters fitted separately per band; default the
        reflectances (names starting ``rho``); the others are shared by all bands.
    n_starts : int, optional
        Extra random starts within the bounds (default :data:`DEFAULT_STARTS` per model, 0
        otherwise); the lowest-cost solution wins.
    rng : int, Generator or None
        Random state of the extra starts.
    absolute_sigma : bool, optional
        ``True``: σ absolute, covariance unscaled; ``False``: scaled by χ²/dof; default
        (``None``): ``max(1, χ²/dof)`` with σ, χ²/dof without (module docstring).
    guess : bool
        Start from :func:`initial_guess` (default) rather than the template's values.
    max_nfev : int, optional
        Evaluation budget per start (default ``100 · (n_free + 1)``).
    linear : names, optional
        Free parameters (flat or base names) on which the model depends linearly, such as
        Li-Torrance's ``k_dd``, ``k_udf``, ``k_uds``, ``k_fs`` (Li and Torrance 2005
        eq. 2-14). They are then solved exactly by bounded linear least squares for every
        trial of the other parameters (variable projection, :mod:`gonio.fit.linear`): the
        same minimum and the same standard errors (the Jacobian's linear columns are the
        basis itself), far fewer model evaluations. Linearity is checked at the start
        (``ValueError`` otherwise); not with ``residual="log"``.

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        Bad samples, an unknown model or residual, unknown parameter names, fewer samples than
        free parameters, or a model returning non-finite values.
    """
    t0 = time.perf_counter()
    p = _Problem(samples, model, residual, fixed=fixed, free=free, init=init,
                 per_band=per_band, guess=guess)  # fmt: skip
    starts = p.starts(n_starts, np.random.default_rng(rng))
    budget = max_nfev or 100 * (len(p.free_idx) + 1)
    p.fun_checked(p.x0)  # a model that cannot be evaluated at the start raises a clear error
    vp = p.varpro(linear)
    best, nfev = _minimise(p, starts, vp, budget)
    return _result(p, best, vp, nfev, len(starts), absolute_sigma, t0)


class _Problem:
    """One fit's problem: the data, the parameter layout, the free and fixed parameters with
    their start values and bounds, and the residual functions of the free parameters."""

    def __init__(
        self, samples: BRDFSamples, model: str | BRDF, residual: str, *, fixed: Any,
        free: Iterable[str] | None, init: Mapping[str, float] | None,
        per_band: Sequence[str] | None, guess: bool,
    ) -> None:  # fmt: skip
        self.samples = samples
        self.residual = residual
        self.per_band = per_band
        self.data = data = _prepare(samples)
        self.template = parse_model(model)
        self.res = _Residual(residual, data)
        self.start = _guess(self.template, samples, data) if guess else self.template
        self.layout = _make_layout(self.start, data, per_band)
        self.entries = list(self.layout.entries)
        self.names = [e[0] for e in self.entries]
        self.index = {n: i for i, n in enumerate(self.names)}
        self.values = np.array([e[1] for e in self.entries], dtype=np.float64)
        for key, v in (init or {}).items():  # start values: init overrides, then fixed
            for i in self.expand(key):
                self.values[i] = _as_float(v, key)
                lo_i, hi_i = self.entries[i][2], self.entries[i][3]
                if not lo_i <= self.values[i] <= hi_i:
                    raise ValueError(
                        f"init {self.names[i]} = {float(self.values[i])!r} is outside its "
                        f"bounds [{lo_i}, {hi_i}]"
                    )
        self.fixed_idx = self._fixed(fixed, free)
        self.lo = np.array([e[2] for e in self.entries])
        self.hi = np.array([e[3] for e in self.entries])
        self._inside_bounds()
        self.free_idx = [i for i in range(len(self.entries)) if i not in self.fixed_idx]
        self.n_used = int(self.res.mask.sum())
        if not self.free_idx:
            raise ValueError("every parameter is fixed; nothing to fit")
        if self.n_used <= len(self.free_idx):
            raise ValueError(
                f"samples has {self.n_used} usable rows for {len(self.free_idx)} free "
                "parameters; expected more rows than free parameters"
            )
        self.fun_checked, self.fun = self.objective(data, self.res)
        self.x0 = self.values[self.free_idx]
        self.lb, self.ub = self.lo[self.free_idx], self.hi[self.free_idx]
        # fixed variable scales from the start's magnitudes: x_scale="jac" rescales every
        # iteration and crawled along Lafortune's c-n valley (536 vs 100 evaluations)
        span = np.where(np.isfinite(self.ub - self.lb), self.ub - self.lb, np.inf)
        xscale = np.maximum(np.abs(self.x0), np.minimum(1e-2 * span, 1.0))
        self.xscale = np.where(xscale > 0, xscale, 1.0)

    def expand(self, key: str) -> list[int]:
        """Indices of a flat parameter name, or of every element of a base name."""
        if key in self.index:
            return [self.index[key]]
        hits = [i for i, n in enumerate(self.names) if _base_name(n) == key]
        if not hits:
            raise ValueError(
                f"unknown parameter {key!r} for model {_label(self.template)!r}; "
                f"expected one of {self.names}"
            )
        return hits

    def _fixed(self, fixed: Any, free: Iterable[str] | None) -> set[int]:
        """The held parameters: the models' defaults (unless released by ``free``) and
        ``fixed`` (names, or a mapping to the values they are held at)."""
        names = self.names
        fixed_idx: set[int] = set()
        released = {i for key in (free or ()) for i in self.expand(key)}
        for pre, comp in _components(self.template):
            for key in DEFAULT_FIXED.get(comp.name, ()) + _ALWAYS_FIXED:
                full = f"{pre}.{key}" if pre else key
                hits = [i for i, n in enumerate(names) if _base_name(n) == full]
                fixed_idx.update(i for i in hits if i not in released)
        if fixed is not None:
            if isinstance(fixed, str):
                raise ValueError(
                    f"fixed must be a list of names or a mapping, got string {fixed!r}"
                )
            items = fixed.items() if isinstance(fixed, Mapping) else ((k, None) for k in fixed)
            for key, v in items:
                for i in self.expand(key):
                    fixed_idx.add(i)
                    if v is not None:
                        self.values[i] = _as_float(v, key)
        return fixed_idx

    def _inside_bounds(self) -> None:
        """Keep every free start strictly inside finite bounds (TRF needs interior points)."""
        lo, hi, values = self.lo, self.hi, self.values
        for i in range(len(self.entries)):
            if i in self.fixed_idx:
                continue
            span = hi[i] - lo[i] if math.isfinite(hi[i] - lo[i]) else max(abs(values[i]), 1.0)
            pad = 1e-6 * span
            values[i] = min(max(values[i], lo[i] + pad), hi[i] - pad)

    def vals_of(self, x: NDArray) -> dict[str, float]:
        """Every parameter's value (flat names) with the free ones from ``x``."""
        v = self.values.copy()
        v[self.free_idx] = x
        return dict(zip(self.names, v.tolist()))

    def objective(self, d: _Data, r: _Residual) -> tuple[Callable, Callable]:
        """The residual vector of the free parameters on data ``d``: one that raises for an
        invalid model, and the optimiser's, which gives an invalid trial an infinite misfit
        (so that TRF shrinks its trust region instead of stopping)."""
        n = int(r.mask.sum())

        def checked(x: NDArray) -> NDArray:
            return r(_predict_layout(self.layout, d, self.vals_of(x)))

        def safe(x: NDArray) -> NDArray:
            try:
                return checked(x)
            except (ValueError, FloatingPointError, ZeroDivisionError):
                return np.full(n, np.inf)

        return checked, safe

    def starts(self, n_starts: int | None, rng: np.random.Generator) -> list[NDArray]:
        """The start, and ``n_starts`` random starts within the bounds (model-specific ones,
        physically sensible lobes, where the model has a starter)."""
        if n_starts is None:
            n_starts = max(
                (DEFAULT_STARTS.get(m.name, 0) for _, m in _components(self.template)), default=0
            )
        if not 0 <= n_starts <= MAX_STARTS:
            raise ValueError(f"n_starts must be in [0, {MAX_STARTS}], got {n_starts}")
        starts = [self.x0]
        for k in range(n_starts):
            xs = _random_start(self.entries, self.free_idx, self.x0, rng)
            comps = _components(self.start)
            if any(m.name in _STARTERS for _, m in comps) and self.layout.n_groups == 1:
                new = []
                for _, m in comps:
                    st = _STARTERS.get(m.name)
                    new.append(type(m)(**st(m.params, rng, k)) if st else m)
                rebuilt = new[0] if len(new) == 1 else Sum(new)
                entries = _make_layout(rebuilt, self.data, self.per_band).entries
                vals = {e[0]: e[1] for e in entries}
                xs = np.array([vals.get(self.names[i], self.values[i]) for i in self.free_idx])
                xs = np.clip(xs, self.lb, self.ub)
            starts.append(xs)
        return starts

    def varpro(self, linear: Iterable[str] | None) -> _VarPro | None:
        """Variable projection over the ``linear`` free parameters (checked to be linear)."""
        if linear is None:
            return None
        if isinstance(linear, str):
            raise ValueError(f"linear must be a list of names, got string {linear!r}")
        lin_set = {i for key in linear for i in self.expand(key)}
        lin_free = [j for j, i in enumerate(self.free_idx) if i in lin_set]
        if not lin_free:
            return None
        if self.residual == "log":
            raise ValueError(
                "linear= needs a residual linear in the model value; "
                "residual 'log' is not (use 'absolute', 'relative' or 'li_torrance')"
            )
        vp = _VarPro(self.layout, self.data, self.res, self.values, self.free_idx, lin_free,
                     self.names, self.lb, self.ub)  # fmt: skip
        vp.check_linear(self.x0)
        return vp

    def solve(self, f: Callable, xs: NDArray, nfev_max: int, tol: float) -> Any:
        """One bounded trust-region run (``scipy.optimize.least_squares``, method TRF)."""
        from scipy.optimize import least_squares  # imported here: ~0.5 s, only fits need it

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return least_squares(
                f, xs, bounds=(self.lb, self.ub), method="trf", x_scale=self.xscale,
                max_nfev=nfev_max, xtol=tol, ftol=tol, gtol=tol,
            )  # fmt: skip

    def screen_objective(self) -> Callable:
        """The optimiser's residual on a fixed random subset of at most :data:`SCREEN_ROWS`
        rows (the whole table when it is smaller), for screening many starts cheaply."""
        data = self.data
        if len(data.y) <= SCREEN_ROWS:
            return self.fun
        pick = np.sort(np.random.default_rng(0).choice(len(data.y), SCREEN_ROWS, replace=False))
        sub_data = _prepare(self.samples.subset(pick))
        # band indices refer to the full table's bands (the layout's)
        sub_data.band = None if data.band is None else data.band[pick]
        sub_data.wavelengths = data.wavelengths
        return self.objective(sub_data, _Residual(self.residual, sub_data))[1]


def _minimise(
    p: _Problem, starts: list[NDArray], vp: _VarPro | None, budget: int
) -> tuple[Any, int]:
    """The best solution over the starts, and the evaluations it took.

    Multi-start: every start is screened with a short run (on a subset of large tables),
    then the best one is polished on all the data. With variable projection every start is
    solved to the end.
    """
    screen = len(starts) > 1 and vp is None
    screen_fun = p.screen_objective() if screen else p.fun
    n_free = len(p.free_idx)
    best = None
    nfev = 0
    for xs in starts:
        if vp is not None:
            sol = vp.solve(xs, p.xscale, budget)
        else:
            try:
                sol = p.solve(
                    screen_fun, xs, min(budget, 15 * (n_free + 1)) if screen else budget,
                    1e-6 if screen else 1e-10,
                )  # fmt: skip
            except ValueError:  # a random start where the model cannot be evaluated
                continue
        nfev += sol.nfev
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        raise ValueError(f"no start of the fit of {_label(p.template)!r} could be evaluated")
    if screen:
        if screen_fun is not p.fun:  # converge on the subset (cheap), then polish on all rows
            best = p.solve(screen_fun, best.x, budget, 1e-10)
            nfev += best.nfev
        best = p.solve(p.fun, best.x, budget, 1e-10)
        nfev += best.nfev
    return best, nfev


def _result(
    p: _Problem, best: Any, vp: _VarPro | None, nfev: int, n_starts: int,
    absolute_sigma: bool | None, t0: float,
) -> FitResult:  # fmt: skip
    """The :class:`FitResult` of the best solution: χ², covariance, standard errors, rms."""
    data, names, free_idx = p.data, p.names, p.free_idx
    x = best.x
    r = best.fun
    chi2 = float(r @ r)
    dof = p.n_used - len(free_idx)
    chi2_dof = chi2 / dof if dof > 0 else math.inf
    J = _jacobian(p.fun_checked, x, p.lb, p.ub, r) if vp is None else vp.jacobian(x, r)
    cov, rank_ok, free_inf = _covariance(J)
    cov_scale = 1.0
    if dof > 0 and math.isfinite(chi2_dof):
        if absolute_sigma is None:
            cov_scale = max(1.0, chi2_dof) if data.sigma is not None else chi2_dof
        elif not absolute_sigma:
            cov_scale = chi2_dof
    cov = cov * cov_scale
    final = p.vals_of(x)
    models = p.layout.models(final)
    f = _predict_layout(p.layout, data, final)
    m = p.res.mask
    diff = f[m] - data.y[m]
    pos = data.y[m] > 0
    stderr = dict.fromkeys(names, 0.0)
    for j, i in enumerate(free_idx):
        stderr[names[i]] = math.inf if free_inf[j] else float(math.sqrt(max(cov[j, j], 0.0)))
    at_bounds = [
        names[i]
        for j, i in enumerate(free_idx)
        if any(
            math.isfinite(b) and abs(x[j] - b) <= 1e-9 * max(1.0, abs(b))
            for b in (p.lb[j], p.ub[j])
        )
    ]
    if not np.isfinite(x).all():  # cannot happen with TRF, but never hand back NaN silently
        raise ValueError(f"fit of {_label(p.template)!r} produced non-finite parameters {final}")
    unbounded = [names[i] for j, i in enumerate(free_idx) if free_inf[j]]
    notes = [n for n in (_chi2_note(chi2_dof, data.sigma is not None),
                         _identifiability_note(rank_ok, unbounded), _duplicates_note(data, m))
             if n]  # fmt: skip
    return FitResult(
        model=models[0],
        models=models,
        model_name=_label(p.template),
        residual=p.residual,
        params=final,
        stderr=stderr,
        free=[names[i] for i in free_idx],
        fixed=[names[i] for i in sorted(p.fixed_idx)],
        bounds={n: (float(p.lo[i]), float(p.hi[i])) for i, n in enumerate(names)},
        converged=bool(best.status > 0 and np.isfinite(chi2)),
        identifiable=rank_ok,
        message=str(best.message) + "".join(notes),
        rms=_rms(diff),
        rms_relative=_rms(diff[pos] / data.y[m][pos]) if pos.any() else math.nan,
        chi2=chi2,
        dof=dof,
        chi2_dof=chi2_dof,
        n_samples=p.n_used,
        n_excluded=int((~p.res.mask).sum()),
        nfev=nfev,
        n_starts=n_starts,
        absolute_sigma=absolute_sigma is True
        or (absolute_sigma is None and data.sigma is not None and cov_scale == 1.0),
        cov_scale=cov_scale,
        covariance=cov,
        at_bounds=at_bounds,
        wavelengths_nm=None if data.wavelengths is None else data.wavelengths.tolist(),
        time_s=time.perf_counter() - t0,
        warnings=[n.removeprefix(_NOTE) for n in notes],
    )


#: How :func:`fit` appends a note to its message.
_NOTE = "; note: "


class _VarPro:
    """Variable projection over the linear free parameters of :func:`fit` (``linear=``).

    The model is ``f = f(a) + A(θ) (k − a)`` in the linear parameters ``k`` (``a``: a base
    point inside their bounds, 0 where allowed); the basis ``A`` comes from model
    evaluations: one for ``f(a)`` and one per group of linear parameters that touch
    disjoint rows (all bands of a per-band parameter at once), so a Li-Torrance fit with
    93 per-band k's costs 4 model evaluations per trial σ/τ.
    """

    def __init__(self, layout, data, res, values, free_idx, lin_free, names, lb, ub) -> None:
        self.layout, self.data, self.res = layout, data, res
        self.values, self.free_idx, self.names = values, list(free_idx), names
        self.lin = np.asarray(lin_free, dtype=np.intp)
        lin_set = set(lin_free)
        self.nl = np.array([j for j in range(len(free_idx)) if j not in lin_set], np.intp)
        self.lb, self.ub = lb, ub
        lo, hi = lb[self.lin], ub[self.lin]
        self.a = np.clip(0.0, lo, hi)
        self.step = np.where(self.a + 1.0 <= hi, 1.0, hi - self.a)
        if np.any(self.step <= 0):
            bad = [names[free_idx[self.lin[k]]] for k in np.flatnonzero(self.step <= 0)]
            raise ValueError(f"linear parameters {bad} have empty bounds; expected lower < upper")
        self.dlo, self.dhi = lo - self.a, hi - self.a
        self.groups = self._groups()
        self.n = int(res.mask.sum())

    def _groups(self) -> list[tuple[NDArray[np.intp], NDArray[np.intp] | None]]:
        """``[(members, key)]``: members index ``self.lin``; ``key`` per used row the member
        that row depends on (−1: none), or ``None`` for a single member seen by every row."""
        lay, d = self.layout, self.data
        if lay.band_index is not None:
            row_key = lay.band_index[d.band]
        elif lay.n_groups > 1:
            row_key = d.band
        else:
            row_key = None
        by_base: dict[str, list[int]] = {}
        for m, j in enumerate(self.lin):
            by_base.setdefault(_base_name(self.names[self.free_idx[j]]), []).append(m)
        out: list[tuple[NDArray[np.intp], NDArray[np.intp] | None]] = []
        for base, members in by_base.items():
            idx = []
            for m in members:
                name = self.names[self.free_idx[self.lin[m]]]
                tail = name[len(base) :]
                ok = tail.startswith("[") and tail.endswith("]") and tail[1:-1].isdigit()
                idx.append(int(tail[1:-1]) if ok else -1)
            banded = (
                row_key is not None
                and min(idx) >= 0
                and (lay.band_index is not None or base in lay.per_band)
                and len(members) > 1
            )
            if not banded:
                out.extend((np.array([m], np.intp), None) for m in members)
                continue
            lookup = np.full(max(int(row_key.max()), max(idx)) + 1, -1, np.intp)
            for pos, i in enumerate(idx):
                lookup[i] = pos
            key = lookup[row_key][self.res.mask]
            out.append((np.array(members, np.intp), key))
        return out

    def predict(self, x: NDArray) -> NDArray:
        v = self.values.copy()
        v[self.free_idx] = x
        f = _predict_layout(self.layout, self.data, dict(zip(self.names, v.tolist())))
        return f[self.res.mask]

    def basis(self, x: NDArray) -> tuple[NDArray, NDArray]:
        """``(f(a), A)`` at the non-linear parameters of ``x`` (used rows)."""
        x = np.array(x, dtype=np.float64)
        x[self.lin] = self.a
        fa = self.predict(x)
        A = np.zeros((fa.size, self.lin.size))
        for members, key in self.groups:
            x1 = x.copy()
            x1[self.lin[members]] = self.a[members] + self.step[members]
            dv = self.predict(x1) - fa
            if key is None:
                A[:, members[0]] = dv / self.step[members[0]]
            else:
                ok = np.flatnonzero(key >= 0)
                cols = members[key[ok]]
                A[ok, cols] = dv[ok] / self.step[cols]
        return fa, A

    def project(self, x: NDArray) -> tuple[NDArray, NDArray]:
        """The best linear parameters for the non-linear ones of ``x``: ``(x, residual)``."""
        fa, A = self.basis(x)
        w = self.res.scale
        Aw = A * w[:, None]
        bw = (self.res.y - fa) * w
        dk = solve_bounded(Aw, bw, self.dlo, self.dhi)
        x = np.array(x, dtype=np.float64)
        x[self.lin] = self.a + dk
        return x, Aw @ dk - bw

    def check_linear(self, x0: NDArray) -> None:
        x = np.array(x0, dtype=np.float64)
        frac = np.modf(np.arange(1, self.lin.size + 1) * 0.6180339887)[0]
        x[self.lin] = self.a + self.step * (0.2 + 0.6 * frac)
        fa, A = self.basis(x)
        f = self.predict(x)
        lin = fa + A @ (x[self.lin] - self.a)
        tol = 1e-8 * max(float(np.max(np.abs(f))), 1e-300)
        bad = np.abs(lin - f) > tol
        if bad.any():
            raise ValueError(
                "linear= names parameters the model does not depend on linearly: at a test "
                f"point the linear prediction misses {int(bad.sum())} of {f.size} values by "
                f"up to {float(np.max(np.abs(lin - f))):.3g}; expected parameters entering "
                "as pure scale factors"
            )

    def solve(self, xs: NDArray, xscale: NDArray, budget: int) -> Any:
        from types import SimpleNamespace

        if self.nl.size == 0:
            x, _ = self.project(xs)
            r = self.res(self._full(x))
            return SimpleNamespace(
                x=x, fun=r, cost=0.5 * float(r @ r), status=1, nfev=1,
                message="linear least squares (no non-linear parameter)",
            )  # fmt: skip
        base = np.array(xs, dtype=np.float64)

        def fun(z: NDArray) -> NDArray:
            xx = base.copy()
            xx[self.nl] = z
            try:
                return self.project(xx)[1]
            except (ValueError, FloatingPointError, ZeroDivisionError):
                return np.full(self.n, np.inf)

        from scipy.optimize import least_squares

        nl = self.nl
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = least_squares(
                fun, base[nl], bounds=(self.lb[nl], self.ub[nl]), method="trf",
                x_scale=xscale[nl], max_nfev=budget, xtol=1e-10, ftol=1e-10, gtol=1e-10,
            )  # fmt: skip
        base[nl] = sol.x
        x, _ = self.project(base)
        r = self.res(self._full(x))
        return SimpleNamespace(
            x=x, fun=r, cost=0.5 * float(r @ r), status=sol.status, nfev=sol.nfev,
            message=str(sol.message),
        )  # fmt: skip

    def _full(self, x: NDArray) -> NDArray:
        v = self.values.copy()
        v[self.free_idx] = x
        return _predict_layout(self.layout, self.data, dict(zip(self.names, v.tolist())))

    def jacobian(self, x: NDArray, r0: NDArray) -> NDArray:
        """Jacobian of the weighted residuals: the basis for the linear columns (exact),
        central differences for the others (as :func:`_jacobian`)."""
        J = np.empty((r0.size, len(self.free_idx)))
        _, A = self.basis(x)
        J[:, self.lin] = A * self.res.scale[:, None]
        if self.nl.size:
            nl = self.nl

            def g(z: NDArray) -> NDArray:
                xx = np.array(x, dtype=np.float64)
                xx[nl] = z
                return self.res(self._full(xx))

            J[:, nl] = _jacobian(g, x[nl], self.lb[nl], self.ub[nl], r0)
        return J


#: chi2/dof above which, with the samples' own σ, :func:`fit` adds a note to the message
CHI2_NOTE = 10.0


def _chi2_note(chi2_dof: float, has_sigma: bool) -> str:
    """A note for a fit whose misfit its σ cannot explain: the optimizer converged (that is
    what ``converged`` says) but probably not to the fit (measured: Ward started at the
    lower corner of its bounds without the data guess stops at chi2/dof 493, the guessed
    start at 0.99, ``gonio stress --stages fits``)."""
    if not has_sigma or not (chi2_dof > CHI2_NOTE):
        return ""
    return (
        f"; note: chi2/dof = {chi2_dof:.3g} with the samples' own sigma: a local minimum or a "
        f"model that cannot describe the data (try {keyword('n_starts')} or {keyword('init')})"
    )


#: Most extra random starts :func:`fit` runs (each is a full optimisation).
MAX_STARTS = 10_000


def _identifiability_note(rank_ok: bool, unbounded: list[str]) -> str:
    """A note for a fit whose Jacobian is rank-deficient: some parameter combinations are
    not constrained by the samples (their standard errors are infinite)."""
    if rank_ok:
        return ""
    which = f" ({', '.join(unbounded)} unconstrained)" if unbounded else ""
    return (
        f"; note: not identifiable: the samples do not determine every free parameter{which}; "
        f"fix some ({keyword('fixed')}) or measure more geometries"
    )


def _duplicates_note(data: _Data, mask: NDArray) -> str:
    """A note when rows repeat other rows exactly (a table given twice): the standard errors
    assume independent samples, so each repeat shrinks them (by sqrt(2) for a doubled table)."""
    cols = [data.wi[mask], data.wo[mask], data.y[mask][:, None]]
    if data.band is not None:
        cols.append(np.asarray(data.band)[mask][:, None].astype(np.float64))
    key = np.concatenate(cols, axis=1)
    n_dup = repeated_rows(key)
    if n_dup == 0:
        return ""
    return (
        f"; note: {n_dup} of {key.shape[0]} rows repeat other rows exactly: the standard "
        "errors assume independent samples and are too small"
    )


def repeated_rows(key: NDArray) -> int:
    """How many rows of ``key`` (n, k) repeat another row: ``n`` minus the rows of
    ``np.unique(key, axis=0)``, the same count.

    ``np.unique`` with ``axis`` sorts the rows as records (0.5 s for the 170 000 rows of a
    default campaign, half of its fit); here each row's bits are hashed to one 64-bit
    integer and sorted (0.02 s), and only rows whose hashes collide are compared by
    ``np.unique``. Rows with different bits after ``-0.0`` is made ``0.0`` differ as
    numbers too (a NaN equals nothing, as in ``np.unique``), so a row of its own hash
    repeats no other row.
    """
    key = np.ascontiguousarray(key, dtype=np.float64) + 0.0  # (-0.0 + 0.0 is 0.0)
    n = key.shape[0]
    if n < 2:
        return 0
    if key.shape[1] == 0:  # empty rows are all the same row
        return n - 1
    bits = key.view(np.uint64)
    h = np.zeros(n, dtype=np.uint64)
    for c in range(bits.shape[1]):  # a multiply-xorshift mix, column by column (wrapping)
        h ^= bits[:, c]
        h *= np.uint64(0x9E3779B97F4A7C15)
        h ^= h >> np.uint64(31)
    order = np.argsort(h)
    same = h[order[1:]] == h[order[:-1]]
    if not same.any():
        return 0
    shared = np.zeros(n, dtype=bool)  # in a run of equal hashes
    shared[1:] |= same
    shared[:-1] |= same
    sub = key[order[shared]]
    return int(sub.shape[0] - np.unique(sub, axis=0).shape[0])


def _rms(r: NDArray) -> float:
    """Root mean square without overflow (scaled by the largest magnitude): a fit stopped
    far from the data (e.g. started at a parameter bound) has residuals whose squares
    overflow; the rms is then the largest finite value or inf, never a warning."""
    r = np.asarray(r, dtype=np.float64)
    if r.size == 0:
        return math.nan
    big = float(np.max(np.abs(r)))
    if not math.isfinite(big) or big == 0.0:
        return big
    return big * float(np.sqrt(np.mean((r / big) ** 2)))


def _as_float(v: Any, key: str) -> float:
    """``v`` as a finite float; ``ValueError`` naming the parameter ``key`` and the value."""
    return check_scalar(v, f"value of parameter {key!r}")


def _jacobian(fun: Callable, x: NDArray, lb: NDArray, ub: NDArray, r0: NDArray) -> NDArray:
    """Central-difference Jacobian (one-sided next to a bound), robust to jumps.

    Each column is differenced with steps ``h`` and ``h/8``. Where a model has a jump (e.g.
    Li-Torrance's eq. 7 short-cut S = 1 above a threshold that moves with τ/σ), a row whose
    threshold falls inside the step gets ``jump/2h`` added: with one step that row was
    wrong, and a Li-Torrance fit whose σ and τ only enter as σ/τ came out "identifiable"
    with a stderr 6 500x too small (garnet red paint). Rows where the two steps disagree
    (by more than 1e-3 relative) keep the smaller magnitude (a jump makes it larger).
    """
    J = np.empty((r0.size, x.size))
    for j in range(x.size):
        span = ub[j] - lb[j]
        h = 1e-6 * max(abs(x[j]), 1e-2 * span if math.isfinite(span) else 1e-3, 1e-6)
        a, b = (_difference(fun, x, lb, ub, r0, j, step) for step in (h, h / 8.0))
        bad = np.abs(a - b) > 1e-3 * (np.abs(a) + np.abs(b)) + 1e-300
        J[:, j] = np.where(bad & (np.abs(b) < np.abs(a)), b, a)
    return J


def _difference(
    fun: Callable, x: NDArray, lb: NDArray, ub: NDArray, r0: NDArray, j: int, h: float
) -> NDArray:
    """One column of the difference Jacobian with step ``h``."""
    up = x[j] + h <= ub[j]
    dn = x[j] - h >= lb[j]
    xp, xm = x.copy(), x.copy()
    if up and dn:
        xp[j] += h
        xm[j] -= h
        return (fun(xp) - fun(xm)) / (2 * h)
    if up:
        xp[j] += h
        return (fun(xp) - r0) / h
    xm[j] -= h
    return (r0 - fun(xm)) / h


def _covariance(J: NDArray) -> tuple[NDArray, bool, NDArray]:
    """``(JᵀJ)⁻¹`` via SVD; parameters in the null space get an infinite variance."""
    n = J.shape[1]
    norms = np.sqrt(np.sum(J * J, axis=0))
    dead = norms == 0  # a parameter the misfit does not depend on at all
    d = np.where(dead, 1.0, norms)
    _, s, vt = np.linalg.svd(J / d, full_matrices=False)  # columns scaled to unit length
    keep = s > 1e-7 * s[0] if s.size and s[0] > 0 else np.zeros(s.shape, bool)
    inv = np.where(keep, 1.0 / np.where(keep, s, 1.0) ** 2, 0.0)
    cov = ((vt.T * inv) @ vt) / np.outer(d, d)
    null = vt[~keep]
    free_inf = (np.abs(null) > 1e-3).any(axis=0) if null.size else np.zeros(n, bool)
    free_inf |= dead
    return cov, bool(keep.all() and not dead.any()), free_inf
