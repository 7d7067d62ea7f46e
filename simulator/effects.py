"""The imperfections of the LBL imaging gonioreflectometer, as named, parameterised effects.

Every effect is one magnitude (a float with a unit and a physically valid range,
:data:`EFFECTS`); zero switches it off and skips its work, so an instrument with every
magnitude at zero is the ideal instrument, bit for bit. A *preset* (:data:`PRESETS`) states
each effect as a :class:`Distribution` (a typical magnitude and its spread between
instruments); :func:`realise` draws the magnitudes of one physical instrument from it, so
that different seeds are different instruments (as in different laboratories). Effects
with a spatial or per-setting realisation (the dome's figure-error map, the standard's true
deviation within its certificate, each f-stop's error) are drawn deterministically from the
realised magnitudes and the instrument seed by the instrument itself
(:class:`gonio.simulator.lbl.LBLInstrument`).

The presets:

``ideal``
    Every effect zero: today's ideal instrument.
``ward1992``
    Ward's prototype (Ward 1992 §3, §3.3): a thermoformed acrylic dome whose optics are
    "less than perfect, especially near the edges", a video CCD behind an uncoated-era
    fisheye, a pressed-PTFE (Halon-like) standard, an unregulated 3 W halogen lamp, the
    sample rotated by hand; the campaign option :data:`PRESET_OPTIONS` adds the 108 x 80
    digitised image.
``modern``
    The same geometry built today: a precision (diamond-turned or glass) dome, a
    multi-coated fisheye on a scientific CMOS / CCD camera, a Spectralon standard with a
    goniometric certificate, a regulated lamp.

Magnitudes that no publication states for this device are engineering estimates; their
docstrings say so.

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics
(Proc. SIGGRAPH '92), 26(2), 265-272. §3 (device), §3.2 (eq. 2), §3.3 (limitations).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "EFFECTS",
    "PRESETS",
    "PRESET_OPTIONS",
    "Distribution",
    "EffectSpec",
    "check_magnitudes",
    "effect_rng",
    "is_ideal",
    "preset_of",
    "realise",
]


@dataclass(frozen=True)
class EffectSpec:
    """What one effect is: its name, unit, valid range, physical source.

    Parameters
    ----------
    name : str
        Key in :data:`EFFECTS` and in a magnitudes mapping.
    unit : str
        Unit of the magnitude.
    valid : (float, float)
        Closed range of physically meaningful magnitudes (``hi_open`` makes the top open).
    doc : str
        What the effect does in the simulated instrument and how its magnitude is used.
    reference : str
        The physical source of the effect and of the preset magnitudes.
    hi_open : bool
        The upper bound itself is not valid (a glare fraction of 1 is no image).
    """

    name: str
    unit: str
    valid: tuple[float, float]
    doc: str
    reference: str
    hi_open: bool = False

    def contains(self, value: float) -> bool:
        """True when ``value`` is a finite magnitude inside :attr:`valid`."""
        lo, hi = self.valid
        if not math.isfinite(value) or value < lo:
            return False
        return value < hi if self.hi_open else value <= hi

    def clip(self, value: float) -> float:
        """``value`` clipped into the valid range (just below an open top)."""
        lo, hi = self.valid
        top = math.nextafter(hi, -math.inf) if self.hi_open else hi
        return float(min(max(value, lo), top))

    def range_text(self) -> str:
        """The valid range as ``[lo, hi]`` or ``[lo, hi)``."""
        lo, hi = self.valid
        return f"[{lo:g}, {hi:g}{')' if self.hi_open else ']'}"


@dataclass(frozen=True)
class Distribution:
    """A preset's statement of one effect: a typical magnitude and its spread.

    Parameters
    ----------
    typical : float
        The typical magnitude (the mean of the instruments such a build gives).
    spread : float
        Standard deviation between instruments (0: every instrument has ``typical``).
    valid : (float, float)
        Range the drawn value is clipped to (a preset fills it from the effect's
        :class:`EffectSpec`); default unbounded.
    """

    typical: float
    spread: float = 0.0
    valid: tuple[float, float] = (-math.inf, math.inf)

    def __post_init__(self) -> None:
        for name in ("typical", "spread"):
            v = getattr(self, name)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"Distribution.{name} must be a number, got {v!r}") from None
            if not math.isfinite(v):
                raise ValueError(f"Distribution.{name} must be finite, got {v!r}")
            object.__setattr__(self, name, v)
        if self.spread < 0.0:
            raise ValueError(f"Distribution.spread must be >= 0, got {self.spread!r}")

    def draw(self, rng: np.random.Generator) -> float:
        """One instrument's magnitude: normal(typical, spread), clipped to :attr:`valid`."""
        v = self.typical if self.spread == 0.0 else float(rng.normal(self.typical, self.spread))
        lo, hi = self.valid
        return float(min(max(v, lo), hi))


