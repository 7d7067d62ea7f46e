"""The BRDF base class, parameter specifications and the model registry.

Every model is a subclass of :class:`BRDF` declaring ``name``, ``PARAMS`` (a tuple of
:class:`Param`) and ``_eval(wi, wo)``; the :func:`register` decorator puts it in the registry
that :func:`gonio.brdf.create`, :func:`gonio.brdf.names` and :func:`gonio.brdf.spec` read
(colour-science's ``*_METHODS`` mapping habit, ``docs/architecture.md``).

Conventions: ``wi`` points towards the light, ``wo`` towards the viewer, both away from the
surface in the local frame (z = normal). Values are in sr⁻¹, shape ``(...)`` for a grey model
and ``(..., n_bands)`` for a spectral one. Directions below the horizon give 0, never NaN.
Directions must be unit vectors (within :data:`gonio._validate.UNIT_TOLERANCE`); every public
method checks them with :func:`gonio._validate.as_unit_directions` and raises ``ValueError``
otherwise (``evaluate_unchecked`` skips the check for trusted arrays).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gonio._validate import as_unit_directions

__all__ = [
    "BRDF",
    "CallableBRDF",
    "ModelSpec",
    "Param",
    "as_brdf",
    "create",
    "get_class",
    "names",
    "register",
    "spec",
]


@dataclass(frozen=True)
class Param:
    """One model parameter: its name, default, closed bounds, unit and meaning.

    ``default=None`` marks a required parameter. ``kind`` is ``"float"`` (a scalar, or a
    1-D array of per-band values when ``spectral`` is true) or ``"object"`` (validated by the
    model itself, e.g. Lafortune's list of lobes or a measured table).
    """

    name: str
    default: Any
    lower: float = -math.inf
    upper: float = math.inf
    unit: str = ""
    doc: str = ""
    kind: str = "float"
    spectral: bool = False
    optional: bool = False  # None is an allowed value (e.g. ``c_n=None`` = the maximum)

    def check(self, value: Any, model: str) -> Any:
        """Validate ``value``; return it as float (or float array) or unchanged for objects."""
        if self.kind == "object" or (value is None and self.optional):
            return value
        where = f"{model}: parameter {self.name}"
        arr = np.asarray(value, dtype=object if value is None else None)
        if value is None or arr.dtype.kind not in "biuf":
            raise ValueError(f"{where} must be a number, got {value!r}")
        arr = arr.astype(np.float64)
        if arr.ndim > (1 if self.spectral else 0):
            raise ValueError(
                f"{where} must be a scalar{' or a 1-D array of bands' if self.spectral else ''}"
                f", got shape {arr.shape}"
            )
        if not np.isfinite(arr).all():
            raise ValueError(f"{where} must be finite, got {value!r}")
        if np.any(arr < self.lower) or np.any(arr > self.upper):
            raise ValueError(
                f"{where} = {value!r} is outside its bounds [{self.lower}, {self.upper}]"
                + (f" ({self.unit})" if self.unit else "")
            )
        return float(arr) if arr.ndim == 0 else arr


@dataclass(frozen=True)
class ModelSpec:
    """What ``brdf.spec(name)`` returns: parameters with bounds, units and defaults.

    ``reciprocal`` and ``energy_conserving`` state the model's documented properties (used
    by the property tests and ``gonio stress``); ``known_issues`` names documented
    breakdowns, e.g. Ward's albedo divergence at grazing incidence (Neumann §7.4).
    """

    name: str
    params: Mapping[str, Param]
    reference: str
    summary: str = ""
    reciprocal: bool = True
    energy_conserving: bool = True
    known_issues: tuple[str, ...] = ()
    has_sampler: bool = False
    has_delta: bool = False
    analytic_albedo: bool = False

    def defaults(self) -> dict[str, Any]:
        """Parameter name -> default value (required parameters are omitted)."""
        return {k: p.default for k, p in self.params.items() if p.default is not None}

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Parameter name -> ``(lower, upper)`` for the float parameters."""
        return {k: (p.lower, p.upper) for k, p in self.params.items() if p.kind == "float"}


