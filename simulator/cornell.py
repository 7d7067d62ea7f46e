"""The Cornell automated three-axis gonioreflectometer, simulated.

What the instrument is (Li and Torrance 2005, §5.1 and issue 7): a quartz-halogen source on
an arm revolving about the sample, a sample with two rotations, a fixed grating
spectroradiometer (≈1024 pixels over ≈385-710 nm) viewing the sample through a folding mirror,
31 bands at 10 nm from 400 to 700 nm, two polarisations measured and combined, BRDF relative to
a Spectralon-like standard or absolute from the direct beam, a source solid angle of ≈0.0005 sr,
85° range, 7° retro-reflection cone, ≈11 hours for a full hemispherical campaign.

Layers (each usable on its own):

* :mod:`gonio.simulator.cornell_kinematics` — motor angles ↔ directions, reachability.
* :mod:`gonio.simulator.cornell_plans` — sampling plans, ordering, run-time estimate.
* :mod:`gonio.simulator.spectra` — lamp, detector response, polarisation, standard.
* here: the radiometry (:meth:`CornellInstrument.expected_brdf`: the BRDF averaged over the
  source and detector cones, the mirror part rendered through the source's solid angle), the
  raw spectra with noise (:meth:`CornellInstrument.spectrum_render`, the function the fake
  USB2000+ calls), the reduction to 31 bands (:func:`reduce_measurement`) and a whole campaign
  (:func:`simulate_campaign` → :class:`gonio.samples.BRDFSamples`).

Radiometry. With ``E_i = L_s Ω_s cos θi`` the detector reads the radiance ``f E_i`` averaged
over its cone, so the instrument measures::

    f_meas(wi, wo) = 1/(Ω_s Ω_d cos θi) ∫_src ∫_det f(wi', wo') cos θi' dωi' dωo'
                     + ρ(wi) A(β) / (Ω_s Ω_d cos θi)

where the second term is the mirror part (``brdf.delta``: reflectance ρ), ``A`` the solid angle
shared by the detector cone and the mirror image of the source cone, ``β`` their separation.
With the detector cone inside the source image the peak is ``ρ / (Ω_s cos θi)`` — eq. 16's
``exp(−g)/dω_i`` top hat with ``dω_i = Ω_s``. The double integral uses an equal-area product
Gauss rule per cone; it is skipped (centre value used) when the BRDF changes by less than
``skip_tol`` (relative) between the centre and the rims of both cones — the lobe is then much
wider than the source. The shortcut is off by default (``skip_tol = 0``: every pose is
integrated): its error must stay far below the noise even after a fit averages thousands of
samples, and it does not pay. With ``1e-3`` the skipped poses read the centre value where the
cone average differs by up to 1e-3 (with the same sign along a lobe flank), which biased τ of
a noisy 240-geometry garnet_red_paint fit by 3.5 of its standard errors (noise-free data
with the noisy run's weights: τ 8.20044 instead of 8.2; with ``1e-4``, ``1e-5`` or ``0``:
8.200000); at ``1e-5`` the rim estimate of the error is itself off by a factor 4, and a
full hemispherical campaign took as long with the check as without it.

Raw counts per pixel: ``bias + t·(dark + T_filter·(K·P(λ)·η_q(λ)·f_conv(λ) + stray))`` with
shot noise (Poisson in electrons), Gaussian read noise, 16-bit clipping; ``P`` the halogen
spectrum, ``η_q`` the detector response for polarisation ``q``. Noise is drawn from a generator
keyed by (seed, quantised motor positions, integration time, polariser, shutter, target,
filter, number of pixels, occurrence count), so the same sequence of reads gives the same
counts whether they come in-process or through the fake devices.

Reduction: dark-subtracted rate per polarisation, minus the stray light measured on a beam
trap, divided by the reference (standard: × ρ_std(λ)/π · cos θi_ref / cos θi; direct beam:
× attenuation / (Ω_s cos θi)), the two polarisations averaged, then the pixels projected onto
31 hat functions (least squares, exact for spectra linear between band centres). Noise-free,
this returns the cone-averaged model to rounding error.

References
----------
.. [LiTorrance2005] H. Li and K. E. Torrance, "A practical, comprehensive light reflection model",
   Technical report, Program of Computer Graphics, Cornell University, 2005.
   Here: the instrument of §5.1 (source arm, two-axis stage, 31-band spectroradiometer) and
   the source solid angle of eq. 16.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from gonio.simulator.cornell_kinematics import AXES, Kinematics, forward, inverse
from gonio.simulator.cornell_plans import (
    Plan,
    Timing,
    estimate_run_time,
    hemispherical_plan,
    incidence_plane_plan,
    order_plan,
    read_plan_csv,
    reference_seconds,
)
from gonio.simulator.cornell_true import TrueInstrument
from gonio.simulator.spectra import detector_response, halogen_spectrum, spectralon_reflectance
from numpy.typing import ArrayLike, NDArray

from gonio.brdf.base import BRDF, as_brdf
from gonio.samples import BRDFSamples

__all__ = [
    "AXES",
    "BANDS_NM",
    "BENCH_STAGES",
    "CornellConfig",
    "CornellInstrument",
    "Kinematics",
    "Plan",
    "Reference",
    "Timing",
    "accuracy_check",
    "auto_exposure",
    "bench_renderers",
    "effective_cos",
    "estimate_run_time",
    "first_polarizer",
    "forward",
    "hemispherical_plan",
    "incidence_plane_plan",
    "inverse",
    "measure_raw",
    "order_plan",
    "read_plan_csv",
    "read_sequence",
    "reduce_measurement",
    "simulate_campaign",
]

#: The 31 reduced bands (nm).
BANDS_NM = np.arange(400.0, 701.0, 10.0)

#: Target codes of the ``"target"`` key of a read.
TARGETS = {"sample": 0, "standard": 1, "beam_trap": 2, "direct": 3}
_POL = {"s": 0.0, "p": 90.0}

#: Stage layout for ``gonio.simulator.bench.Bench`` (degrees, deg/s, deg/s²).
BENCH_STAGES = (
    ("arm", {"lower": -180.0, "upper": 180.0, "speed": 5.0, "acceleration": 10.0}),
    ("turntable", {"lower": -180.0, "upper": 180.0, "speed": 10.0, "acceleration": 20.0}),
    ("tilt", {"lower": -90.0, "upper": 90.0, "speed": 10.0, "acceleration": 20.0}),
)


def _default_coeffs() -> tuple[float, float, float, float]:
    c2 = -2.0e-6
    c1 = (710.0 - 385.0 - c2 * 1023.0**2) / 1023.0
    return (385.0, c1, c2, 0.0)


@dataclass(frozen=True)
class CornellConfig:
    """Physics of the simulated instrument (all values configurable).

    Solid angles in sr, times in s, rates in counts/s; ``wavelength_coeffs`` is the USB2000+-style
    polynomial λ(p) = c0 + c1 p + c2 p² + c3 p³ (nm) of pixel p.
    """

    kinematics: Kinematics = field(default_factory=Kinematics)
    source_solid_angle: float = 5e-4
    source_solid_angle_nominal: float | None = None  # the value the reduction assumes
    detector_solid_angle: float = 1e-4
    lamp_temperature_k: float = 3100.0
    n_pixels: int = 1024
    wavelength_coeffs: tuple[float, float, float, float] = field(default_factory=_default_coeffs)
    standard_peak_rate: float = 2.5e5  # counts/s, one polarisation, standard at reference pose
    bias_counts: float = 1500.0
    dark_rate: float = 100.0
    read_noise_counts: float = 20.0
    gain_e_per_count: float = 1.0
    saturation_counts: float = 65535.0
    stray_fraction: float = 1e-4  # stray rate relative to a perfect white diffuser's signal
    filter_transmission: float = 1e-3  # ND filter for the direct beam and mirror peaks
    reference_theta_i_deg: float = 10.0
    reference_theta_o_deg: float = 0.0
    t_min: float = 1e-3
    t_max: float = 10.0
    t_preview: float = 0.01
    exposure_target: float = 0.7  # fraction of the counts above bias aimed at
    quad_rings: int = 3
    quad_phi: int = 8
    skip_tol: float = 0.0  # convolution shortcut tolerance; 0 = off (module docstring: why)
    n_reference_reads: int = 16  # reads averaged for the reference (its noise is common to all)
    #: realised effect magnitudes of the true instrument (gonio.simulator.cornell_effects;
    #: None or all zero = the ideal instrument). The reduction uses :meth:`lab_view`.
    effects: Mapping[str, float] | None = None
    instrument_seed: int = 0  # draws of the realised instrument (tilt azimuths, stage noise)

    def __post_init__(self) -> None:
        if self.effects is not None:
            from gonio.simulator.cornell_effects import resolve_effects

            object.__setattr__(self, "effects", resolve_effects(dict(self.effects), 0))
        if not isinstance(self.instrument_seed, int | np.integer) or self.instrument_seed < 0:
            raise ValueError(f"instrument_seed = {self.instrument_seed!r}: expected an int >= 0")
        for name in (
            "source_solid_angle",
            "detector_solid_angle",
            "standard_peak_rate",
            "gain_e_per_count",
            "filter_transmission",
            "t_min",
            "t_preview",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} = {v!r}: expected a positive number")  # fmt: skip
        if not (self.t_min < self.t_max):
            raise ValueError(f"t_min = {self.t_min!r} must be below t_max = {self.t_max!r}")
        if int(self.n_pixels) != self.n_pixels or self.n_pixels < 64:
            raise ValueError(f"n_pixels = {self.n_pixels!r}: expected an integer >= 64")
        if self.skip_tol < 0:
            raise ValueError(f"skip_tol = {self.skip_tol!r}: expected >= 0")

    def lab_view(self) -> CornellConfig:
        """What the laboratory knows: this configuration without the true effects."""
        return self if self.effects is None else replace(self, effects=None)

    @property
    def omega_nominal(self) -> float:
        s = self.source_solid_angle_nominal
        return self.source_solid_angle if s is None else s

    def pixel_wavelengths(self, n_pixels: int | None = None) -> NDArray[np.float64]:
        p = np.arange(self.n_pixels if n_pixels is None else n_pixels, dtype=np.float64)
        c = self.wavelength_coeffs
        return c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3

    def reference_angles(self) -> NDArray[np.float64]:
        """Motor angles of the standard's reference geometry."""
        ti, to = np.radians(self.reference_theta_i_deg), np.radians(self.reference_theta_o_deg)
        wi = np.array([np.sin(ti), 0.0, np.cos(ti)])
        wo = np.array([-np.sin(to), 0.0, np.cos(to)])
        r = inverse(wi, wo, self.kinematics)
        if not bool(r.reachable):
            raise ValueError("the reference geometry is not reachable")
        return r.angles


