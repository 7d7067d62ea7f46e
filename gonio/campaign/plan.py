"""The LBL campaign's plan: what is measured and how, validated before anything runs.

A :class:`Plan` names the instrument, material, incidence angles, sample rotations,
exposures, noise and seed; :meth:`Plan.resolved` fills in the defaults and checks every
field (a ``ValueError`` naming the field, the value and what is expected).
:func:`capture_seed` gives every capture its own seed, a function of the campaign seed and
the capture's name only, so that the result does not depend on the order of the captures,
on the number of workers or on a resume.

Ward's protocol (Ward 1992, §4-5): 21 incidence angles from 0° to 80°; an anisotropic sample
is also measured after rotating it by 90° about its normal so that both principal directions
lie in the plane of incidence once. gonio's default for an anisotropic sample adds a third
rotation between them (``rotations_deg=(0, 45, 90)``): Radiance's ``pabopto2bsdf`` infers a
BSDF's symmetry from incident azimuths strictly inside a quadrant, so 0° and 90° alone cannot be
exported as a Radiance BSDF (:mod:`gonio.io.pabopto`), and 45° also samples the lobe between the
principal directions.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

__all__ = ["DEFAULT_ANGLES_DEG", "DEFAULT_COMPARE", "Plan", "capture_seed", "default_plan"]

#: Ward's 21 incidence angles, 0° to 80° in 4° steps.
DEFAULT_ANGLES_DEG: tuple[float, ...] = tuple(float(x) for x in np.linspace(0.0, 80.0, 21))


#: Models with separate x and y coefficients that φi = 0 alone cannot separate.
_XY_MODELS = frozenset({"lafortune"})


#: Thinning modes and their default options (Plan.thinning).
_THINNING: dict[str, dict[str, float]] = {
    "select": {"base_level": 5, "peak_level": 8, "peak_fraction": 0.1},
    "average": {"rel_tol": 0.002, "min_split": 2},
}


#: Models compared with the main fit by default (fitted to the same samples).
DEFAULT_COMPARE: dict[str, tuple[str, ...]] = {}


@dataclass(frozen=True)
class Plan:
    """What a campaign measures and how.

    Parameters
    ----------
    material : str
        Preset name (``gonio.materials``); its model and parameters are the truth.
    model : str, optional
        Model to fit (default: the preset's model). A sum ``"lambert + ward"`` is allowed.
    instrument : {"lbl"}
        The imaging gonioreflectometer (the only campaign instrument so far).
    mirror : {"ellipsoid", "hemisphere"}
        The dome of the LBL instrument.
    theta_i_deg : sequence of float
        Incidence angles in degrees.
    rotations_deg : sequence of float, optional
        Sample rotations about the normal (the incidence azimuth φi in the sample frame);
        default ``(0, 45, 90)`` for an anisotropic truth (α_x ≠ α_y) or a fitted model whose
        x and y coefficients only a second rotation separates (Lafortune's C_x, C_y),
        ``(0,)`` otherwise. 0° and 90° put both principal directions in the plane of
        incidence (Ward 1992, §4); 45° lies inside the quadrant, which Radiance's
        ``pabopto2bsdf`` needs to infer the quadrilateral symmetry of such a sample
        (:func:`gonio.io.pabopto.pabopto_symmetry`).
    exposures_s : sequence of float, optional
        Fixed exposure bracket; default the instrument's automatic bracket.
    noise : float
        0 = noise off, 1 = the instrument's default noise; another factor ``f`` scales every
        relative noise of the camera (shot, read, dark) by ``f`` by dividing the sensor's
        full well, gain and dark current by ``f²`` and its read noise by ``f``.
    seed : int
        Campaign seed; every capture's seed derives from it (:func:`capture_seed`).
    residual : str
        Residual of the fit (``gonio.fit.RESIDUALS``).
    compare : sequence of str, optional
        Other models fitted to the same samples and reported beside the main fit (e.g.
        ``("cook_torrance", "lafortune")`` for a Ward material); default none.
    plots : bool
        Write the PNG plots.
    thinning_mode : {"select", "average"}
        How each capture's pixels become samples. ``"select"`` (default): one pixel per
        equal-solid-angle cell, finer cells in the specular peak, each reduced alone with a σ
        from its neighbours (:func:`gonio.calibration.reduce.reduce_selected`) — unbiased
        point values, and only the selected pixels are merged. ``"average"``: the averaging
        thinning of :func:`gonio.calibration.thinning.thin` on every pixel, which widens
        fitted lobes. Measured (rolled brass, 21 θi × 2 rotations, default noise, seed 0):
        select 120,876 samples, every parameter within 1.5 s.e. (ρd 0.050 %, α_y 0.004 %);
        average 323,690 samples, α_x +0.053 % (+13 s.e.), α_y +0.058 % (+15 s.e.).
    thinning : pairs (name, value), optional
        Keyword arguments of the thinning: for ``"select"`` ``base_level`` (5),
        ``peak_level`` (8), ``peak_fraction`` (0.1); for ``"average"`` those of
        :func:`~gonio.calibration.thinning.thin` (default ``rel_tol=0.002, min_split=2``).
    d_over_r : float, optional
        The LBL dome's D/R (half the source-sample separation over the mirror radius); default
        the instrument's (0.01 m / 0.15 m).
    debias : bool
        Remove the second-order bias of eq. 2's ratio of noisy readings
        (:func:`gonio.calibration.radiometry.eq2`, ``debias``) when the captures are noisy
        (``noise > 0``). Measured (rolled brass, default plan, default noise): mean ρs pull
        +1.03 ± 0.15 over 49 seeds without, −0.02 ± 0.14 over 60 seeds with it.
    preset : {"modern", "ward1992", "ideal"}
        The instrument's build (:data:`gonio.simulator.effects.PRESETS`): each imperfection
        as a distribution over instruments, realised by ``instrument_seed``. Default
        ``"modern"``: the realistic instrument of the project's default geometry (a
        640 × 480 camera on a hemi-ellipsoid is a modern build; Ward's 1992 device,
        ``"ward1992"``, also digitised to 108 × 80 and had an acrylic hemisphere). ``"ideal"``
        is the perfect instrument (every effect off).
    instrument_seed : int, optional
        Which physical instrument of the preset (its realised magnitudes and maps); default
        the campaign ``seed``, so that different seeds are different instruments.
    binning : (width, height), optional
        Reduce every raw image to this size before quantisation (Ward's 108 × 80
        digitiser); default the preset's (:data:`gonio.simulator.effects.PRESET_OPTIONS`),
        ``(0, 0)`` full resolution.
    corrections : sequence of str, optional
        The laboratory's corrections (:data:`gonio.campaign.knowledge.CORRECTIONS`:
        ``geometry``, ``standard``, ``exposure``, ``glare``, ``saturation``, ``drift``);
        default all. A correction
        left out is an ablation: its effect stays in the data and the budget carries it as
        an uncorrected term.
    calibration : str, optional
        A calibration folder (``calibration.json``, :mod:`gonio.calibration.laboratory`)
        to reduce with instead of calibrating the instrument (the default, once per
        physical instrument).
    restandard_every : int
        Re-measure the standard during the sample sweeps: after the sample's capture at
        every ``restandard_every``-th incidence angle of each rotation (the first included)
        the sample is swapped for the standard and the standard captured again at that
        incidence; the ratio to its first capture follows the lamp, and the ``drift``
        correction (:func:`gonio.campaign.knowledge.correct_drift`) divides each sample
        capture by it, interpolated in time. 0 (default): no re-measurement. Each
        re-measurement adds two manual swaps to the real instrument's run time.
    bracket_min_signal_dn : float, optional
        The automatic bracket's threshold
        (:meth:`gonio.simulator.lbl.LBLInstrument.plan_bracket` ``min_signal_dn``): a wider stop is
        kept only if it brings a lit pixel at least this many DN above the background that no kept
        stop covered. None (default): the instrument's own, 16 DN. Higher takes more frames a
        capture (each pixel from a brighter frame), lower fewer (``gonio design --brackets`` chooses
        it).
    """

    material: str = "rolled_brass"
    model: str | None = None
    instrument: str = "lbl"
    mirror: str = "ellipsoid"
    theta_i_deg: tuple[float, ...] = DEFAULT_ANGLES_DEG
    rotations_deg: tuple[float, ...] | None = None
    exposures_s: tuple[float, ...] | None = None
    noise: float = 1.0
    seed: int = 0
    residual: str = "absolute"
    compare: tuple[str, ...] | None = None
    plots: bool = True
    thinning: tuple[tuple[str, float], ...] | None = None
    thinning_mode: str = "select"
    d_over_r: float | None = None
    debias: bool = True
    preset: str = "modern"
    instrument_seed: int | None = None
    binning: tuple[int, int] | None = None
    corrections: tuple[str, ...] | None = None
    calibration: str | None = None
    restandard_every: int = 0
    bracket_min_signal_dn: float | None = None

    def resolved(self, truth: Any = None) -> Plan:
        """The plan with defaults filled in and every field validated.

        ``truth`` (a BRDF measured instead of a preset, see :func:`run`) lets ``material``
        be a free label.
        """
        from gonio.fit import RESIDUALS, parse_model

        info = _material_info(self.material, truth)  # ValueError listing the presets
        model = self.model or info["model"]
        from gonio._validate import check_model_terms

        for m in (model, *(self.compare or ())):
            check_model_terms(m, "model")
        parse_model(model)  # unknown model -> ValueError listing the registered names
        if self.instrument != "lbl":
            raise ValueError(f"instrument {self.instrument!r}; expected 'lbl'")
        if self.mirror not in ("ellipsoid", "hemisphere"):
            raise ValueError(f"mirror {self.mirror!r}; expected 'ellipsoid' or 'hemisphere'")
        angles = tuple(float(a) for a in self.theta_i_deg)
        if not angles or any(not (0.0 <= a < 90.0) or not math.isfinite(a) for a in angles):
            raise ValueError(f"theta_i_deg {self.theta_i_deg!r}: expected angles in [0, 90)")
        if len(set(angles)) != len(angles):
            raise ValueError(f"theta_i_deg {self.theta_i_deg!r} has repeated angles")
        rot = self._resolved_rotations(info["params"], model)
        _distinct_groups(angles, rot)
        exp = self.exposures_s
        if exp is not None:
            exp = tuple(float(e) for e in exp)
            if not exp or any(not (e > 0 and math.isfinite(e)) for e in exp):
                raise ValueError(f"exposures_s {self.exposures_s!r}: expected positive seconds")
        noise = float(self.noise)
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise {self.noise!r}: expected 0 (off), 1 (on) or a factor > 0")
        if not isinstance(self.seed, int | np.integer) or self.seed < 0:
            raise ValueError(f"seed {self.seed!r}: expected a non-negative integer")
        if self.residual not in RESIDUALS:
            raise ValueError(f"residual {self.residual!r}; expected one of {list(RESIDUALS)}")
        compare = self.compare
        if compare is None:  # the defaults that are registered in this installation
            from gonio.brdf import names

            compare = tuple(c for c in DEFAULT_COMPARE.get(model, ()) if c in names())
        compare = tuple(c for c in compare if c != model)
        for c in compare:
            parse_model(c)
        thinning = self._resolved_thinning()
        if not isinstance(self.debias, bool | np.bool_):
            raise ValueError(f"debias {self.debias!r}: expected True or False")
        from gonio.campaign.knowledge import check_corrections

        corrections = None if self.corrections is None else check_corrections(self.corrections)
        if self.calibration is not None and not isinstance(self.calibration, str):
            raise ValueError(f"calibration {self.calibration!r}: expected a folder path")
        d_over_r = self.d_over_r
        if d_over_r is not None:
            d_over_r = float(d_over_r)
            if not (math.isfinite(d_over_r) and 0.0 < d_over_r < 0.5):
                raise ValueError(f"d_over_r {self.d_over_r!r}: expected a ratio in (0, 0.5)")
        n_re = self.restandard_every
        if not (isinstance(n_re, int | np.integer) and not isinstance(n_re, bool)
                and 0 <= n_re <= len(angles)):  # fmt: skip
            raise ValueError(
                f"restandard_every {n_re!r}: expected an integer in [0, {len(angles)}] "
                "(0: no re-measured standard)"
            )
        dn = self.bracket_min_signal_dn
        if dn is not None:
            ok = isinstance(dn, int | float | np.integer | np.floating) and not isinstance(dn, bool)
            if not (ok and math.isfinite(dn) and dn > 0):
                raise ValueError(
                    f"bracket_min_signal_dn {dn!r}: expected a positive number of DN "
                    "(None: the instrument's own)"
                )
            dn = float(dn)
        preset, instrument_seed, binning = self._resolved_instrument()
        return replace(
            self,
            preset=preset,
            instrument_seed=instrument_seed,
            binning=binning,
            thinning=thinning,
            model=model,
            theta_i_deg=angles,
            rotations_deg=rot,
            exposures_s=exp,
            noise=noise,
            seed=int(self.seed),
            compare=compare,
            d_over_r=d_over_r,
            debias=bool(self.debias),
            corrections=corrections,
            restandard_every=int(n_re),
            bracket_min_signal_dn=dn,
        )

    def _resolved_rotations(self, params: Mapping[str, Any], model: str) -> tuple[float, ...]:
        """``rotations_deg``, checked; by default 0, 45 and 90° where the material is
        anisotropic or the model has a lobe with an x/y coefficient, else 0 alone."""
        rot = self.rotations_deg
        if rot is None:
            p = params
            aniso = "alpha_x" in p and "alpha_y" in p and p["alpha_x"] != p["alpha_y"]
            # a Lafortune lobe's C_y multiplies y_i·y_o, which is 0 whenever φi = 0 in the
            # sample frame: without a second rotation C_y is not measured at all
            xy = any(c.strip() in _XY_MODELS for c in model.split("+"))
            rot = (0.0, 45.0, 90.0) if aniso or xy else (0.0,)
        rot = tuple(float(r) for r in rot)
        if not rot or any(not math.isfinite(r) for r in rot) or len(set(rot)) != len(rot):
            raise ValueError(f"rotations_deg {self.rotations_deg!r}: expected distinct angles")
        seen: dict[float, float] = {}
        for r in rot:
            if (m := r % 360.0) in seen:
                raise ValueError(
                    f"rotations_deg {self.rotations_deg!r}: {seen[m]:g} and {r:g} are the same "
                    "rotation (equal modulo 360)"
                )
            seen[m] = r
        return rot

    def _resolved_thinning(self) -> tuple[tuple[str, float], ...]:
        """``thinning`` as (option, value) pairs of ``thinning_mode``, its defaults filled in."""
        if self.thinning_mode not in _THINNING:
            raise ValueError(
                f"thinning_mode {self.thinning_mode!r}; expected one of {sorted(_THINNING)}"
            )
        allowed = _THINNING[self.thinning_mode]
        given = dict(allowed if self.thinning is None else self.thinning)
        bad = sorted(set(given) - set(allowed))
        if bad:
            raise ValueError(
                f"thinning {bad} not options of thinning_mode {self.thinning_mode!r}; "
                f"expected some of {sorted(allowed)}"
            )
        return tuple((str(k), v) for k, v in given.items())

    def _resolved_instrument(self) -> tuple[str, int, tuple[int, int] | None]:
        """``preset``, ``instrument_seed`` and ``binning``, checked, defaults filled in."""
        from gonio.simulator.effects import PRESET_OPTIONS, PRESETS

        if self.preset not in PRESETS:
            raise ValueError(f"preset {self.preset!r}; expected one of {', '.join(PRESETS)}")
        iseed = self.seed if self.instrument_seed is None else self.instrument_seed
        if not isinstance(iseed, int | np.integer) or iseed < 0:
            raise ValueError(f"instrument_seed {iseed!r}: expected a non-negative integer")
        b = self.binning if self.binning is not None else PRESET_OPTIONS[self.preset]["binning"]
        if b is not None:
            import inspect

            from gonio.simulator import LBLInstrument

            sig = inspect.signature(LBLInstrument).parameters  # the camera's pixels
            cam = (sig["width"].default, sig["height"].default)
            try:
                b = tuple(int(x) for x in b)
                ok = len(b) == 2 and (b == (0, 0) or (min(b) >= 1 and b[0] <= cam[0]
                                                      and b[1] <= cam[1]))  # fmt: skip
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ValueError(
                    f"binning {self.binning!r}: expected (width, height) from 1 up to the "
                    f"camera's {cam[0]} x {cam[1]} (a digitiser reduces), or (0, 0) for full "
                    "resolution"
                )
        return self.preset, int(iseed), b

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (tuples as lists); ``bracket_min_signal_dn`` only where set (a plan
        without it writes what it wrote before the field, and resumes the folders made then)."""
        d = asdict(self)
        if d["bracket_min_signal_dn"] is None:
            del d["bracket_min_signal_dn"]
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Plan:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        names = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown plan field(s) {unknown}; expected some of {sorted(names)}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        if kw.get("thinning") is not None:
            kw["thinning"] = tuple(tuple(x) for x in kw["thinning"])
        return cls(**kw)


