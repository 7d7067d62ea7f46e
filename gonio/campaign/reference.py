"""A model is not the truth: the reference a fit of another family is judged against.

When the fitted model is not the family that made the data (Ward fitted to an Oren-Nayar
plaster — the normal case in a laboratory, where no model is the truth), its parameters
have no true values. What a perfect instrument would have given is the model's best
approximation of the truth *on the same directions with the same weights*: the fit of the
truth's noise-free values at the campaign's own sample directions, weighted by the samples'
σ, with the same residual, template and fixed parameters (the least-squares projection of
the truth onto the model; White 1982 calls its limit the pseudo-true parameter). The
campaign's fit scatters about that reference by the instrument's errors, so the uncertainty
budget is checked against it; how far the reference itself is from the truth is the model's
inadequacy, reported in BRDF space over the measured hemisphere (the rms and the worst
relative difference of the fitted BRDF from the true one), the number a renderer's user
needs.

References
----------
.. [White1982] H. White, "Maximum likelihood estimation of misspecified models",
   Econometrica 50(1), 1-25, 1982. https://doi.org/10.2307/1912526
   §2-3: the estimator of a misspecified model converges to the parameter that minimises
   the distance to the true distribution (the pseudo-true value).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["inadequacy", "model_reference", "true_values"]


def true_values(truth: Any, samples: Any) -> NDArray[np.float64]:
    """The truth's noise-free BRDF at the samples' directions (a spectral truth by its
    band mean: what a grey camera sees of it)."""
    f = np.asarray(truth(samples.wi, samples.wo), dtype=np.float64)
    return f.mean(axis=-1) if f.ndim > 1 else f


def inadequacy(model: Any, truth: Any, samples: Any) -> dict[str, float | None]:
    """The fitted BRDF against the true BRDF over the samples' directions: ``rms`` (sr⁻¹),
    ``rms_relative`` and ``worst_relative`` (``|f − f_true| / f_true`` over the
    directions where the truth is above 10⁻³ of its largest value)."""
    from gonio.fit import predict

    ft = true_values(truth, samples)
    fm = np.asarray(predict(model, samples), dtype=np.float64)
    if fm.ndim > 1:
        fm = fm.mean(axis=-1)
    d = fm - ft
    ok = ft > 1e-3 * float(np.max(ft)) if ft.size and np.max(ft) > 0 else np.zeros(ft.shape, bool)
    rel = np.abs(d[ok]) / ft[ok]
    return {
        "rms": float(np.sqrt(np.mean(d * d))) if d.size else None,
        "rms_relative": float(np.sqrt(np.mean(rel * rel))) if rel.size else None,
        "worst_relative": float(np.max(rel)) if rel.size else None,
        "n_directions": int(ok.sum()),
    }


def model_reference(truth: Any, result: Any, samples: Any) -> dict[str, Any]:
    """The reference of a fit whose model is not the truth's family.

    Parameters
    ----------
    truth : BRDF
        The model that made the data.
    result : FitResult
        The campaign's fit (its model, residual, fixed parameters).
    samples : BRDFSamples
        The fitted samples (their directions and σ).

    Returns
    -------
    dict
        ``params`` (the reference value of each free parameter), ``converged``,
        ``chi2_dof`` of the reference fit in the samples' σ (the model's inadequacy in
        units of the noise), ``inadequacy`` of the campaign's fit and of the reference
        (:func:`inadequacy`), and ``method``.
    """
    from gonio import fit as _fit

    ft = true_values(truth, samples)
    exact = dataclasses.replace(samples, value=ft)
    fixed = {k: result.params[k] for k in result.fixed if k in result.params}
    ref = _fit.fit(exact, result.model, residual=result.residual, guess=False,
                   fixed=fixed or None)  # fmt: skip
    return {
        "method": "the fitted model's least-squares approximation of the truth's noise-free "
        "values on the campaign's sample directions, with the samples' sigma",
        "params": {k: float(ref.params[k]) for k in result.free},
        "converged": bool(ref.converged),
        "chi2_dof": float(ref.chi2_dof) if math.isfinite(ref.chi2_dof) else None,
        "inadequacy": {
            "fit": inadequacy(result.model, truth, samples),
            "reference": inadequacy(ref.model, truth, samples),
        },
    }