# ----------------------------------------------------------------------------- cones


def _cone_rule(alpha: float, rings: int, nphi: int) -> tuple[NDArray, NDArray, NDArray]:
    """Equal-area product rule on a cap of half-angle ``alpha``: (r, phi, weight)."""
    xs, ws = np.polynomial.legendre.leggauss(rings)
    s = 0.5 * (xs + 1.0)
    r = alpha * np.sqrt(s)
    rr, pp, ww = [], [], []
    for k in range(rings):
        phi = (np.arange(nphi) + 0.5 * (k % 2)) * (2 * np.pi / nphi)
        rr.append(np.full(nphi, r[k]))
        pp.append(phi)
        ww.append(np.full(nphi, 0.5 * ws[k] / nphi))
    return np.concatenate(rr), np.concatenate(pp), np.concatenate(ww)


def _basis(w: NDArray) -> tuple[NDArray, NDArray]:
    a = np.where(np.abs(w[..., 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0, 0]))
    t1 = np.cross(a, w)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, np.cross(w, t1)


def _cone_points(w: NDArray, r: NDArray, phi: NDArray) -> NDArray:
    """Directions at angle r, azimuth phi around each w: (N, K, 3)."""
    t1, t2 = _basis(w)
    cr, sr = np.cos(r), np.sin(r)
    return (
        cr[None, :, None] * w[:, None, :]
        + (sr * np.cos(phi))[None, :, None] * t1[:, None, :]
        + (sr * np.sin(phi))[None, :, None] * t2[:, None, :]
    )


def _alpha(omega: float) -> float:
    return math.acos(1.0 - omega / (2.0 * math.pi))


def effective_cos(wi: ArrayLike, config: CornellConfig | None = None) -> NDArray[np.float64]:
    """Effective cosine of incidence of the source cone around ``wi`` (..., 3): the mean of
    ``max(cos θ, 0)`` over the cone (the instrument's quadrature rule), i.e. the irradiance
    per unit source radiance and solid angle. It replaces the centre's cos θi wherever the
    measurement divides by the irradiance (the standard's signal, the reduction, the cone
    average), so that a Lambertian sample reads exactly ρ/π against either reference (the
    centre cosine is higher by about α²/4 = 4e-5 for the 0.0005 sr source).
    """
    c = config or CornellConfig()
    w = np.asarray(wi, dtype=np.float64)
    flat = w.reshape(-1, 3)
    r, phi, wt = _cone_rule(_alpha(c.source_solid_angle), c.quad_rings, c.quad_phi)
    pts = _cone_points(flat, r, phi)
    return (np.clip(pts[:, :, 2], 0.0, None) @ wt).reshape(w.shape[:-1])


def _lens_area(d: NDArray, r1: float, r2: float) -> NDArray:
    """Area shared by two discs of radii r1, r2 whose centres are d apart."""
    d = np.asarray(d, dtype=np.float64)
    out = np.zeros_like(d)
    inside = d <= abs(r1 - r2)
    out[inside] = math.pi * min(r1, r2) ** 2
    part = (~inside) & (d < r1 + r2)
    if part.any():
        dd = d[part]
        a1 = np.arccos(np.clip((dd**2 + r1**2 - r2**2) / (2 * dd * r1), -1, 1))
        a2 = np.arccos(np.clip((dd**2 + r2**2 - r1**2) / (2 * dd * r2), -1, 1))
        tri = 0.5 * np.sqrt(
            np.clip((-dd + r1 + r2) * (dd + r1 - r2) * (dd - r1 + r2) * (dd + r1 + r2), 0, None)
        )
        out[part] = r1**2 * a1 + r2**2 * a2 - tri
    return out


