"""The true (imperfect) Cornell instrument: the effect paths of
:class:`gonio.simulator.cornell.CornellInstrument`.

:class:`TrueInstrument` is mixed into the instrument; its methods run only when the
configuration carries non-zero effects (``CornellConfig.effects``), so the ideal instrument
keeps its own code path, bit for bit. What each effect is and where its magnitude comes from:
:data:`gonio.simulator.cornell_effects.EFFECTS`; the physics:
:mod:`gonio.simulator.cornell_physics`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from gonio.simulator import cornell_physics as phys
from gonio.simulator.cornell_effects import lamp_factor
from gonio.simulator.effects import effect_rng
from numpy.typing import NDArray

__all__ = ["TrueInstrument"]


class TrueInstrument:
    """Effect paths of the Cornell instrument (a mixin; ``self.fx`` holds the magnitudes)."""

    fx: dict[str, float] | None

    def _fx_setup(self) -> None:
        """Realise what the magnitudes alone do not fix (azimuths, the stage noise stream)."""
        from gonio.simulator.cornell import _alpha, _cone_rule

        c, m = self.config, self.fx
        seed = int(c.instrument_seed)
        self.omega_true = c.source_solid_angle * (1.0 + m["source_solid_angle_error"])
        self._alpha_s = _alpha(self.omega_true)
        r, p, w = _cone_rule(self._alpha_s, c.quad_rings, c.quad_phi)
        self._rule_s = (r, p, phys.taper_weights(r, w, self._alpha_s, m["source_cone_taper"]))
        r, p, w = self._rule_d
        self._rule_d = (r, p, phys.taper_weights(r, w, self._alpha_d, m["detector_cone_taper"]))
        az = effect_rng(seed, "cornell", "tilt_azimuths").uniform(0.0, 2 * math.pi, 2)
        self._tilt_az = (float(az[0]), float(az[1]))
        self._moves: dict[tuple, int] = {}
        self._lag = np.zeros(3)
        self.true_angles = np.zeros(3)
        self.clock_s = 0.0
        self._pol_cache: dict[tuple, float] = {}
        self._last_counts: tuple[tuple, NDArray] | None = None  # (read key, noise-free counts)
        self._last_pose: NDArray | None = None  # the event clock's last motor pose (deg)
        from gonio.simulator.cornell_plans import Timing

        self._timing = Timing()

    # ------------------------------------------------------------------ motion
    def _fx_move(self, new: NDArray) -> None:
        """Backlash and positioning noise of a move from ``self.angles`` to ``new``; the noise
        is keyed by the commanded pose and its occurrence, so a dry run
        (:meth:`true_angles_of`) predicts the campaign's true poses exactly."""
        m = self.fx
        b, s = m["stage_backlash_deg"], m["stage_noise_deg"]
        if b == 0 and s == 0:
            self.true_angles = new.copy()
            return
        key = tuple(np.round(np.degrees(new) * 1e4).astype(int).tolist())
        n = self._moves.get(key, 0)
        self._moves[key] = n + 1
        g = effect_rng(int(self.config.instrument_seed), "cornell", "stage", self.seed, *key, n)
        off, self._lag = phys.stage_offsets(np.degrees(new - self.angles), self._lag, b, s, g)
        self.true_angles = new + np.radians(off)

    def true_angles_of(self, angles: NDArray) -> NDArray:
        """The true poses the stages reach for the commanded sequence ``angles`` (N, 3) from
        the present state (a dry run: the instrument's state is left as it was)."""
        saved = (self.angles.copy(), self._lag.copy(), dict(self._moves), self.true_angles.copy())
        out = np.empty_like(np.asarray(angles, float))
        for j, a in enumerate(np.asarray(angles, float)):
            self._fx_move(a)
            self.angles = a.copy()
            out[j] = self.true_angles
        self.angles, self._lag, self._moves, self.true_angles = saved
        return out

    def _fx_state(self) -> tuple:
        return (self._lag.copy(), self.true_angles.copy())

    def _fx_restore(self, state: tuple) -> None:
        self._lag, self.true_angles = state[0].copy(), state[1].copy()

    # ------------------------------------------------------------------ radiometry
    def _fx_cos(self, wi: NDArray) -> NDArray:
        """The true irradiance per unit source radiance: the tapered source cone's mean cos."""
        from gonio.simulator.cornell import _cone_points

        r, p, w = self._rule_s
        pts = _cone_points(np.atleast_2d(wi), r, p)
        return np.clip(pts[:, :, 2], 0.0, None) @ w / w.sum()

    def _fx_expected(self, a: NDArray) -> tuple[NDArray, NDArray]:
        """Cone-averaged true BRDF (footprint included) and the true effective cos at the true
        motor angles ``a`` (N, 3); caches the polarisation factor of each pose."""
        from gonio.simulator.cornell import _cone_points, _lens_area, forward

        m, sample = self.fx, self.sample
        wi0, wo0 = forward(a, self.config.kinematics)
        wi, wo = wi0, wo0
        if m["sample_tilt_rad"] or m["sample_wobble_rad"]:
            wi = phys.tilt_directions(wi0, a[:, 1], m, self._tilt_az)
            wo = phys.tilt_directions(wo0, a[:, 1], m, self._tilt_az)
        ci = self._fx_cos(wi)
        rs, ps, ws = self._rule_s
        rd, pd, wd = self._rule_d
        out = None
        for chunk in np.array_split(np.arange(len(a)), max(1, len(a) // 256)):
            pi = _cone_points(wi[chunk], rs, ps)
            po = _cone_points(wo[chunk], rd, pd)
            f = sample.evaluate_unchecked(pi[:, :, None, :], po[:, None, :, :])
            wgt = ws[:, None] * wd[None, :] * np.clip(pi[:, :, 2], 0, None)[:, :, None]
            sm = (
                np.einsum("mijb,mij->mb", f, wgt)
                if f.ndim == 4
                else np.einsum("mij,mij->m", f, wgt)
            )
            if out is None:
                out = np.empty((len(a),) + sm.shape[1:])
            cc = np.where(ci[chunk] > 0, ci[chunk], 1.0)
            out[chunk] = sm / cc.reshape((-1,) + (1,) * (sm.ndim - 1))
        if sample.has_delta:
            d, rho = sample.delta(wi)
            beta = np.arccos(np.clip(np.sum(d * wo, -1), -1, 1))
            area = _lens_area(beta, self._alpha_s, self._alpha_d)
            w = area / (math.pi * self._alpha_d**2 * self.omega_true) / np.where(ci > 0, ci, 1.0)
            out = out + (rho * w[:, None] if rho.ndim == 2 else rho * w)
        lit = phys.lit_fraction(
            wi0, wo0, m["beam_diameter_mm"], m["fov_diameter_mm"], m["sample_size_mm"]
        )
        out = out * (lit[:, None] if out.ndim == 2 else lit)
        if m["sample_polarisation"] and sample.name == "li_torrance":
            pol = self._fx_polarisation(wi, wo)
            for ang, v in zip(a, pol):
                self._pol_cache[tuple(np.round(np.degrees(ang), 6).tolist())] = float(v)
        return out, ci

    def _fx_polarisation(self, wi: NDArray, wo: NDArray) -> NDArray:
        """``s P r_dd`` per pose: Fresnel's degree of polarisation times the directional-diffuse
        share of the BRDF (centre values, mean over bands)."""
        p = self.sample.params
        dd = type(self.sample)(**{**p, "k_udf": 0.0, "k_uds": 0.0, "k_fs": 0.0, "d_omega_i": None})
        f_dd = np.asarray(dd.evaluate_unchecked(wi, wo), float).reshape(len(wi), -1).mean(1)
        f = np.asarray(self.sample.evaluate_unchecked(wi, wo), float).reshape(len(wi), -1).mean(1)
        share = np.where(f > 0, f_dd / np.where(f > 0, f, 1.0), 0.0)
        n = float(np.mean(np.atleast_1d(p.get("n_ior", 1.5))))
        return self.fx["sample_polarisation"] * phys.fresnel_polarisation(wi, wo, n) * share

    def _fx_counts(
        self,
        positions: Mapping[str, float],
        t: float,
        wl: NDArray,
        target: int,
        q: str | None,
        shutter: bool,
        filt: bool,
        blocked: bool,
    ) -> NDArray:
        """Noise-free counts of one read of the true instrument (see ``expected_counts``)."""
        from gonio.simulator.cornell import TARGETS, forward
        from gonio.simulator.spectra import spectralon_reflectance

        c, m = self.config, self.fx
        counts = np.full(wl.shape, c.bias_counts + c.dark_rate * t)
        if not shutter:
            return counts
        wl = wl + m["wavelength_shift_nm"]  # the true wavelengths of the pixels
        k = self._spectral_k(wl, q)
        ang = np.radians([float(positions[a]) for a in self.axes])
        if blocked and target in (TARGETS["sample"], TARGETS["standard"]):
            sig = np.zeros(wl.shape)
        elif target == TARGETS["sample"]:
            fconv, ci = self._conv_at(ang)
            sig = k * self._f_pixels(fconv, wl) * max(ci, 0.0)
            pol = self._pol_cache.get(tuple(np.round(np.degrees(ang), 6).tolist()), 0.0)
            if pol and q is not None:
                e = math.radians(m["polariser_error_deg"]) if q == "p" else 0.0
                sig = sig * (1.0 + (pol if q == "s" else -pol) * math.cos(2 * e))
        elif target == TARGETS["standard"]:
            wi, wo = forward(ang, c.kinematics)
            ce = float(self._fx_cos(wi)[0])
            lit = float(
                phys.lit_fraction(
                    wi, wo, m["beam_diameter_mm"], m["fov_diameter_mm"], m["sample_size_mm"]
                )[0]
            )
            sig = k * spectralon_reflectance(wl) / math.pi * ce * lit
        elif target == TARGETS["direct"]:
            sig = k / self.omega_true
        else:
            sig = np.zeros(wl.shape)
        if m["slit_fwhm_nm"] and target != TARGETS["beam_trap"]:
            sig = phys.slit_convolve(sig, wl, m["slit_fwhm_nm"])
        if m["stray_light_fraction"]:
            sig = sig + m["stray_light_fraction"] * float(np.mean(sig))
        lamp = lamp_factor(m, self.clock_s)
        stray = c.stray_fraction * k / math.pi
        tr = c.filter_transmission if filt else 1.0
        x = t * tr * lamp * (sig + stray)
        if m["nonlinearity"]:
            x = x * (1.0 - m["nonlinearity"] * x / (c.saturation_counts - c.bias_counts))
        return counts + x

    def _fx_tick_move(self, positions: Mapping[str, float]) -> None:
        """Event clock (``self.event_clock``, the instrument behind the fake devices): a
        change of the motor positions since the last read costs the real instrument's move
        and settling time (:class:`gonio.simulator.cornell_plans.Timing`)."""
        from gonio.simulator.cornell import AXES

        if not all(k in positions for k in AXES):
            return  # expected_counts names the missing stage
        tm = self._timing
        pose = np.array([float(positions[k]) for k in AXES])
        last = self._last_pose
        if last is not None and np.any(pose != last):
            move = float(tm.move_time(np.radians(pose - last)[None])[0])
            self.clock_s += move + tm.settle_s
        self._last_pose = pose

    def _fx_tick_read(self, integration_s: float) -> None:
        """Event clock: a read costs its integration time and the read-out overhead."""
        self.clock_s += float(integration_s) + self._timing.read_overhead_s

    def advance_clock(self, seconds: float) -> None:
        """Campaign time passes (the lamp warms up and drifts)."""
        if self.fx is not None:
            self.clock_s += float(seconds)

    def fx_summary(self) -> dict[str, Any]:
        """The realised instrument (for the campaign's truth side of the summary)."""
        return {} if self.fx is None else {"effects": dict(self.fx), "tilt_azimuths": self._tilt_az}
