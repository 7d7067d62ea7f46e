"""The imperfections of the Cornell three-axis gonioreflectometer, as named effects.

The same framework as the LBL instrument's (:mod:`gonio.simulator.effects`: an
:class:`~gonio.simulator.effects.EffectSpec` per effect, a preset as one
:class:`~gonio.simulator.effects.Distribution` per effect, realised per instrument seed by
:func:`realise`), with the Cornell instrument's own table. Every magnitude of zero switches
its effect off and skips its work, so the ``ideal`` preset is the ideal instrument bit for
bit. Magnitudes that no publication states for this instrument are engineering estimates;
their references say so.

Presets:

``ideal``
    Every effect zero: the ideal instrument.
``cornell2005``
    The instrument of Li and Torrance (2005, §5.1) as far as the paper describes it (a
    quartz-halogen source of about 0.0005 sr, "tentatively" so; 4 in x 4 in samples; a
    grating spectroradiometer giving "31 convolved wavelength samples"; two polarisations;
    about 11 hours for a hemispherical scan), with engineering estimates for what it does
    not state (beam and field-of-view diameters, cone profiles, stage errors, stray light,
    non-linearity). The default of ``gonio campaign --instrument cornell``.

References
----------
Li, H., Torrance, K. E. (2005). A practical, comprehensive light reflection model. Technical
report PCG-05-03, Program of Computer Graphics, Cornell University, §5.1 (instrument), eq. 16
(source solid angle), Fig. 6 (polarised BRDF of laser paper).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from gonio.simulator.effects import Distribution, EffectSpec, _spec, is_ideal, preset_of
from gonio.simulator.effects import check_magnitudes as _check_table
from gonio.simulator.effects import realise as _realise

__all__ = [
    "EFFECTS",
    "LAMP_WARMUP_TAU_S",
    "PRESETS",
    "check_magnitudes",
    "is_ideal",
    "is_preset",
    "lab_knowledge",
    "realise",
    "resolve_effects",
]

#: the lamp's warm-up time constant (s), the ``lamp_warmup`` effect's documented value (a
#: data-sheet figure the laboratory knows as well)
LAMP_WARMUP_TAU_S = 600.0

_LT = "Li, H., Torrance, K. E. (2005). A practical, comprehensive light reflection model"
_EST = "engineering estimate (the paper states no value)"


#: every Cornell effect, by name
EFFECTS: dict[str, EffectSpec] = {
    s.name: s
    for s in (
        _spec(
            "beam_diameter_mm", "mm", (0.0, 500.0),
            "Diameter of the collimated source beam (top-hat irradiance across it); the lit "
            "spot on the sample is an ellipse D x D / cos(theta_i) along the incidence "
            "azimuth. The detector reads the radiance averaged over its field of view, so a "
            "field of view that leaves the lit spot (or the sample) reads low by the fraction "
            "that is dark. 0 = an infinitely wide beam.",
            f"{_LT}, §5.1 (collimated source on an arm); the diameter is an {_EST}.",
        ),
        _spec(
            "fov_diameter_mm", "mm", (0.0, 101.6),
            "Diameter of the detector's field of view at normal view; an ellipse "
            "D x D / cos(theta_o) on the sample along the viewing azimuth. 0 = a point (the "
            "field of view never leaves the lit spot).",
            f"{_LT}, §5.1: covering 85 deg on a 4-inch sample needs a field of view "
            f"<= 101.6 mm x cos 85 deg = 8.9 mm; the diameter is an {_EST}.",
        ),
        _spec(
            "sample_size_mm", "mm", (0.0, 1000.0),
            "Side of the square sample (its edges along the sample frame's x and y). "
            "0 = an infinite sample.",
            f"{_LT}, §5.1: samples 'at least 4 inch by 4 inch square to allow full "
            "hemispherical BRDF scans' (101.6 mm).",
        ),
        _spec(
            "source_cone_taper", "1", (0.0, 1.0),
            "Radiance profile across the source cone: L(r) = 1 - t (r / alpha)^2 (r the "
            "angle from the cone axis, alpha its half-angle) instead of a top hat; the "
            "instrument's cone quadrature is weighted by it (the mirror part keeps the top "
            "hat's overlap formula).",
            f"A lamp filament imaged through a condenser has a falling edge; {_EST}.",
        ),
        _spec(
            "detector_cone_taper", "1", (0.0, 1.0),
            "Responsivity profile across the detector's acceptance cone, "
            "1 - t (r / alpha)^2, as for the source.",
            f"Vignetting inside the spectroradiometer's fore-optics; {_EST}.",
        ),
        _spec(
            "source_solid_angle_error", "1", (-0.5, 0.5),
            "Relative error of the nominal source solid angle 0.0005 sr: the true "
            "Omega_s = 0.0005 (1 + e). The reduction and the fit use the nominal value "
            "(eq. 16's d omega_i), so the mirror part of a glossy sample scales as 1/(1+e).",
            f"{_LT}, eq. 16: d omega_i 'was tentatively set as 0.0005, which is the "
            "estimated solid angle of the experimental light source'.",
        ),
        _spec(
            "lamp_warmup", "1", (0.0, 0.5),
            "Relative output deficit of the lamp at the campaign's start, decaying with a "
            "600 s time constant: E(t) = E (1 - w exp(-t / 600 s) + d t / 1 h).",
            "Quartz-halogen lamps need 15-30 min to stabilise (Walker, J. H. et al. (1987). "
            "Spectral irradiance calibrations. NBS Special Publication 250-20, §4).",
        ),
        _spec(
            "lamp_drift", "1/h", (-0.2, 0.2),
            "Linear relative drift of the lamp output per hour of campaign time (signed); "
            "over the paper's 11-hour scan 0.001/h is a 1.1 % change.",
            "Incandescent output goes as about V^3.4 of the supply (IES Lighting Handbook, "
            f"10th ed. (2011), ch. 7); a regulated supply's drift is an {_EST}.",
        ),
        _spec(
            "stage_backlash_deg", "deg", (0.0, 1.0),
            "Backlash of each rotation stage: after a move the load trails the motor "
            "(encoder) by half this band on the side it came from. The reduction uses the "
            "commanded (encoder) angles.",
            "Worm-gear rotation stages: 0.005-0.02 deg (e.g. Newport URS-series data "
            "sheets); the simulated bench's Stage.backlash.",
        ),
        _spec(
            "stage_noise_deg", "deg", (0.0, 0.5),
            "RMS positioning error of each rotation stage, drawn afresh after each move.",
            "Bi-directional repeatability of motorised rotation stages, 0.001-0.005 deg "
            "(Newport URS-series data sheets); the simulated bench's Stage.noise.",
        ),
        _spec(
            "sample_tilt_rad", "rad", (0.0, 0.05),
            "Tilt of the sample's normal relative to the stage's tilt axis frame (its "
            "azimuth drawn from the instrument seed, fixed in the sample): the true "
            "sample-frame directions are the nominal ones rotated by this angle.",
            f"Mounting tolerance of a 4-inch panel on the stage: about 1 mrad; {_EST}.",
        ),
        _spec(
            "sample_wobble_rad", "rad", (0.0, 0.05),
            "Wobble of the turntable axis (axial run-out): a tilt of this size whose "
            "azimuth is fixed in the laboratory, so in the sample frame it turns with the "
            "turntable angle.",
            "Rotation-stage wobble, 20-100 urad (Newport URS-series data sheets).",
        ),
        _spec(
            "stray_light_fraction", "1", (0.0, 0.05),
            "In-spectrometer stray light: each pixel receives this fraction of the mean "
            "signal over all pixels (a uniform stray-light distribution). For a coloured "
            "sample it raises the weak bands against the white standard's reference.",
            "Array spectroradiometers: 1e-4 to 1e-3 (Zong, Y., Brown, S. W., Johnson, "
            "B. C., Lykke, K. R., Ohno, Y. (2006). Simple spectral stray light correction "
            "method for array spectroradiometers. Applied Optics 45(6), 1111-1119, "
            "doi:10.1364/AO.45.001111).",
        ),
        _spec(
            "slit_fwhm_nm", "nm", (0.0, 10.0),
            "Full width at half maximum of the spectrometer's (Gaussian) slit function: "
            "every spectrum is convolved with it before the pixels read it. Must stay "
            "below the 10 nm band spacing.",
            f"{_LT}, §5.1: '31 convolved wavelength samples'; the width is an {_EST}.",
            hi_open=True,
        ),
        _spec(
            "wavelength_shift_nm", "nm", (-5.0, 5.0),
            "Error of the stored wavelength calibration: the true wavelength of every pixel "
            "is the stored one plus this shift.",
            "Wavelength accuracy of array spectrometers after a line-lamp calibration, "
            "0.1-0.3 nm (e.g. Kostkowski, H. J. (1997). Reliable Spectroradiometry. "
            "Spectroradiometry Consulting, ch. 6).",
        ),
        _spec(
            "nonlinearity", "1", (-0.1, 0.1),
            "Residual relative non-linearity of the detector after its stored correction: "
            "the counts above bias read x (1 - a x / x_full) (signed).",
            "Linearity of corrected CCD array spectrometers, better than 0.2-0.5 % "
            "(Kostkowski 1997, ch. 7); residual an engineering estimate.",
        ),
        _spec(
            "sample_polarisation", "1", (0.0, 1.0),
            "Scale of the sample's polarisation: the first-surface directional-diffuse part "
            "(k_dd) of li_torrance reflects s and p by Fresnel's ratio at the half-angle "
            "(f_s,p = f (1 +- s P r_dd), P = (R_s - R_p)/(R_s + R_p) with the model's n, "
            "r_dd the directional-diffuse share of f); the subsurface parts stay "
            "depolarised. 1 = Fresnel's full degree of polarisation.",
            f"{_LT}, §3 and Fig. 6 (polarised BRDF of laser paper: subsurface scattering is "
            "'more de-polarized'); Born, M., Wolf, E. (1999). Principles of Optics, 7th "
            "ed., Cambridge University Press, §1.5.2 (Fresnel).",
        ),
        _spec(
            "polariser_error_deg", "deg", (0.0, 10.0),
            "Angle error of the polariser's p position (s at 0 deg, p at 90 deg + e): the "
            "two reads are no longer orthogonal, so their average is not the unpolarised "
            "BRDF for a polarising sample.",
            f"Repeatability of a motorised polariser mount; {_EST}.",
        ),
    )
}  # fmt: skip


def _preset(values: Mapping[str, tuple[float, float]]) -> dict[str, Distribution]:
    return preset_of(values, EFFECTS)


#: named instrument builds (typical magnitude, spread between instruments)
PRESETS: dict[str, dict[str, Distribution]] = {
    "ideal": _preset({}),
    "cornell2005": _preset(
        {
            "beam_diameter_mm": (25.0, 1.0),
            "fov_diameter_mm": (8.0, 0.3),
            "sample_size_mm": (101.6, 0.0),  # 4 inch (§5.1)
            "source_cone_taper": (0.3, 0.1),
            "detector_cone_taper": (0.2, 0.1),
            "source_solid_angle_error": (0.0, 0.1),  # 'tentatively' 0.0005 sr (eq. 16)
            "lamp_warmup": (0.005, 0.002),
            "lamp_drift": (0.001, 0.0005),  # +1.1 % over 11 h
            "stage_backlash_deg": (0.01, 0.003),
            "stage_noise_deg": (0.002, 0.0005),
            "sample_tilt_rad": (1e-3, 5e-4),
            "sample_wobble_rad": (5e-5, 2e-5),
            "stray_light_fraction": (1e-3, 2e-4),
            "slit_fwhm_nm": (5.0, 0.5),
            "wavelength_shift_nm": (0.0, 0.2),
            "nonlinearity": (0.0, 0.002),
            "sample_polarisation": (1.0, 0.0),
            "polariser_error_deg": (0.0, 0.5),
        }
    ),
}

#: the default preset of a Cornell campaign
DEFAULT_PRESET = "cornell2005"


def check_magnitudes(m: Mapping[str, float]) -> None:
    """``ValueError`` for an unknown effect, a magnitude outside its range, or a field of
    view larger than the sample (the message names the parameter, the value and the range)."""
    _check_table(m, EFFECTS)
    fov, size = float(m.get("fov_diameter_mm", 0.0)), float(m.get("sample_size_mm", 0.0))
    if fov > 0 and size > 0 and fov > size:
        raise ValueError(
            f"effect fov_diameter_mm = {fov!r} is larger than sample_size_mm = {size!r}: "
            "the field of view must fit on the sample"
        )


def realise(preset: str | Mapping[str, Distribution], seed: int) -> dict[str, float]:
    """The realised magnitudes of one physical instrument built to ``preset`` (a name of
    :data:`PRESETS` or a mapping of Distributions; each effect from its own stream of
    ``seed``, clipped to its range; unnamed effects 0): the framework's
    :func:`gonio.simulator.effects.realise` with the Cornell table."""
    return _realise(
        preset, seed, table=EFFECTS, presets=PRESETS, stream="cornell", check=check_magnitudes
    )


def resolve_effects(
    effects: str | Mapping[str, float] | None, seed: int
) -> dict[str, float] | None:
    """Magnitudes from a preset (a name or a mapping of Distributions, realised with
    ``seed``), a mapping of magnitudes (checked, missing effects 0) or None (ideal). Returns
    None for the ideal instrument."""
    if effects is None:
        return None
    if is_preset(effects):
        m = realise(effects, seed)
    else:
        check_magnitudes(effects)
        m = {name: float(effects.get(name, 0.0)) for name in EFFECTS}
    return None if is_ideal(m) else m


def is_preset(effects: object) -> bool:
    """True for a preset name or a mapping of Distributions (a custom preset)."""
    if isinstance(effects, str):
        return True
    return (
        isinstance(effects, Mapping)
        and len(effects) > 0
        and all(isinstance(d, Distribution) for d in effects.values())
    )


def lab_knowledge(
    preset: str | Mapping[str, Distribution] | None,
) -> dict[str, tuple[float, float]]:
    """What a laboratory knows of its instrument: per effect the nominal value (the preset's
    typical magnitude: a data sheet, a characterisation) and its standard uncertainty (the
    spread between instruments). ``{}`` for None or the ideal preset's zeros."""
    if preset is None:
        return {}
    dists = PRESETS[preset] if isinstance(preset, str) else preset
    return {
        n: (float(d.typical), float(d.spread))
        for n, d in dists.items()
        if d.typical != 0.0 or d.spread != 0.0
    }


def lamp_factor(m: Mapping[str, float], t_s: float) -> float:
    """Relative lamp output at campaign time ``t_s`` (s): 1 - w exp(-t/600) + d t/3600."""
    w, d = float(m.get("lamp_warmup", 0.0)), float(m.get("lamp_drift", 0.0))
    return 1.0 - w * math.exp(-t_s / LAMP_WARMUP_TAU_S) + d * t_s / 3600.0