@lru_cache(maxsize=16)
def _hat_projector(wl_key: tuple[float, ...], bands_key: tuple[float, ...]):
    wl = np.asarray(wl_key)
    bands = np.asarray(bands_key)
    step = float(np.min(np.diff(bands)))
    use = (wl >= bands[0] - 1e-9) & (wl <= bands[-1] + 1e-9)
    hat = np.clip(1.0 - np.abs(wl[use, None] - bands[None, :]) / step, 0.0, None)
    proj = np.linalg.pinv(hat)  # (n_bands, n_used)
    return use, proj


def read_sequence(first: str = "s") -> tuple[tuple[str, bool], ...]:
    """Order of the dark/signal reads of one geometry after the preview (shutter open,
    polariser ``first``): ``(polariser, shutter open)`` pairs — signal and dark through
    ``first``, then dark and signal through the other polariser. The shutter moves twice
    and the polariser once; the geometry ends open on the other polariser, where the next
    geometry's preview (``first`` alternating) reads. Shared by the simulator and the
    runner through the drivers (``gonio.campaign.drivers``), so their keyed noise matches.
    """
    if first not in _POL:
        raise ValueError(f"first = {first!r}: expected 's' or 'p'")
    other = "p" if first == "s" else "s"
    return ((first, True), (first, False), (other, False), (other, True))


def first_polarizer(index: int) -> str:
    """Polariser of the preview of geometry ``index`` of a campaign (alternating)."""
    return "s" if int(index) % 2 == 0 else "p"


def auto_exposure(
    read: Callable[..., NDArray], config: Any, target: str = "sample", polarizer: str = "s"
) -> tuple[float, bool]:
    """Preview read → ``(integration time, filter in)`` aiming at ``config.exposure_target``.

    ``read(t, polarizer=, target=, filter_in=)`` returns a raw spectrum: the simulator's own
    :meth:`CornellInstrument.read` or a spectrometer reached through the drivers
    (``gonio.campaign.drivers``), which thereby perform the same reads.
    """
    c = config
    room = c.exposure_target * (c.saturation_counts - c.bias_counts)
    filt = False
    for _ in range(2):
        prev = read(c.t_preview, polarizer=polarizer, target=target, filter_in=filt)
        peak = max(float(np.max(prev)) - c.bias_counts - c.dark_rate * c.t_preview, 1.0)
        if float(np.max(prev)) >= c.saturation_counts and not filt:
            filt = True
            continue
        t = room / (peak / c.t_preview)
        if t < c.t_min and not filt:
            filt = True
            continue
        return float(np.clip(round(t, 6), c.t_min, c.t_max)), filt
    return c.t_min, True


def measure_raw(
    read: Callable[..., NDArray], config: Any, target: str = "sample", n_reads: int = 1,
    first: str = "s",
) -> dict[str, dict[str, Any]]:  # fmt: skip
    """The reads of one geometry through ``read`` (see :func:`auto_exposure`): a preview
    through ``first``, then :func:`read_sequence`; each dark and signal spectrum is the mean
    of ``n_reads`` reads."""
    t, filt = auto_exposure(read, config, target, first)
    for _ in range(7):  # a saturated signal read (a polarising sample) is read again shorter
        reads: dict[tuple[str, bool], list] = {}
        for q, shutter in read_sequence(first):
            kw = dict(polarizer=q, target=target, filter_in=filt, shutter=shutter)
            reads[(q, shutter)] = [read(t, **kw) for _ in range(n_reads)]
        sat = any(np.max(r) >= config.saturation_counts for q in "sp" for r in reads[(q, True)])
        if not sat or t <= config.t_min:
            break
        t = max(config.t_min, round(0.3 * t, 6))
    return {
        q: {
            "signal": np.mean(reads[(q, True)], axis=0),
            "dark": np.mean(reads[(q, False)], axis=0),
            "t": t,
            "filter": int(filt),
        }
        for q in ("s", "p")
    }


# ----------------------------------------------------------------------------- reduction


@dataclass
class Reference:
    """Reference rates measured at the start of a campaign.

    ``rate[q]``: net counts/s per pixel of the standard (or of the direct beam, corrected for
    the ND filter) with the stray light removed; ``stray[q]``: beam-trap counts/s per pixel;
    ``mode``: ``"standard"`` or ``"direct"``; ``scale``: per-pixel factor turning a rate ratio
    into ``f · cos θi`` (``ρ_std(λ)/π · cos θi_ref`` for the standard, ``1/Ω_s`` for the
    direct beam).
    """

    mode: str
    wavelengths_nm: NDArray[np.float64]
    rate: dict[str, NDArray[np.float64]]
    stray: dict[str, NDArray[np.float64]]
    scale: NDArray[np.float64]
    meta: dict[str, Any] = field(default_factory=dict)


def remove_uniform_stray(rate: NDArray, fraction: float) -> NDArray:
    """Invert a uniform stray-light distribution: ``m = r + s mean(r)`` gives
    ``r = m - s mean(m) / (1 + s)`` (``rate`` per pixel, ``fraction`` = s >= 0)."""
    if not (fraction >= 0 and math.isfinite(fraction)):
        raise ValueError(f"stray_correction = {fraction!r}: expected a finite number >= 0")
    m = np.asarray(rate, float)
    return m - fraction * float(np.mean(m)) / (1.0 + fraction)


def _net_rate(signal, dark, t, transmission, config):
    net = (np.asarray(signal, float) - np.asarray(dark, float)) / (t * transmission)
    var = (
        np.clip(np.asarray(signal, float) - config.bias_counts, 0, None) / config.gain_e_per_count
        + np.clip(np.asarray(dark, float) - config.bias_counts, 0, None) / config.gain_e_per_count
        + 2 * config.read_noise_counts**2
    ) / (t * transmission) ** 2
    return net, var