def _spec(name, unit, valid, doc, reference, hi_open=False) -> EffectSpec:
    return EffectSpec(name, unit, (float(valid[0]), float(valid[1])), doc, reference, hi_open)


_WARD = "Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics 26(2)"

#: every LBL effect, by name
EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in (
        _spec(
            "dome_slope_error", "rad", (0.0, 0.02),
            "RMS slope error of the dome's figure at its rim; the error grows as the square "
            "of the distance from the dome axis (zero on the axis). A smooth random map of "
            "the two slope components (low-order modes, drawn from the instrument seed) "
            "tilts the surface normal, so each pixel's true reflected direction is deviated "
            "by twice the local slope error from the nominal one the reduction assumes.",
            f"{_WARD}, §3.3: the acrylic hemisphere's 'optical properties are less than "
            "perfect, especially near the edges'. Thermoformed acrylic: several mrad "
            "(engineering estimate, no figure published); diamond-turned or ground glass "
            "optics: well below 1 mrad.",
        ),
        _spec(
            "focus_error", "1", (0.0, 0.5),
            "RMS relative error |s - s_f| / s_f of the focus distance over the image: the "
            "lens is focused at R/2, where a parallel bundle from the sample meets after the "
            "dome; the focal surface is a sphere of radius R/2 about the dome centre, which "
            "the off-axis lens sees at distances that differ by about 2D/R (its depth of "
            "field) plus the setting error. Blurs the image with a Gaussian of RMS "
            "(f_lens / (N s_f)) * focus_error / 4 rad (a defocus disc of diameter "
            "aperture x focus error, RMS = diameter / 4).",
            f"{_WARD}, §3.1: 'By focusing the lens at one half the hemisphere radius, a near "
            "perfect imaging of the reflected angles takes place.' Thin-lens depth of "
            "field: e.g. Hecht, E. (2017). Optics, 5th ed., Pearson.",
        ),
        _spec(
            "diffraction_wavelength", "nm", (0.0, 1100.0),
            "Effective wavelength of the diffraction blur at the working f-number N: the "
            "Airy core approximated by a Gaussian of RMS 0.42 lambda N on the sensor "
            "(0 = no diffraction). 550 nm for white light through a photopic filter.",
            "Zhang, B., Zerubia, J., Olivo-Marin, J.-C. (2007). Gaussian approximations of "
            "fluorescence microscope point-spread function models. Applied Optics 46(10), "
            "1819-1829, doi:10.1364/AO.46.001819 (paraxial Airy: sigma = 0.21 lambda / NA "
            "= 0.42 lambda N).",
        ),
        _spec(
            "pixel_fill", "1", (0.0, 1.0),
            "Fraction of the pixel area that collects light: the ideal instrument samples "
            "the image at pixel centres; a real pixel integrates over a square of side "
            "sqrt(fill), i.e. a blur of RMS sqrt(fill / 12) pixel in each axis.",
            "Interline CCDs without microlenses: fill factors 0.3-0.5; with microlenses and "
            "in back-illuminated sensors 0.8-1 (e.g. Holst, G. C., Lomheim, T. S. (2011). "
            "CMOS/CCD Sensors and Camera Systems, 2nd ed., SPIE Press).",
        ),
        _spec(
            "veiling_glare", "1", (0.0, 1.0),
            "Veiling glare: a fraction of all the light the lens forms into the image is "
            "scattered uniformly over the image circle (added to every pixel inside it as "
            "fraction x the mean image irradiance over the circle). Present in the sample, "
            "standard and background images alike; eq. 2 does not remove it.",
            "ISO 9358:1994, Optics and optical instruments - Veiling glare of image forming "
            "systems; McCann, J. J., Rizzi, A. (2007). Veiling glare: the dynamic range "
            "limit of HDR images. Proc. SPIE 6492, IS&T/SPIE Electronic Imaging (camera "
            "lenses: glare of one to a few percent of the mean image irradiance).",
            hi_open=True,
        ),
        _spec(
            "vignetting", "1", (0.0, 1.0),
            "Relative-illumination loss of the fisheye at the edge of its field: the "
            "response falls as 1 - v (theta / theta_max)^2. Cancels in eq. 2 (same pixel in "
            "the sample and standard images) but costs signal-to-noise towards grazing "
            "angles.",
            "Kumler, J. J., Bauer, M. L. (2000). Fish-eye lens designs and their relative "
            "performance. Proc. SPIE 4093, Current Developments in Lens Design and Optical "
            "Systems Engineering (relative illumination of fisheye designs at the field edge).",
            hi_open=True,
        ),
        _spec(
            "lens_body_height", "m", (0.0, 0.02),
            "Height of the fisheye's front barrel above the sample plane (a cylinder of "
            "radius 2D - 1.25 r_s about the lens axis, touching the holder's rim): rays from "
            "the sample towards the dome that pass through it never reach the camera "
            "(grazing directions on the camera's side). The pixels that see those rays are "
            "dark in every image.",
            f"{_WARD}, Figure 2-3 (the lens looks up beside the sample, 2D away, its front "
            "at about the sample plane); the protrusion is an engineering estimate.",
        ),
        _spec(
            "holder_rim_height", "m", (0.0, 0.005),
            "Height of the sample holder's rim (radius 1.25 x the sample radius) above the "
            "sample surface: it shadows the incident beam at grazing incidence and blocks "
            "grazing reflected directions, for the sample and the standard alike.",
            f"{_WARD}, §3.3: 'we are limited in our ability to measure the reflectance "
            "function near grazing angles, due to the size and shape of our reflecting "
            "hemisphere and the size of our sample' (rim height an engineering estimate).",
        ),
        _spec(
            "sample_height", "m", (-0.003, 0.003),
            "Height of the sample surface above the plane where the standard sat (signed): "
            "the mirror images the sample plane z = 0; a sample at z = h is seen at shifted "
            "points, its beam footprint moves by h tan(theta_i), and the hemi-ellipsoid's "
            "focal property no longer maps every pixel to the sample centre.",
            f"{_WARD}, §3 (sample holder at the second focus); mounting tolerance of a "
            "sample against the holder's ledge (engineering estimate, 0.1 mm by hand, 20 um "
            "against a reference stop). Rays leaving a raised sample at grazing angles land "
            "beside it: the pixels with cos(theta_o) < |h| / r_s see the holder, not the "
            "sample. Measured on rolled brass: alone, 20 um gives rho_d +2.9 % (chi2/dof "
            "28), 0.1 mm +100 %; with the modern holder's 0.2 mm rim, which hides those "
            "pixels in the standard's image too, 20 um moves every parameter < 0.05 %.",
        ),
        _spec(
            "sample_tilt", "rad", (0.0, 0.05),
            "Tilt of the sample's normal relative to the holder axis (its azimuth drawn "
            "from the instrument seed, fixed in the sample, so it turns with the holder): "
            "incident and reflected directions in the sample frame differ from the "
            "nominal ones the reduction uses.",
            "Mounting tolerance of a sample on a holder (engineering estimate: a few mrad "
            "by hand, < 1 mrad against a reference flat).",
        ),
        _spec(
            "reillumination", "1", (0.0, 0.2),
            "Fraction of the light the sample reflects that the dome returns to it (sample "
            "-> dome -> lens front and housing -> dome -> sample): an extra diffuse "
            "irradiance r rho_dh(wi) E cos(theta_i) on the sample, seen as radiance "
            "r rho_dh(wi) E cos(theta_i) rho_dh(wo) / pi (reciprocity); in the standard's "
            "image too.",
            f"{_WARD}, §3 (the dome reflects the sample's light into the lens); magnitude "
            "R_m^2 x the reflectance of the lens front and its housing (0.5^2 x 1-5 %, an "
            "engineering estimate).",
        ),
        _spec(
            "ambient_on_sample", "1", (0.0, 1.0),
            "Fraction of the room's ambient radiance (the Background's, through the dome's "
            "transmittance) that reaches the sample: a diffuse irradiance "
            "a pi T L_ambient over the whole sample disk. The background image (no sample) "
            "does not contain its reflection.",
            f"{_WARD}, §3.2: the background measurement uses 'the dark room behind to "
            "simulate a black body' and reduces 'the effects of stray and ambient light'; "
            "an exterior baffle shields the camera (fraction an engineering estimate).",
        ),
        _spec(
            "fstop_series", "1", (0.0, 1.0),
            "Use the true f-numbers 2^(k/2) of the engraved series (f/11 is 11.31, f/5.6 is "
            "5.66, f/22 is 22.63) instead of the marked ones: 1 = the real lens, 0 = the "
            "marked values are exact. The side-car records the marked value.",
            "ISO 517:2008, Photography - Apertures and related properties pertaining to "
            "photographic lenses (the marked series is the rounded sqrt(2) progression).",
        ),
        _spec(
            "fstop_error", "1", (0.0, 0.2),
            "RMS relative error of the aperture area of each f-stop of the real lens (one "
            "fixed error per stop, drawn from the instrument seed).",
            "ISO 517:2008 tolerances on the aperture of a marked stop (about +-5 % in area "
            "for mechanical irises; engineering estimate for this lens).",
        ),
        _spec(
            "iris_repeatability", "1", (0.0, 0.1),
            "RMS relative error of the aperture area each time the iris is set (a fresh "
            "draw for each frame).",
            "Mechanical iris repeatability (engineering estimate: about 1 % in area for "
            "manual and motorised irises).",
        ),
        _spec(
            "lamp_warmup", "1", (0.0, 0.5),
            "Relative output deficit of the lamp at the campaign's first capture, decaying "
            "with a 600 s time constant: E(t) = E (1 - w exp(-t / 600 s) + d t / 1 h).",
            "Quartz-halogen lamps need 15-30 min to stabilise (e.g. Walker, J. H. et al. "
            "(1987). Spectral irradiance calibrations. NBS Special Publication 250-20).",
        ),
        _spec(
            "lamp_drift", "1/h", (-0.2, 0.2),
            "Linear relative drift of the lamp output per hour of campaign time (signed).",
            "Output of an incandescent lamp goes as about V^3.4 of its supply voltage, so an "
            "unregulated supply's 0.1 %/h drift is ~0.3 %/h of light (e.g. IES Lighting "
            "Handbook, 10th ed. (2011)).",
        ),
        _spec(
            "lamp_flicker", "1", (0.0, 0.05),
            "RMS relative fluctuation of the lamp output from frame to frame.",
            "Engineering estimate for a DC-driven halogen lamp (0.05-0.3 %).",
        ),
        _spec(
            "standard_non_lambertian", "1", (0.0, 2.0),
            "Scale of the diffuse standard's departure from Lambert's law: its BRDF is "
            "(rho/pi) [1 + s (F(wi, wo) - 1)] with F the PTFE / Spectralon reflectance "
            "factor of gonio.simulator.standard (1.04 at normal; 1.07, 1.10, 1.22 in the "
            "forward direction at 45, 60, 75 deg incidence). 1 = a real PTFE standard.",
            "Weidner, V. R., Hsia, J. J. (1981). Reflection properties of pressed "
            "polytetrafluoroethylene powder. J. Opt. Soc. Am. 71(7), 856-861, "
            "doi:10.1364/JOSA.71.000856; Bhandari, A. et al. (2011). Bidirectional "
            "reflectance distribution function of Spectralon white reflectance standard "
            "illuminated by incoherent unpolarized and plane-polarized light. Applied "
            "Optics 50(16), 2431-2442, doi:10.1364/AO.50.002431.",
        ),
        _spec(
            "standard_certificate_u", "1", (0.0, 0.1),
            "Relative standard uncertainty (k = 1) of the standard's calibration "
            "certificate; the real standard deviates from the certified values by a smooth "
            "random function of the angles with this RMS, drawn from the instrument seed. "
            "The certificate states the expanded uncertainty U = 2 u.",
            "Goniometric BRDF calibrations of white standards: U(k=2) about 1 % at national "
            "laboratories (e.g. Basic, N. et al. (2023). Intercomparison of bidirectional "
            "reflectance distribution function measurements at in- and out-of-plane "
            "geometries. Applied Optics 62(13), 3320-3329, doi:10.1364/AO.486156); a "
            "1990s laboratory's own reference: a few percent.",
        ),
    )
}  # fmt: skip