def _distinct_groups(angles: tuple[float, ...], rotations: tuple[float, ...]) -> None:
    """Refuse angles (or rotations) that would share a raw group folder: its name keeps
    θi to 0.01° and a rotation to 0.1° (:func:`gonio.campaign.folder.group_key`), and two
    captures in one folder would overwrite (or on resume stand in for) one another."""
    from gonio.campaign.folder import group_key

    for name, values, key, step in (
        ("theta_i_deg", angles, group_key, "0.01"),
        ("rotations_deg", rotations, lambda r: group_key(0.0, r), "0.1"),
    ):
        seen: dict[str, float] = {}
        for v in values:
            k = key(v)
            if k in seen:
                raise ValueError(
                    f"{name}: {seen[k]:g} and {v:g} would share the raw group folder {k!r} "
                    f"(its name keeps {step}°); expected angles that differ at {step}°"
                )
            seen[k] = v


def _material_info(material: str, truth: Any = None) -> dict[str, Any]:
    """The preset record, or one made from ``truth`` (a BRDF) for a label that is no preset."""
    from gonio import materials

    if truth is None or material in materials.names():
        info = materials.info(material)
        if truth is not None:
            info = {**info, "model": truth.name, "params": dict(truth.params)}
        return info
    if not isinstance(material, str) or not material.strip() or any(c.isspace() for c in material):
        raise ValueError(f"material {material!r} must be a name without white space")
    return {"model": truth.name, "params": dict(truth.params), "class": "dielectric",
            "source": "user BRDF"}  # fmt: skip