def reduce_measurement(
    reads: Mapping[str, Mapping[str, Any]],
    reference: Reference,
    cos_theta_i: float,
    config: CornellConfig | None = None,
    bands_nm: ArrayLike = BANDS_NM,
    stray_correction: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], bool]:
    """Raw spectra of one geometry → ``(BRDF per band, standard error per band, saturated)``.

    ``cos_theta_i``: the effective cosine of incidence (:func:`effective_cos` of the
    incidence direction; the centre's cos θi would read a Lambertian 4e-5 high).
    ``reads[q]`` for ``q`` in ``("s", "p")`` holds ``signal`` and ``dark`` (counts per pixel),
    ``t`` (integration time, s) and ``filter`` (0 or 1). Pure function: the campaign runner
    that goes through the drivers calls it with the spectra it read.

    ``stray_correction`` = s > 0: the laboratory's in-spectrometer stray-light fraction (a
    uniform stray-light distribution, each pixel reading s x the mean signal), removed from
    the sample's and the reference's net rates by :func:`remove_uniform_stray` (the exact
    inverse of that distribution: Zong et al. 2006's correction matrix for a uniform
    distribution).

    References
    ----------
    Zong, Y., Brown, S. W., Johnson, B. C., Lykke, K. R., Ohno, Y. (2006). Simple spectral
    stray light correction method for array spectroradiometers. Applied Optics 45(6),
    1111-1119, doi:10.1364/AO.45.001111.
    """
    config = config or CornellConfig()
    if cos_theta_i <= 0:
        raise ValueError(f"cos_theta_i = {cos_theta_i!r}: expected > 0")
    fs, vs = [], []
    saturated = False
    for q in ("s", "p"):
        if q not in reads:
            raise ValueError(f"reads lacks polarisation {q!r}; expected keys 's' and 'p'")
        r = reads[q]
        tr = config.filter_transmission if r.get("filter", 0) else 1.0
        saturated |= bool(np.any(np.asarray(r["signal"]) >= config.saturation_counts))
        net, var = _net_rate(r["signal"], r["dark"], float(r["t"]), tr, config)
        net = net - reference.stray[q]
        ref_rate = reference.rate[q]
        if stray_correction:
            net = remove_uniform_stray(net, stray_correction)
            ref_rate = remove_uniform_stray(ref_rate, stray_correction)
        k = reference.scale / ref_rate / cos_theta_i
        fs.append(net * k)
        vs.append(var * k * k)
    f = 0.5 * (fs[0] + fs[1])
    v = 0.25 * (vs[0] + vs[1])
    use, proj = _hat_projector(
        tuple(np.round(reference.wavelengths_nm, 9)), tuple(np.asarray(bands_nm, float))
    )
    vals = proj @ f[use]
    sig = np.sqrt((proj * proj) @ v[use])
    return vals, sig, saturated


# ----------------------------------------------------------------------------- instrument


def _seed_from(rng: int | np.random.Generator | None) -> int:
    if isinstance(rng, np.random.Generator):
        return int(rng.integers(0, 2**63 - 1))
    if rng is None:
        return int(np.random.SeedSequence().entropy % (2**63))
    if isinstance(rng, (int, np.integer)) and rng >= 0:
        return int(rng)
    raise ValueError(f"rng = {rng!r}: expected a non-negative int, a Generator or None")