def preset_of(
    values: Mapping[str, tuple[float, float]], table: Mapping[str, EffectSpec] | None = None
) -> dict[str, Distribution]:
    """A preset: every effect of ``table`` (default the LBL :data:`EFFECTS`) as a
    :class:`Distribution` of ``values[name] = (typical, spread)`` (absent: 0, 0), clipped
    to the effect's valid range."""
    out = {}
    for name, spec in (EFFECTS if table is None else table).items():
        typ, spread = values.get(name, (0.0, 0.0))
        lo, hi = spec.valid
        out[name] = Distribution(typ, spread, (lo, spec.clip(hi)))
    return out


_preset = preset_of


#: named instrument builds: each effect as a Distribution (typical, spread between instruments)
PRESETS: dict[str, dict[str, Distribution]] = {
    "ideal": _preset({}),
    "ward1992": _preset(
        {
            "dome_slope_error": (4e-3, 1.5e-3),  # thermoformed acrylic (§3.3)
            "focus_error": (0.15, 0.05),  # depth of field 2D/R plus a hand-set focus
            "diffraction_wavelength": (550.0, 0.0),  # white light, photopic
            "pixel_fill": (0.4, 0.1),  # 1990 interline video CCD, no microlenses
            "veiling_glare": (0.03, 0.01),  # single-coated fisheye, acrylic dome
            "vignetting": (0.4, 0.1),
            "lens_body_height": (0.003, 0.001),
            "holder_rim_height": (0.0005, 0.0002),
            "sample_height": (0.0, 1e-4),  # placed by hand against the holder's ledge
            "sample_tilt": (4e-3, 2e-3),
            "reillumination": (0.01, 0.003),
            "ambient_on_sample": (0.5, 0.2),
            "fstop_series": (1.0, 0.0),  # a real lens's engraved stops
            "fstop_error": (0.03, 0.01),
            "iris_repeatability": (0.01, 0.003),
            "lamp_warmup": (0.02, 0.01),  # unregulated 3 W lamp
            "lamp_drift": (0.005, 0.003),
            "lamp_flicker": (0.002, 0.001),
            "standard_non_lambertian": (1.0, 0.1),  # pressed PTFE (Halon)
            "standard_certificate_u": (0.015, 0.0),
        }
    ),
    "modern": _preset(
        {
            "dome_slope_error": (5e-4, 2e-4),  # diamond-turned / glass
            "focus_error": (0.08, 0.02),  # the depth-of-field term 2D/R dominates
            "diffraction_wavelength": (550.0, 0.0),
            "pixel_fill": (0.9, 0.05),  # microlenses
            "veiling_glare": (0.01, 0.003),  # multi-coated fisheye
            "vignetting": (0.2, 0.05),
            "lens_body_height": (0.002, 0.0005),
            "holder_rim_height": (0.0002, 0.0001),
            "sample_height": (0.0, 2e-5),  # against a reference stop
            "sample_tilt": (1e-3, 5e-4),
            "reillumination": (0.003, 0.001),  # black-anodised housing, coated front
            "ambient_on_sample": (0.1, 0.05),  # baffled
            "fstop_series": (1.0, 0.0),
            "fstop_error": (0.01, 0.003),
            "iris_repeatability": (0.003, 0.001),
            "lamp_warmup": (0.005, 0.002),  # regulated supply
            "lamp_drift": (0.001, 0.0005),
            "lamp_flicker": (0.0005, 0.0002),
            "standard_non_lambertian": (1.0, 0.05),  # Spectralon
            "standard_certificate_u": (0.005, 0.0),  # goniometric certificate, U = 1 %
        }
    ),
}