def default_plan(**overrides: Any) -> Plan:
    """The built-in campaign (rolled brass, LBL, ellipsoid, default noise, seed 0), resolved."""
    return Plan(**overrides).resolved()


def capture_seed(seed: int, key: str) -> int:
    """The seed of one capture: a function of the campaign seed and the capture name only.

    ``SeedSequence(seed, spawn_key=(h,))`` with ``h`` the first 8 bytes of SHA-256(key), so
    that captures do not depend on the order in which they are taken (or skipped on resume).
    """
    h = int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "little")
    ss = np.random.SeedSequence(int(seed), spawn_key=(h,))
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


#: the fields an LBL plan file may set (the measurement's design; everything else stays the
#: command line's)
PLAN_FILE_FIELDS = (
    "theta_i_deg", "rotations_deg", "exposures_s", "restandard_every", "bracket_min_signal_dn",
)  # fmt: skip


def read_plan_file(path: Any) -> dict[str, Any]:
    """An LBL plan file (JSON, as ``gonio design`` writes it): ``{"instrument": "lbl",
    "theta_i_deg": [...], "rotations_deg": [...], "restandard_every": N, ...}`` → the
    :class:`Plan` fields of :data:`PLAN_FILE_FIELDS` it sets (checked again by
    :meth:`Plan.resolved`). A ``ValueError`` names the file and what is wrong."""
    from pathlib import Path

    from gonio.io.jsonfile import FileFormatError, read_json

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"plan file {str(p)!r} does not exist")
    try:
        d = read_json(p)  # (depth-limited)
    except FileFormatError as exc:
        raise FileFormatError(f"plan file: not JSON as gonio design writes it: {exc}") from None
    if not isinstance(d, dict) or d.get("instrument", "lbl") != "lbl":
        raise ValueError(f"plan file {str(p)!r}: expected a JSON object with instrument 'lbl'")
    if "theta_i_deg" not in d:
        raise ValueError(f"plan file {str(p)!r}: missing theta_i_deg")
    out: dict[str, Any] = {}
    for k in PLAN_FILE_FIELDS:
        v = d.get(k)
        if v is None:
            continue
        if k == "restandard_every":
            if not isinstance(v, int) or isinstance(v, bool):
                raise ValueError(f"plan file {str(p)!r}: {k} {v!r}: expected an integer")
            out[k] = v
            continue
        if k == "bracket_min_signal_dn":
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"plan file {str(p)!r}: {k} {v!r}: expected a number of DN")
            out[k] = float(v)
            continue
        if (
            not isinstance(v, list)
            or not v
            or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in v
            )
        ):
            raise ValueError(f"plan file {str(p)!r}: {k} {v!r}: expected a list of numbers")
        out[k] = tuple(float(x) for x in v)
    return out