class CornellInstrument(TrueInstrument):
    """The simulated instrument: a sample BRDF, the physics config and a seeded noise source.

    Parameters
    ----------
    sample : BRDF, registered model name, material preset name or callable
        What is on the sample holder.
    config : CornellConfig, optional
    noise : bool
        False: no shot, read or dark noise (the bias, dark current and stray light remain and
        are removed by the reduction).
    rng : int, Generator or None
        Seed of the keyed noise.
    """

    axes = AXES

    def __init__(
        self,
        sample: BRDF | str | Any,
        *,
        config: CornellConfig | None = None,
        noise: bool = True,
        rng: int | np.random.Generator | None = None,
    ) -> None:
        self.config = config or CornellConfig()
        self.sample = _as_sample(sample)
        self.noise = bool(noise)
        self.seed = _seed_from(rng)
        self._counter: dict[tuple, int] = {}
        self._conv_cache: dict[tuple, tuple[NDArray, float]] = {}
        self._k_cache: dict[tuple, NDArray] = {}
        self.angles = np.zeros(3)
        self.stats = {"conv_full": 0, "conv_skipped": 0}
        self._white = (
            self.config.standard_peak_rate
            * math.pi
            / (0.99 * math.cos(math.radians(self.config.reference_theta_i_deg)))
        )
        c = self.config
        self._std = as_brdf("lambert", rho=1.0)
        self._alpha_s, self._alpha_d = _alpha(c.source_solid_angle), _alpha(c.detector_solid_angle)
        self._rule_s = _cone_rule(self._alpha_s, c.quad_rings, c.quad_phi)
        self._rule_d = _cone_rule(self._alpha_d, c.quad_rings, c.quad_phi)
        self.fx = c.effects  # None: the ideal instrument (every effect path skipped)
        #: the lamp's clock advanced by each read and move this instrument sees (set for the
        #: instrument behind the fake devices; in-process campaigns advance it per geometry)
        self.event_clock = False
        if self.fx is not None:
            self._fx_setup()

    # ------------------------------------------------------------------ geometry
    @property
    def pixel_wavelengths(self) -> NDArray[np.float64]:
        """Wavelength (nm) of each spectrometer pixel (read-only; computed once)."""
        wl = self.__dict__.get("_pixel_wl")
        if wl is None:
            wl = self.config.pixel_wavelengths()
            wl.setflags(write=False)
            self._pixel_wl = wl
        return wl

    @property
    def sample_wavelengths(self) -> NDArray[np.float64] | None:
        return self.sample.wavelengths_nm

    def move_to(self, angles: ArrayLike) -> None:
        """Set the motor angles (radians, order :data:`AXES`), checking the stage limits."""
        a = np.asarray(angles, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all():
            raise ValueError(f"angles = {angles!r}: expected 3 finite angles (radians)")
        if not self.config.kinematics.within_limits(a):
            raise ValueError(f"angles = {np.degrees(a).tolist()} deg are outside the stage limits")
        if self.fx is not None:
            self._fx_move(a)  # backlash and positioning noise: the true (load) angles
        self.angles = a.copy()

    # ------------------------------------------------------------------ radiometry
    def expected_brdf(
        self, angles: ArrayLike, *, convolve: bool | None = None, brdf: BRDF | None = None
    ) -> NDArray[np.float64]:
        """Cone-averaged BRDF the instrument measures at motor ``angles`` (N, 3):
        ``∫∫ f cos θ dω_s dω_d / (Ω_d ∫ cos θ dω_s)`` over the source and detector cones
        (the reduction divides by the effective cosine, :func:`effective_cos`).

        Shape ``(N,)`` for a grey sample, ``(N, n_bands)`` for a spectral one (the sample's
        bands). ``convolve``: None = adaptive skip (``config.skip_tol``), True = always
        integrate over the cones, False = centre value only.
        """
        m = brdf or self.sample
        a = np.atleast_2d(np.asarray(angles, dtype=np.float64))
        wi, wo = forward(a, self.config.kinematics)
        ci = effective_cos(wi, self.config)  # the irradiance the cone average divides by
        fc = m.evaluate_unchecked(wi, wo)
        out = np.array(fc, dtype=np.float64, copy=True)
        if convolve is not False:
            if convolve is None and self.config.skip_tol > 0:
                need = self._cone_needed(m, wi, wo, fc)
            else:
                need = np.ones(len(a), bool)
            idx = np.flatnonzero(need)
            self.stats["conv_full"] += int(idx.size)
            self.stats["conv_skipped"] += int(len(a) - idx.size)
            self._cone_average(m, wi, wo, ci, idx, out)
        if m.has_delta:
            out = out + self._delta_part(m, wi, wo, ci)
        return out

    def _cone_needed(self, m: BRDF, wi: NDArray, wo: NDArray, fc: NDArray) -> NDArray:
        """Which geometries the cone average changes by more than ``config.skip_tol`` of
        the centre value ``fc`` (the adaptive skip of :meth:`expected_brdf`)."""
        k4 = np.arange(4) * (np.pi / 2)
        rim_i = _cone_points(wi, np.full(4, self._alpha_s), k4)
        rim_o = _cone_points(wo, np.full(4, self._alpha_d), k4 + np.pi / 4)
        f1 = m.evaluate_unchecked(rim_i, wo[:, None, :])
        f2 = m.evaluate_unchecked(wi[:, None, :], rim_o)
        # second differences across each cone: the cone mean of a quadratic differs
        # from the centre value by half the mean rim deviation (mean r² = α²/2)
        c0 = fc[:, None]
        d1 = 0.5 * (f1[:, :2] + f1[:, 2:]) - c0
        d2 = 0.5 * (f2[:, :2] + f2[:, 2:]) - c0
        err = 0.5 * (np.abs(d1).max(axis=1) + np.abs(d2).max(axis=1))
        return (err > self.config.skip_tol * np.abs(fc)).reshape(len(wi), -1).any(axis=1)

    def _cone_average(self, m, wi, wo, ci, idx: NDArray, out: NDArray) -> None:
        """``out[idx]``: the BRDF averaged over the source and detector cones (quadrature
        rules ``_rule_s``, ``_rule_d``) and divided by the effective cosine ``ci``."""
        rs, ps, ws = self._rule_s
        rd, pd, wd = self._rule_d
        for chunk in np.array_split(idx, max(1, idx.size // 256)):
            if chunk.size == 0:
                continue
            pi = _cone_points(wi[chunk], rs, ps)  # (M, Ks, 3)
            po = _cone_points(wo[chunk], rd, pd)  # (M, Kd, 3)
            f = m.evaluate_unchecked(pi[:, :, None, :], po[:, None, :, :])
            wgt = ws[:, None] * wd[None, :] * np.clip(pi[:, :, 2], 0, None)[:, :, None]
            if f.ndim == 4:
                s = np.einsum("mijb,mij->mb", f, wgt)
            else:
                s = np.einsum("mij,mij->m", f, wgt)
            s = s / np.where(ci[chunk] > 0, ci[chunk], 1.0).reshape((-1,) + (1,) * (s.ndim - 1))
            out[chunk] = s

    def _delta_part(self, m: BRDF, wi: NDArray, wo: NDArray, ci: NDArray) -> NDArray:
        """The mirror component's share of the measured BRDF: its reflectance times the
        overlap of the source cone's mirror image with the detector cone."""
        d, rho = m.delta(wi)
        beta = np.arccos(np.clip(np.sum(d * wo, -1), -1, 1))
        area = _lens_area(beta, self._alpha_s, self._alpha_d)
        c = self.config
        # A/(Ω_s Ω_d), the planar lens area rescaled to solid angle (exact when inside)
        w = area / (math.pi * self._alpha_d**2 * c.source_solid_angle)
        w = w / np.where(ci > 0, ci, 1.0)
        return rho * w[:, None] if rho.ndim == 2 else rho * w

    def _conv_at(self, angles: NDArray) -> tuple[NDArray, float]:
        """Cone-averaged BRDF and effective cos θi at one pose (cached by the pose)."""
        key = tuple(np.round(np.degrees(angles), 6).tolist())
        v = self._conv_cache.get(key)
        if v is None:
            self.prime(angles[None])
            v = self._conv_cache[key]
        return v

    def prime(self, angles: ArrayLike) -> None:
        """Precompute (vectorised) the cone-averaged BRDF at many poses before reading them."""
        a = np.atleast_2d(np.asarray(angles, dtype=np.float64))
        if self.fx is not None:
            vals, ci = self._fx_expected(a)
        else:
            vals = self.expected_brdf(a)
            ci = effective_cos(forward(a, self.config.kinematics)[0], self.config)
        if len(self._conv_cache) > 200_000:
            self._conv_cache.clear()
        for ang, v, c in zip(a, vals, ci):
            self._conv_cache[tuple(np.round(np.degrees(ang), 6).tolist())] = (v, float(c))

    def _spectral_k(self, wl: NDArray, q: str | None) -> NDArray:
        key = (wl.shape[0], float(wl[0]), float(wl[-1]), q)
        k = self._k_cache.get(key)
        if k is None:
            c = self.config
            k = self._white * halogen_spectrum(wl, c.lamp_temperature_k) * detector_response(wl, q)
            if q is not None:
                k = 0.5 * k
            self._k_cache[key] = k
        return k

    def _f_pixels(self, f_bands: Any, wl: NDArray) -> NDArray:
        sw = self.sample.wavelengths_nm
        if sw is None or np.ndim(f_bands) == 0:
            return np.full(wl.shape, float(f_bands))
        return np.interp(wl, sw, f_bands)

    # ------------------------------------------------------------------ raw spectra
    def expected_counts(
        self,
        positions: Mapping[str, float],
        integration_time_s: float,
        wavelengths_nm: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Noise-free counts per pixel for a read (see :meth:`spectrum_render`)."""
        c = self.config
        wl = self.pixel_wavelengths if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
        t = float(integration_time_s)
        if not (t > 0 and math.isfinite(t)):
            raise ValueError(f"integration_time_s = {integration_time_s!r}: expected > 0")
        try:
            ang = np.radians([float(positions[k]) for k in AXES])
        except KeyError as exc:
            raise ValueError(
                f"positions lacks stage {exc.args[0]!r}; expected keys {list(AXES)}"
            ) from None
        pol = positions.get("polarizer")
        q = None if pol is None else ("s" if abs(float(pol) % 180.0) < 45.0 else "p")
        shutter = float(positions.get("shutter", 1.0)) >= 0.5
        target = round(float(positions.get("target", 0.0)))
        filt = float(positions.get("filter", 0.0)) >= 0.5
        if target not in TARGETS.values():
            raise ValueError(f"target = {target!r}: expected one of {TARGETS}")
        blocked = abs(_wrap_deg(float(positions["arm"]))) < math.degrees(c.kinematics.retro_cone)
        if self.fx is not None:
            # the references' repeated reads (n_reference_reads of each spectrum, the lamp's
            # clock standing still) have the same noise-free counts: computed once
            key = (*(float(positions[k]) for k in AXES), t, q, shutter, target, filt, blocked,
                   self.clock_s, wl.tobytes())  # fmt: skip
            last = self._last_counts
            if last is not None and last[0] == key and target != TARGETS["sample"]:
                return last[1]
            counts = self._fx_counts(positions, t, wl, target, q, shutter, filt, blocked)
            self._last_counts = (key, counts)
            return counts
        counts = np.full(wl.shape, c.bias_counts + c.dark_rate * t)
        if not shutter:
            return counts
        k = self._spectral_k(wl, q)
        if blocked and target in (TARGETS["sample"], TARGETS["standard"]):
            sig = np.zeros(wl.shape)  # the arm sits between the sample and the folding mirror
        elif target == TARGETS["sample"]:
            fconv, ci = self._conv_at(ang)
            sig = k * self._f_pixels(fconv, wl) * max(ci, 0.0)
        elif target == TARGETS["standard"]:
            wi, _ = forward(ang, c.kinematics)
            ce = float(effective_cos(wi, c))  # the standard sees the whole source cone too
            sig = k * spectralon_reflectance(wl) / math.pi * ce
        elif target == TARGETS["direct"]:
            sig = k / c.source_solid_angle
        else:
            sig = np.zeros(wl.shape)
        stray = c.stray_fraction * k / math.pi
        tr = c.filter_transmission if filt else 1.0
        return counts + t * tr * (sig + stray)

    def spectrum_render(
        self,
        positions: Mapping[str, float],
        integration_time_s: float,
        wavelengths_nm: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Raw counts per pixel (clipped to 0..65535; whole numbers unless ``noise`` is off).

        ``positions`` (degrees, the bench's stage units): ``"arm"``, ``"turntable"``,
        ``"tilt"``; optional ``"polarizer"`` (0 = s, 90 = p, absent = no polariser),
        ``"shutter"`` (1 open, 0 closed), ``"target"`` (0 sample, 1 standard, 2 beam trap,
        3 direct beam), ``"filter"`` (1 = ND filter in). With ``|arm|`` inside the 7° retro cone
        the arm blocks the view of the sample (no signal, stray light only). ``wavelengths_nm``:
        the pixels (default the instrument's own). This is the ``spectrum_render`` of
        ``gonio.simulator.bench.Bench``.
        """
        c = self.config
        wl = self.pixel_wavelengths if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
        tick = self.fx is not None and self.event_clock
        if tick:  # behind the fake devices: the lamp's clock runs with the reads and moves
            self._fx_tick_move(positions)
        mean = self.expected_counts(positions, integration_time_s, wl)
        if tick:
            self._fx_tick_read(integration_time_s)
        if self.noise:
            key = (
                *(round(float(positions[k]) * 1e4) + 2**40 for k in AXES),
                round(float(integration_time_s) * 1e6),
                round(float(positions.get("polarizer", -1.0))) + 1000,
                int(float(positions.get("shutter", 1.0)) >= 0.5),
                round(float(positions.get("target", 0.0))),
                int(float(positions.get("filter", 0.0)) >= 0.5),
                int(wl.shape[0]),
            )
            n = self._counter.get(key, 0)
            self._counter[key] = n + 1
            g = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(*key, n)))
            elec = np.clip(mean - c.bias_counts, 0, None) * c.gain_e_per_count
            elec = g.poisson(elec) / c.gain_e_per_count
            mean = c.bias_counts + elec + g.normal(0.0, c.read_noise_counts, wl.shape)
            mean = np.rint(mean)  # the ADC (part of the noise: noise=False is an ideal detector)
        return np.clip(mean, 0.0, c.saturation_counts)

    def _pos(self) -> dict[str, float]:
        """Where the stages really are, in degrees, with the sample in view."""
        a = self.angles if self.fx is None else self.true_angles
        return {k: float(np.degrees(v)) for k, v in zip(AXES, a)}

    def read(
        self,
        integration_time_s: float,
        *,
        polarizer: str | None = "s",
        shutter: bool = True,
        target: str = "sample",
        filter_in: bool = False,
        angles: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """One raw spectrum at the current motor angles (or ``angles``): the per-read primitive."""
        if target not in TARGETS:
            raise ValueError(f"target = {target!r}: expected one of {sorted(TARGETS)}")
        if polarizer is not None and polarizer not in _POL:
            raise ValueError(f"polarizer = {polarizer!r}: expected 's', 'p' or None")
        if angles is not None:
            a = np.asarray(angles, float)
        else:  # where the stages really are (backlash, positioning noise)
            a = self.angles if self.fx is None else self.true_angles
        pos = {k: float(np.degrees(v)) for k, v in zip(AXES, a)}
        pos.update(shutter=float(shutter), target=float(TARGETS[target]), filter=float(filter_in))
        if polarizer is not None:
            pos["polarizer"] = _POL[polarizer]
        return self.spectrum_render(pos, integration_time_s)

    # ------------------------------------------------------------------ procedures
    def auto_exposure(self, target: str = "sample", polarizer: str = "s") -> tuple[float, bool]:
        """Preview read → ``(integration time, filter in)`` aiming at ``exposure_target``.

        The preview is read through ``polarizer`` (the one in place, so that it need not
        turn); the longer time is then the one of the brighter polarisation within a few
        per cent (the detector's s/p responses differ little), well inside the head room.
        """
        if polarizer not in _POL:
            raise ValueError(f"polarizer = {polarizer!r}: expected 's' or 'p'")
        return auto_exposure(self.read, self.config, target, polarizer)

    def measure_raw(
        self, target: str = "sample", n_reads: int = 1, first: str = "s"
    ) -> dict[str, dict[str, Any]]:
        """The reads of one geometry (:func:`read_sequence`): a preview through the
        polariser ``first``, signal and dark through it, then dark and signal through the
        other one — two shutter moves and one polariser turn per geometry. Campaigns
        alternate ``first`` from geometry to geometry, so the polariser never turns back.

        With ``n_reads > 1`` each dark and signal spectrum is the mean of that many reads.
        """
        return measure_raw(self.read, self.config, target, n_reads, first)

    def calibrate(self, mode: str = "standard", stray: Reference | None = None) -> Reference:
        """Reference measurement: the standard at the reference pose or the direct beam, plus
        the beam trap for stray light (taken from ``stray`` instead when given: a
        re-measured reference during a campaign does not repeat the beam trap)."""
        c = self.config.lab_view()  # what the laboratory computes with
        wl = self.pixel_wavelengths
        saved = self.angles.copy()
        fx_state = self._fx_state() if self.fx is not None else None
        if mode == "standard":
            self.move_to(c.reference_angles())
            target = "standard"
            cos_ref = float(effective_cos(forward(self.angles, c.kinematics)[0], c))
            scale = spectralon_reflectance(wl) / math.pi * cos_ref
        elif mode == "direct":
            self.move_to(np.array([np.pi, 0.0, 0.0]))
            target = "direct"
            scale = np.full(wl.shape, 1.0 / c.omega_nominal)
        else:
            raise ValueError(f"reference mode = {mode!r}: expected 'standard' or 'direct'")
        ref = reference_reads(self.read, c, mode, target, wl, scale, stray)
        self.angles = saved
        if fx_state is not None:
            self._fx_restore(fx_state)  # back where the stages were before the reference
        return ref


def reference_reads(
    read: Callable[..., NDArray], c: Any, mode: str, target: str, wl: NDArray, scale: NDArray,
    stray: Reference | None = None,
) -> Reference:  # fmt: skip
    """The reads of a reference at the pose the stages are in, through ``read`` (the
    simulator's or a spectrometer's through the drivers): the standard or direct beam
    (``c.n_reference_reads`` averaged reads, :func:`measure_raw`), then the beam trap at
    ``t_max`` for the stray light, averaged alike (taken from ``stray`` instead when given:
    a re-measured reference does not repeat the beam trap)."""
    n_avg = max(1, int(c.n_reference_reads))
    raws = measure_raw(read, c, target, n_avg, "s")  # ends on "p"
    traps: dict[tuple[str, bool], NDArray] = {}  # (ends on "s", open)
    for q, shutter in read_sequence("p") if stray is None else ():
        kw = dict(polarizer=q, target="beam_trap", shutter=shutter)
        traps[(q, shutter)] = np.mean([read(c.t_max, **kw) for _ in range(n_avg)], 0)
    stray_rate, rate = {}, {}
    for q in ("s", "p"):
        if stray is None:
            stray_rate[q] = _net_rate(traps[(q, True)], traps[(q, False)], c.t_max, 1.0, c)[0]
        else:
            stray_rate[q] = stray.stray[q]
        r = raws[q]
        tr = c.filter_transmission if r["filter"] else 1.0
        rate[q] = _net_rate(r["signal"], r["dark"], r["t"], tr, c)[0] - stray_rate[q]
    return Reference(mode, wl, rate, stray_rate, scale, {"t": raws["s"]["t"]})


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _as_sample(sample: Any) -> BRDF:
    if isinstance(sample, str):
        from gonio import brdf, materials

        if sample in brdf.names():
            return brdf.create(sample)
        return materials.get(sample)
    return as_brdf(sample)


# ----------------------------------------------------------------------------- campaign


def simulate_campaign(
    plan: Plan | str,
    sample: BRDF | str | Any,
    *,
    rng: int | np.random.Generator | None = 0,
    noise: bool = True,
    reference: str = "standard",
    config: CornellConfig | None = None,
    order: bool = True,
    timing: Timing | None = None,
    reference_every: int = 0,
    drift_correction: bool = True,
    stray_correction: float = 0.0,
    references: list[tuple[float, Reference]] | None = None,
) -> BRDFSamples:
    """Measure ``sample`` along ``plan`` (``"hemispherical"``, ``"incidence_plane"`` or a Plan).

    Returns a spectral :class:`~gonio.samples.BRDFSamples` (one row per reachable geometry and
    band, ``wavelength_nm`` column; directions are the commanded ones, from the motor angles).
    ``metadata`` records the instrument, the reference, the number of cone integrations skipped,
    the integration times and the estimated real-instrument run time.

    ``config`` is the true instrument (its ``effects``); the reduction uses its
    :meth:`CornellConfig.lab_view`. ``reference_every = N > 0`` re-measures the standard
    after every N geometries and at the end (the beam trap only once); with
    ``drift_correction`` each geometry is reduced against the reference interpolated
    linearly in campaign time between the two that bracket it (the lamp's drift and
    warm-up divided out), else against the first. ``stray_correction``: the laboratory's
    in-spectrometer stray-light fraction, removed by :func:`reduce_measurement`.
    ``references``: a list to receive the ``(campaign seconds, Reference)`` pairs measured
    (the first at 0 s).
    """
    if isinstance(plan, str):
        makers = {"hemispherical": hemispherical_plan, "incidence_plane": incidence_plane_plan}
        if plan not in makers:
            raise ValueError(f"plan = {plan!r}: expected one of {sorted(makers)} or a Plan")
        plan = makers[plan](kin=(config or CornellConfig()).kinematics)
    if int(reference_every) != reference_every or reference_every < 0:
        raise ValueError(f"reference_every = {reference_every!r}: expected an integer >= 0")
    inst = CornellInstrument(sample, config=config, noise=noise, rng=rng)
    lab = inst.config.lab_view()
    ref = inst.calibrate(reference)
    p = order_plan(plan, timing) if order else plan.measurable()
    inst.prime(p.angles if inst.fx is None else inst.true_angles_of(p.angles))
    wl_bands = BANDS_NM
    nb = len(wl_bands)
    wi, wo = forward(p.angles, lab.kinematics)
    ce = effective_cos(wi, lab)
    vals, sigs, t_int, n_sat, refs = _measure_plan(
        inst, p, lab, ref, ce, reference, timing or Timing(), reference_every,
        drift_correction, stray_correction, references,
    )  # fmt: skip
    if not noise:
        sigs[:] = np.nan  # no noise: standard errors unknown (not zero), as gonio.fit expects
    meta = _campaign_metadata(inst, p, sample, reference, noise, timing, t_int, n_sat, refs,
                              reference_every)  # fmt: skip
    rep = np.repeat
    return BRDFSamples.from_directions(
        rep(wi, nb, axis=0),
        rep(wo, nb, axis=0),
        vals.ravel(),
        sigs.ravel(),
        wavelength_nm=np.tile(wl_bands, len(p)),
        metadata=meta,
    )


def _measure_plan(
    inst, p, lab, ref, ce, reference, tm, reference_every, drift_correction,
    stray_correction, references,
) -> tuple[NDArray, NDArray, NDArray, int, list[tuple[float, Reference]]]:  # fmt: skip
    """Every geometry of ``p`` measured in order and reduced (``ce``: the effective cosines
    of the laboratory's view ``lab``): ``(values, standard errors, integration times, saturated
    count, references)``. With ``reference_every`` the standard is measured again on the
    instrument's clock, and with ``drift_correction`` each geometry reduced against the
    reference interpolated to its time (see :func:`simulate_campaign`)."""
    wl_bands = BANDS_NM
    nb = len(wl_bands)
    vals = np.empty((len(p), nb))
    sigs = np.empty((len(p), nb))
    t_int = np.empty(len(p))
    n_sat = 0
    refs = [(0.0, ref)]
    pending: list[tuple[int, float, dict]] = []
    prev = np.zeros(3)
    for j, ang in enumerate(p.angles):
        inst.move_to(ang)
        raws = inst.measure_raw("sample", first=first_polarizer(j))
        t_int[j] = raws["s"]["t"]
        if inst.fx is not None or reference_every:
            inst.advance_clock(_geometry_seconds(tm, ang - prev, t_int[j]))
            prev = ang
        if reference_every and drift_correction:
            pending.append((j, inst.clock_s, raws))
        else:
            v, s, sat = reduce_measurement(raws, ref, float(ce[j]), lab, wl_bands, stray_correction)
            vals[j], sigs[j] = v, s
            n_sat += int(sat)
        if reference_every and ((j + 1) % reference_every == 0 or j + 1 == len(p)):
            inst.advance_clock(_reference_seconds(tm, lab, ref))
            refs.append((inst.clock_s, inst.calibrate(reference, stray=ref)))
    if references is not None:
        references.extend(refs)
    for j, tj, raws in pending:
        rj = _interpolated_reference(refs, tj)
        v, s, sat = reduce_measurement(raws, rj, float(ce[j]), lab, wl_bands, stray_correction)
        vals[j], sigs[j] = v, s
        n_sat += int(sat)
    return vals, sigs, t_int, n_sat, refs


def _campaign_metadata(
    inst: Any,
    p: Plan,
    sample: Any,
    reference: str,
    noise: bool,
    timing: Timing | None,
    t_int: NDArray,
    n_sat: int,
    refs: list,
    reference_every: int,
) -> dict[str, Any]:
    """The metadata :func:`simulate_campaign` records: the instrument, the reference, the
    cone integrations skipped, the integration times and the estimated run time."""
    ref_s = _reference_seconds(timing or Timing(), inst.config, refs[0][1])
    est = estimate_run_time(p, timing, t_int, reference_every=reference_every, reference_s=ref_s)
    meta = {
        "instrument": "cornell",
        "sample": sample if isinstance(sample, str) else getattr(inst.sample, "name", "callable"),
        "reference": reference,
        "noise": bool(noise),
        "seed": inst.seed,
        "plan": p.meta,
        "n_geometries": len(p),
        "n_saturated": n_sat,
        "conv_full": inst.stats["conv_full"],
        "conv_skipped": inst.stats["conv_skipped"],
        "integration_s_median": float(np.median(t_int)) if len(p) else 0.0,
        "estimated_run_time_h": est["total_h"],
        "estimated_run_time_u_h": est["total_u_h"],
    }  # (no wall-clock time: the samples of two identical runs are identical bytes)
    if reference_every:
        meta["n_references"] = len(refs)
        meta["reference_drift"] = _reference_drift(refs)
    if inst.fx is not None or reference_every:
        meta["campaign_clock_h"] = inst.clock_s / 3600.0
    return meta


def _geometry_seconds(tm: Timing, delta: NDArray, t: float) -> float:
    """Real-instrument time of one geometry (the run-time estimate's schedule)."""
    per = tm.settle_s + tm.preview_s + tm.read_overhead_s + tm.polarizer_change_s
    return float(tm.move_time(delta[None])[0] + per + 4.0 * (t + tm.read_overhead_s))


def _reference_seconds(tm: Timing, c: CornellConfig, ref: Reference) -> float:
    """Real-instrument time of a re-measured standard
    (:func:`gonio.simulator.cornell_plans.reference_seconds` at the reference's integration
    time and ``n_reference_reads``)."""
    return reference_seconds(tm, float(ref.meta.get("t", 1.0)), c.n_reference_reads)


def _interpolated_reference(refs: list[tuple[float, Reference]], t: float) -> Reference:
    """The reference rates interpolated linearly in time between the two references around
    ``t`` (clamped at the ends)."""
    times = np.array([r[0] for r in refs])
    k = int(np.clip(np.searchsorted(times, t) - 1, 0, len(refs) - 2))
    (ta, ra), (tb, rb) = refs[k], refs[k + 1]
    w = float(np.clip((t - ta) / (tb - ta), 0.0, 1.0)) if tb > ta else 0.0
    rate = {q: (1 - w) * ra.rate[q] + w * rb.rate[q] for q in ra.rate}
    return replace(ra, rate=rate)


def _reference_drift(refs: list[tuple[float, Reference]]) -> list[list[float]]:
    """(hours, mean rate / first mean rate) of each reference measurement."""
    r0 = float(np.mean(refs[0][1].rate["s"] + refs[0][1].rate["p"]))
    return [[t / 3600.0, float(np.mean(r.rate["s"] + r.rate["p"])) / r0] for t, r in refs]


def accuracy_check(
    sample: BRDF | str | Any,
    plan: Plan | None = None,
    *,
    config: CornellConfig | None = None,
    floor: float = 1e-3,
) -> dict[str, Any]:
    """Noise-free campaign of ``sample`` compared with the model at the reached directions.

    Returns the largest relative differences of the measured values from (a) the cone-averaged
    model (:meth:`CornellInstrument.expected_brdf`: what the instrument should read) and (b) the
    plain model ``sample(wi, wo)`` away from the mirror peak, over values above ``floor`` × the
    band's maximum, plus how many cone integrations were skipped. Default plan: the
    hemispherical plan at θi = 10°…80° on a 9 × 9 grid.
    """
    config = config or CornellConfig()
    plan = plan if plan is not None else hemispherical_plan(n=9, kin=config.kinematics)
    p = plan.measurable()
    s = simulate_campaign(p, sample, noise=False, rng=0, config=config, order=False)
    inst = CornellInstrument(sample, config=config, noise=False, rng=0)
    conv = inst.expected_brdf(p.angles)
    nb = len(BANDS_NM)
    meas = s.value.reshape(len(p), nb)
    conv = conv if conv.ndim == 2 else np.repeat(conv[:, None], nb, axis=1)
    plain = inst.sample(s.wi.reshape(len(p), nb, 3)[:, 0], s.wo.reshape(len(p), nb, 3)[:, 0])
    plain = plain if plain.ndim == 2 else np.repeat(plain[:, None], nb, axis=1)
    big = conv > floor * conv.max(axis=0, keepdims=True)
    rel_conv = np.abs(meas - conv)[big] / conv[big]
    mirror = np.zeros(len(p), bool)
    if inst.sample.has_delta:
        wi, wo = forward(p.angles, config.kinematics)
        d, rho = inst.sample.delta(wi)
        beta = np.arccos(np.clip(np.sum(d * wo, -1), -1, 1))
        mirror = (beta < inst._alpha_s + inst._alpha_d) & (np.max(np.atleast_2d(rho.T), 0) > 0)
    ok = big & (plain > 0) & ~mirror[:, None]
    rel_plain = np.abs(meas - plain)[ok] / plain[ok]
    return {
        "n_geometries": len(p),
        "max_rel_vs_cone_averaged": float(rel_conv.max()) if rel_conv.size else 0.0,
        "max_rel_vs_model": float(rel_plain.max()) if rel_plain.size else 0.0,
        "median_rel_vs_model": float(np.median(rel_plain)) if rel_plain.size else 0.0,
        "n_mirror_rows": int(mirror.sum()),
        "conv_full": s.metadata["conv_full"],
        "conv_skipped": s.metadata["conv_skipped"],
    }


def bench_renderers(
    material: str | None = None,
    *,
    rng: int | np.random.Generator | None = 0,
    noise: bool = True,
    config: CornellConfig | None = None,
):
    """``(camera_render, spectrum_render)`` for ``Bench.for_instrument("cornell")``.

    The Cornell instrument has no camera (``None``). ``material`` defaults to
    ``"garnet_red_paint"``. The instrument object is reachable as
    ``spectrum_render.__self__``.
    """
    inst = CornellInstrument(material or "garnet_red_paint", config=config, noise=noise, rng=rng)
    return None, inst.spectrum_render


def with_config(config: CornellConfig, **changes: Any) -> CornellConfig:
    """A copy of ``config`` with some fields changed (``dataclasses.replace``)."""
    return replace(config, **changes)