#: campaign options that come with a preset (not effect magnitudes): Ward's digitiser
PRESET_OPTIONS: dict[str, dict[str, Any]] = {
    "ideal": {"binning": None},
    "ward1992": {"binning": (108, 80)},
    "modern": {"binning": None},
}


def check_magnitudes(m: Mapping[str, float], table: Mapping[str, EffectSpec] | None = None) -> None:
    """Raise ``ValueError`` for an unknown effect or a magnitude outside its valid range.

    The message names the parameter, the value and the range (and the unit). ``table``: the
    instrument's effects (default this module's LBL :data:`EFFECTS`; the Cornell instrument
    passes its own).
    """
    known = EFFECTS if table is None else table
    if not isinstance(m, Mapping):
        raise ValueError(f"effects must be a mapping of effect name to magnitude, got {m!r}")
    for name, value in m.items():
        spec = known.get(name)
        if spec is None:
            raise ValueError(
                f"effect {name!r} is unknown; expected some of {', '.join(sorted(known))}"
            )
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"effect {name} must be a number ({spec.unit}), got {value!r}"
            ) from None
        if not spec.contains(v):
            raise ValueError(
                f"effect {name} = {value!r} is outside its valid range {spec.range_text()} "
                f"({spec.unit})"
            )


def _resolve_preset(
    preset: str | Mapping[str, Distribution],
    presets: Mapping[str, Mapping[str, Distribution]] | None = None,
    table: Mapping[str, EffectSpec] | None = None,
) -> Mapping[str, Distribution]:
    presets = PRESETS if presets is None else presets
    known = EFFECTS if table is None else table
    if isinstance(preset, str):
        if preset not in presets:
            raise ValueError(f"preset {preset!r} is unknown; expected one of {', '.join(presets)}")
        return presets[preset]
    if not isinstance(preset, Mapping):
        raise ValueError(f"preset must be a name or a mapping of Distributions, got {preset!r}")
    for name, d in preset.items():
        if name not in known:
            raise ValueError(
                f"effect {name!r} is unknown; expected some of {', '.join(sorted(known))}"
            )
        if not isinstance(d, Distribution):
            raise ValueError(f"preset entry {name!r} must be a Distribution, got {d!r}")
    return preset