_REGISTRY: dict[str, type[BRDF]] = {}


def register(cls: type[BRDF]) -> type[BRDF]:
    """Class decorator adding a model to the registry under ``cls.name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__} has no 'name'")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise TypeError(f"model name {cls.name!r} registered twice")
    _REGISTRY[cls.name] = cls
    return cls


def names() -> list[str]:
    """Sorted names of all registered models."""
    return sorted(_REGISTRY)


def get_class(name: str) -> type[BRDF]:
    """The model class registered as ``name``; the error lists the valid names."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown BRDF model {name!r}; registered models are: {', '.join(names())}"
        ) from None


def create(name: str, **params: Any) -> BRDF:
    """Instantiate the model registered as ``name`` with ``params``.

    Examples
    --------
    >>> from gonio import brdf
    >>> m = brdf.create("ward", rho_d=0.1, rho_s=0.33, alpha_x=0.05, alpha_y=0.16)
    >>> round(float(m([0, 0, 1.0], [0, 0, 1.0])), 4)
    3.3144
    """
    return get_class(name)(**params)


def spec(name: str) -> ModelSpec:
    """The :class:`ModelSpec` of model ``name`` (parameters, bounds, units, defaults)."""
    return get_class(name).spec()


class BRDF:
    """Base class of every reflectance model.

    Subclasses set the class attributes and implement :meth:`_eval`. Optional overrides:
    :meth:`_albedo` (analytic directional-hemispherical reflectance), :meth:`_sample` and
    :meth:`_pdf` (importance sampling where the paper gives a method), :meth:`delta` (a
    mirror part, rendered separately through a finite source).
    """

    name: ClassVar[str] = ""
    PARAMS: ClassVar[tuple[Param, ...]] = ()
    REFERENCE: ClassVar[str] = ""
    SUMMARY: ClassVar[str] = ""
    RECIPROCAL: ClassVar[bool] = True
    ENERGY_CONSERVING: ClassVar[bool] = True
    KNOWN_ISSUES: ClassVar[tuple[str, ...]] = ()
    #: default relative tolerance of the quadrature albedo
    ALBEDO_RTOL: ClassVar[float] = 1e-4

    def __init__(self, **params: Any) -> None:
        known = {p.name: p for p in self.PARAMS}
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise ValueError(f"{self.name}: unknown parameter(s) {unknown}; expected {list(known)}")
        values: dict[str, Any] = {}
        for p in self.PARAMS:
            if p.name in params:
                v = params[p.name]
            elif p.default is not None or p.optional:
                v = p.default
            else:
                raise ValueError(f"{self.name}: missing required parameter {p.name!r}")
            values[p.name] = p.check(v, self.name)
        self._params = values
        self._setup()

    # ----------------------------------------------------------------- hooks
    def _setup(self) -> None:
        """Precompute derived constants and check cross-parameter constraints."""

    def _eval(self, wi: NDArray[np.float64], wo: NDArray[np.float64]) -> NDArray[np.float64]:
        raise TypeError(f"{type(self).__name__} does not implement _eval")

    # ----------------------------------------------------------------- public API
    @classmethod
    def spec(cls) -> ModelSpec:
        """Parameter specification of this model (see :class:`ModelSpec`)."""
        return ModelSpec(
            name=cls.name,
            params={p.name: p for p in cls.PARAMS},
            reference=cls.REFERENCE,
            summary=cls.SUMMARY,
            reciprocal=cls.RECIPROCAL,
            energy_conserving=cls.ENERGY_CONSERVING,
            known_issues=cls.KNOWN_ISSUES,
            has_sampler=cls._sample is not BRDF._sample,
            has_delta=cls.delta is not BRDF.delta,
            analytic_albedo=cls._albedo is not BRDF._albedo,
        )

    @property
    def params(self) -> dict[str, Any]:
        """Parameter name -> value (a copy)."""
        return dict(self._params)

    @property
    def wavelengths_nm(self) -> NDArray[np.float64] | None:
        """Band centres in nm for a spectral model, ``None`` for a grey one."""
        return None

    @property
    def n_bands(self) -> int | None:
        """Number of spectral bands, or ``None`` for a grey model (values of shape ``(...)``)."""
        wl = self.wavelengths_nm
        return None if wl is None else len(wl)

    def __call__(self, wi: ArrayLike, wo: ArrayLike) -> NDArray[np.float64]:
        """BRDF value f_r(wi, wo) in sr⁻¹; 0 where either direction is below the horizon."""
        wi = as_unit_directions(wi, "wi")
        wo = as_unit_directions(wo, "wo")
        try:
            np.broadcast_shapes(wi.shape, wo.shape)
        except ValueError:
            raise ValueError(
                f"wi shape {wi.shape} and wo shape {wo.shape} do not broadcast"
            ) from None
        return self._eval(wi, wo)

    def evaluate_unchecked(self, wi: NDArray, wo: NDArray) -> NDArray[np.float64]:
        """:meth:`__call__` without input validation, for hot loops on trusted arrays."""
        return self._eval(wi, wo)

    def albedo(self, wi: ArrayLike, rtol: float | None = None) -> NDArray[np.float64]:
        """Directional-hemispherical reflectance ∫ f_r(wi, wo) cos θo dωo.

        Analytic where the model's paper gives it; otherwise an adaptive quadrature in polar
        coordinates about the mirror direction with the horizon as exact limit
        (:func:`pole_hemisphere_integral`); the node count doubles in each dimension until
        three successive estimates agree to ``rtol`` (default :attr:`ALBEDO_RTOL`) relative
        (or 1e-12 absolute). Shape ``(...)`` or ``(..., n_bands)``; 0 for directions below
        the horizon.
        """
        wi = as_unit_directions(wi, "wi")
        rtol = self.ALBEDO_RTOL if rtol is None else float(rtol)
        if not (0.0 < rtol < 1.0):
            raise ValueError(f"rtol must be in (0, 1), got {rtol!r}")
        out = self._albedo(wi, rtol)
        if out is None:
            flat = wi.reshape(-1, 3)
            vals = [self._quadrature_albedo(w, rtol) for w in flat]
            out = np.asarray(vals, dtype=np.float64).reshape(
                wi.shape[:-1] + np.shape(vals[0]) if vals else wi.shape[:-1]
            )
        return out

    def _albedo(self, wi: NDArray, rtol: float) -> NDArray | None:
        """Analytic albedo, or ``None`` to fall back to quadrature."""
        return None

    def _quadrature_albedo(self, wi: NDArray, rtol: float, max_level: int = 8) -> Any:
        if wi[2] <= 0.0:
            return np.zeros(self.n_bands) if self.n_bands else 0.0
        pole = self._albedo_pole(wi)
        history: list[Any] = []
        n_s, n_phi = 24, 32
        for _ in range(max_level):
            est = pole_hemisphere_integral(lambda wo, w=wi: self._eval(w, wo), pole, n_s, n_phi)
            history.append(est)
            # converged when the last three levels agree (two agreeing levels can both miss
            # a narrow lobe on a coarse grid)
            if len(history) >= 3:
                scale = max(float(np.max(np.abs(est))), 1e-300)
                d1 = float(np.max(np.abs(history[-1] - history[-2])))
                d2 = float(np.max(np.abs(history[-2] - history[-3])))
                if max(d1, d2) <= max(rtol * scale, 1e-12):
                    return est
            n_s, n_phi = 2 * n_s, 2 * n_phi
        return est

    def _albedo_pole(self, wi: NDArray) -> NDArray:
        """Direction around which the quadrature albedo concentrates its nodes.

        The mirror direction of ``wi`` by default; a model whose lobe peaks elsewhere
        (e.g. retro-reflection) overrides this.
        """
        return wi * np.array([-1.0, -1.0, 1.0])

    def sample(
        self, wo: ArrayLike, rng: int | np.random.Generator | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Draw one incident direction per ``wo`` and return ``(wi, pdf)``.

        ``pdf`` is the solid-angle density of the returned ``wi``; samples the method rejects
        (below the horizon) come back with ``pdf = 0``. Available where the model's paper
        gives a sampling method (Ward eq. 7, Lafortune lobes, Neumann §4).
        """
        if type(self)._sample is BRDF._sample:
            raise TypeError(f"model {self.name!r} has no sampling method (its paper gives none)")
        wo = as_unit_directions(wo, "wo")
        return self._sample(wo, np.random.default_rng(rng))

    def pdf(self, wo: ArrayLike, wi: ArrayLike) -> NDArray[np.float64]:
        """Solid-angle density with which :meth:`sample` returns ``wi`` given ``wo``."""
        if type(self)._pdf is BRDF._pdf:
            raise TypeError(f"model {self.name!r} has no sampling method (its paper gives none)")
        return self._pdf(as_unit_directions(wo, "wo"), as_unit_directions(wi, "wi"))

    def _sample(self, wo: NDArray, rng: np.random.Generator) -> tuple[NDArray, NDArray]:
        raise TypeError(f"model {self.name!r} has no sampling method")

    def _pdf(self, wo: NDArray, wi: NDArray) -> NDArray:
        raise TypeError(f"model {self.name!r} has no sampling method")

    def delta(self, wi: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The ideal-mirror (Dirac) part: ``(direction, reflectance)`` per incident direction.

        ``direction`` is the mirror direction of ``wi``; ``reflectance`` the fraction of the
        incident flux it carries (shape ``(...)`` or ``(..., n_bands)``). Instruments render it
        through the source's solid angle. Models without a mirror part return reflectance 0.
        """
        wi = as_unit_directions(wi, "wi")
        d = wi * np.array([-1.0, -1.0, 1.0])
        shape = wi.shape[:-1] + ((self.n_bands,) if self.n_bands else ())
        return d, np.zeros(shape)

    @property
    def has_delta(self) -> bool:
        """Whether :meth:`delta` can return a non-zero reflectance."""
        return type(self).delta is not BRDF.delta

    def __add__(self, other: BRDF) -> BRDF:
        from gonio.brdf.composite import Sum

        return Sum([self, other])

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={_short(v)}" for k, v in self._params.items())
        return f"{type(self).__name__}({args})"


def _short(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return f"array(shape={v.shape})"
    return repr(v)


def hemisphere_integral(
    f: Callable[[NDArray], NDArray], n_s: int, n_phi: int
) -> NDArray[np.float64]:
    """∫_Ω f(w) cos θ dω by product Gauss-Legendre in ``s = sqrt(cos θ)`` and φ.

    With ``cos θ = s²``: ``cos θ dω = s² · 2s ds dφ``. The substitution smooths the
    ``1/sqrt(cos θ)`` factor of Ward-type models at grazing angles.
    """
    xs, ws = np.polynomial.legendre.leggauss(n_s)
    s = 0.5 * (xs + 1.0)
    w_s = 0.5 * ws * 2.0 * s**3
    # φ: composite midpoint rule (spectrally accurate for periodic integrands)
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    w_phi = 2.0 * np.pi / n_phi
    mu = s**2
    st = np.sqrt(np.clip(1.0 - mu**2, 0.0, None))
    wo = np.stack(
        np.broadcast_arrays(
            st[:, None] * np.cos(phi)[None, :],
            st[:, None] * np.sin(phi)[None, :],
            mu[:, None],
        ),
        axis=-1,
    )
    vals = np.asarray(f(wo))
    weights = w_s[:, None] * w_phi
    if vals.ndim == 3:
        return np.einsum("ijb,ij->b", vals, weights)
    return np.einsum("ij,ij->", vals, weights)


def pole_hemisphere_integral(
    f: Callable[[NDArray], NDArray], pole: NDArray, n_s: int, n_phi: int
) -> NDArray[np.float64]:
    """∫_Ω f(w) cos θ dω in polar coordinates (t, φ) about ``pole`` with the exact horizon.

    ``w = cos t · pole + sin t (cos φ e₁ + sin φ e₂)``. Along each azimuth φ the great-circle
    ray from the pole (which must be above the horizon) leaves the upper hemisphere at
    ``t_max(φ) = atan2(pole_z, −a(φ))`` with ``a(φ) = cos φ e₁_z + sin φ e₂_z``, so the domain
    is covered exactly once and the integrand is smooth inside it. ``t = t_max s²`` grades
    the Gauss-Legendre nodes in ``s`` towards the pole, where specular lobes peak;
    φ uses the midpoint rule (spectral for periodic integrands). The Jacobian is
    ``sin t · 2 t_max s``.
    """
    from gonio.geometry import local_frame

    frame = local_frame(pole)
    e1, e2, p = frame[0], frame[1], frame[2]
    xs, ws = np.polynomial.legendre.leggauss(n_s)
    s = 0.5 * (xs + 1.0)
    w_s = 0.5 * ws
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    a = np.cos(phi) * e1[2] + np.sin(phi) * e2[2]
    t_max = np.arctan2(max(p[2], 0.0), -a)  # (P,)
    t = t_max[None, :] * s[:, None] ** 2  # (S, P)
    st, ct = np.sin(t), np.cos(t)
    dirs = (
        ct[..., None] * p
        + (st * np.cos(phi)[None, :])[..., None] * e1
        + (st * np.sin(phi)[None, :])[..., None] * e2
    )
    cos_o = np.maximum(dirs[..., 2], 0.0)
    dirs[..., 2] = cos_o
    weights = (w_s[:, None] * (2.0 * np.pi / n_phi)) * st * 2.0 * t_max[None, :] * s[:, None]
    weights = weights * cos_o
    vals = np.asarray(f(dirs))
    if vals.ndim == 3:
        return np.einsum("ijb,ij->b", vals, weights)
    return np.einsum("ij,ij->", vals, weights)


class CallableBRDF(BRDF):
    """Wrap a plain callable ``f(wi, wo)`` so it can stand wherever a model is accepted.

    The callable's values are multiplied by 0 below the horizon and checked for NaN.
    """

    name: ClassVar[str] = "callable"
    RECIPROCAL: ClassVar[bool] = False

    def __init__(self, func: Callable[[NDArray, NDArray], ArrayLike], label: str = "") -> None:
        if not callable(func):
            raise ValueError(f"func must be callable, got {type(func).__name__}")
        self._func = func
        self._label = label or getattr(func, "__name__", "callable")
        self._params = {}

    def _eval(self, wi: NDArray, wo: NDArray) -> NDArray:
        v = np.asarray(self._func(wi, wo), dtype=np.float64)
        if not np.isfinite(v).all():
            raise ValueError(f"BRDF callable {self._label!r} returned non-finite values")
        up = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
        if v.ndim > up.ndim:
            up = up[..., None]
        return np.where(up, v, 0.0)

    def __repr__(self) -> str:
        return f"CallableBRDF({self._label})"


def as_brdf(model: BRDF | Callable | str, **params: Any) -> BRDF:
    """Accept a model instance, a registered name (with ``params``) or a plain callable."""
    if isinstance(model, BRDF):
        return model
    if isinstance(model, str):
        return create(model, **params)
    if callable(model):
        return CallableBRDF(model)
    raise ValueError(f"expected a BRDF, a model name or a callable, got {type(model).__name__}")