def effect_rng(seed: int, *key: str | int) -> np.random.Generator:
    """A generator that depends only on ``seed`` and ``key`` (e.g. an effect's name).

    ``SeedSequence(seed, spawn_key=(h,))`` with ``h`` the first 8 bytes of SHA-256 of the
    key, so adding an effect or drawing in another order changes no other draw.
    """
    if not isinstance(seed, int | np.integer) or int(seed) < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    text = "/".join(str(k) for k in key)
    h = int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(h,)))


def realise(
    preset: str | Mapping[str, Distribution],
    seed: int,
    *,
    table: Mapping[str, EffectSpec] | None = None,
    presets: Mapping[str, Mapping[str, Distribution]] | None = None,
    stream: str = "effect",
    check: Callable[[Mapping[str, float]], None] | None = None,
) -> dict[str, float]:
    """The realised magnitudes of one physical instrument built to ``preset``.

    Each effect is drawn from its own stream (:func:`effect_rng` of ``seed``, ``stream`` and
    its name) and clipped to its valid range; effects the preset does not name are 0.
    Different seeds are different instruments; the same seed is the same instrument.
    ``table``, ``presets``, ``stream`` and ``check`` make it any instrument's (default this
    module's LBL :data:`EFFECTS`, :data:`PRESETS`, stream ``"effect"`` and
    :func:`check_magnitudes`; the Cornell instrument passes its own).

    Examples
    --------
    >>> realise("ideal", 3)["veiling_glare"]
    0.0
    >>> realise("modern", 1) == realise("modern", 1)
    True
    """
    known = EFFECTS if table is None else table
    dists = _resolve_preset(preset, presets, known)
    out: dict[str, float] = {}
    for name, spec in known.items():
        d = dists.get(name)
        v = 0.0 if d is None else d.draw(effect_rng(seed, stream, name))
        out[name] = spec.clip(v)
    if check is None:
        check_magnitudes(out, known)
    else:
        check(out)
    return out


def is_ideal(m: Mapping[str, float] | None) -> bool:
    """True when ``m`` is None or every magnitude is zero."""
    return m is None or all(float(v) == 0.0 for v in m.values())
