"""The LBL instrument's scene: the light a capture's frames are made of, rendered once for
any f-number — the beam (source), the sample's reflection over the pixels that see it
(sample, dome), the background and stray light (:mod:`gonio.simulator.lbl_stray`), each at
its pixel's response (:mod:`gonio.simulator.lbl_readout`).

This part knows the optics, the source, the sample's BRDF (or the diffuse standard's true
model) and the effects' magnitudes; it asks the pose (:mod:`gonio.simulator.lbl_pose`) for
the sample's geometry and the stray light for the background. It does not know the
exposure's f-number, the lamp's clock or the sensor's read-out: those are a frame's
(:mod:`gonio.simulator.lbl_frame`).

Radiometry (photon units, see :mod:`gonio.simulator.source`): a sample point lit by the beam
(irradiance ``E`` normal to the beam, dome transmittance ``T``) reflects radiance
``L = f_r(wi, wo) T E cos θ_i``; the dome reflects ``R_m L`` into the lens; a pixel collects
``QE (1 + PRNU) (π / 4N²) p² R_m L t`` electrons (``p`` the pixel pitch). A mirror (delta)
component of reflectance ρ_δ gives radiance ``ρ_δ T E / Ω_s`` over the image of the source
cone, rendered with sub-pixel sampling.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3 (device, Figure 2-4) and eq. 2, which holds at every lit pixel of a scene:
``(V - V_bg)/(V_std - V_bg) · ρ_std/π = f_r``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from gonio.simulator.lbl_pose import SamplePose
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lbl_stray import StrayLight
from gonio.simulator.lbl_trace import Geometry, Optics
from gonio.simulator.source import Source, cone_directions
from numpy.typing import NDArray

from gonio.brdf.base import BRDF

__all__ = ["Scene", "SceneMaker"]


@dataclass
class Scene:
    """A noise-free scene rendered once, for any f-number.

    Electrons at f-number ``N`` (``tk = exposure/N²``, ``k = k0 · tk``)::

        e = bg · tk + dark · exposure + rc · lit · (k·kd0 + k·ks0 · g · isq)  (at idx)
            [+ k · delta value at the delta pixels]

    i.e. the signal and the background scale with 1/N², the dark current does not. A capture
    and every stop of a bracket compose from the same scene with the same arithmetic, so a
    bracket's noise-free frames equal separate captures bit for bit.
    """

    bg: NDArray  # background electrons per second at f/1, per pixel (flat)
    dark: NDArray  # dark electrons per second, per pixel (flat)
    exposure: float
    k0: float  # beam irradiance x dome transmittance x dome reflectance
    idx: NDArray  # candidate pixels (sorted; repeated per ray when supersampled)
    rc: NDArray  # their response (electrons per unit radiance-time at f/1, / rays)
    lit: NDArray  # uint8: inside the beam footprint
    g: NDArray
    isq: NDArray
    kd0: float
    ks0: float
    delta: tuple[NDArray, NDArray] | None
    rays: int = 1
    runs: tuple[NDArray, NDArray] | None = None  # idx as runs (Geometry.runs), if unique


def _ward_kernel_params(model: BRDF) -> tuple[float, float, float, float, bool] | None:
    """(kd, ks, 1/αx², 1/αy², approx) if the model has a specialised kernel, else None."""
    from gonio.brdf.lambert import Lambert
    from gonio.brdf.ward import Ward, WardApprox

    t = type(model)
    if t is Ward or t is WardApprox:
        p = model.params
        return (
            p["rho_d"] / math.pi,
            p["rho_s"] / (4.0 * math.pi * p["alpha_x"] * p["alpha_y"]),
            1.0 / p["alpha_x"] ** 2,
            1.0 / p["alpha_y"] ** 2,
            t is WardApprox,
        )
    if t is Lambert:
        return (model.params["rho"] / math.pi, 0.0, 1.0, 1.0, False)
    return None


def _lobe_width(model: BRDF) -> float | None:
    """Smallest lobe width (radians) of models that declare one, else None."""
    p = model.params
    if "alpha_x" in p and "alpha_y" in p:
        return float(min(p["alpha_x"], p["alpha_y"]))
    if "alpha" in p and isinstance(p["alpha"], float):
        return float(p["alpha"])
    if model.name == "lambert":
        return math.inf
    return None


@dataclass(eq=False)
class SceneMaker:
    """Renders :class:`Scene` s (``fx``: the instrument's non-zero effect magnitudes,
    ``scene_fx``: any of the scene effects on, ``seed``: the instrument seed)."""

    optics: Optics
    source: Source
    pose: SamplePose
    stray: StrayLight
    readout: Readout
    fx: Mapping[str, float]
    scene_fx: bool
    rho_standard: float
    seed: int
    _std_model: BRDF | None = field(default=None, init=False, repr=False)
    _ones_c: NDArray | None = field(default=None, init=False, repr=False)

    def render(
        self, kind, model, theta_i, phi_i, exposure, band, source_samples, kernel=True,
        visible_only=True, rays=1,
    ) -> Scene:  # fmt: skip
        """The noise-free scene, independent of the f-number (see :class:`Scene`), in the
        order the light goes: the beam (source), the sample as it is posed and what it
        reflects into each pixel (sample, dome), the background and stray light (dome,
        lens)."""
        if rays != 1 and not visible_only:
            raise ValueError("rays_per_pixel > 1 needs visible_only=True")
        fx, pose, readout = self.fx, self.pose, self.readout
        g = pose.true_geometry(kind, rays) if fx else self.optics.geometry(rays)
        wi_local, wi_dome, psi = pose.beam(theta_i, phi_i)
        wi_sig = None
        if kind == "brdf" and (fx.get("sample_tilt") or fx.get("sample_height")):
            g, wi_sig = pose.posed(g, theta_i, wi_local, wi_dome, psi)
        bg = self.stray.background_photons(wi_dome)
        dark = readout.dark()
        if kind == "standard":
            model = self.standard_model()
        if model is not None and model.n_bands and band is not None:
            if not (0 <= band < model.n_bands):
                raise ValueError(f"band must be in [0, {model.n_bands}), got {band!r}")
        m = self.optics.mirror
        k0 = self.source.irradiance * m.transmittance * m.reflectance
        if model is None:
            rc = readout.response()[1][:0]
            idx = g.idx[:0]
            lit, gv, isq, kd0, ks0 = idx.astype(np.uint8), rc, rc, 0.0, 0.0
            runs = (idx, idx)
        else:
            idx = g.idx
            rc = readout.candidate_response(g, rays) if fx else readout.rays_response(g, rays)
            lit, gv, isq, kd0, ks0 = self.signal_terms(
                g, model, theta_i, phi_i, 1.0, band, source_samples, kernel, visible_only,
                wi_sig,
            )  # fmt: skip
            if fx.get("holder_rim_height"):
                lit = pose.rim_shadow(g, lit, theta_i, wi_dome)
            runs = g.runs()
        if self.scene_fx:
            bg = self.stray.scene_background(
                bg, kind, model, theta_i, g, rc, lit, gv, isq, kd0, ks0, k0
            )
        delta = None
        if model is not None and model.has_delta:
            wi_local, _, _ = pose.beam(theta_i, phi_i)
            delta = self.delta_terms(model, wi_local, wi_dome, psi, band)
        return Scene(bg, dark, exposure, k0, idx, rc, lit, gv, isq, kd0, ks0, delta, rays, runs)

    def standard_model(self) -> BRDF:
        """The real standard: Lambertian, or the PTFE shape times its deviation from the
        certificate (drawn once from the instrument seed)."""
        m = self._std_model
        if m is None:
            fx = self.fx
            scale = fx.get("standard_non_lambertian", 0.0)
            u = fx.get("standard_certificate_u", 0.0)
            if scale == 0.0 and u == 0.0:
                from gonio.brdf.lambert import Lambert

                m = Lambert(rho=self.rho_standard)
            else:
                from gonio.simulator.effects import effect_rng
                from gonio.simulator.standard import true_standard

                from gonio.brdf.base import CallableBRDF

                rng = effect_rng(self.seed, "standard_certificate_u")
                f = true_standard(self.rho_standard, scale, u, rng)
                m = CallableBRDF(f, "ptfe_standard")
            self._std_model = m
        return m

    def source_dirs(self, model: BRDF, wi_local: NDArray, n: int | None) -> tuple[NDArray, NDArray]:
        if n is None:
            width = _lobe_width(model)
            n = 1 if (width is None or width >= 5.0 * self.source.divergence) else 19
        return cone_directions(wi_local, self.source.divergence, int(n))

    def signal_terms(
        self,
        g: Geometry,
        model: BRDF,
        theta_i: float,
        phi_i: float,
        k: float,
        band: int | None,
        source_samples: int | None,
        kernel: bool,
        visible_only: bool,
        wi_local: NDArray | None = None,
    ) -> tuple[NDArray, NDArray, NDArray, float, float]:
        """Per-candidate signal terms ``(lit, g, isq, kdc, ksc)``.

        A candidate pixel j gains ``resp[j] · lit[j] · (kdc + ksc · g[j] · isq[j])``
        electrons; ``k`` = E T R_m t / N². Ward/Lambert with one source direction use the
        numba exponent kernel and numpy's exp (``g`` = the exponential, ``isq`` = 1/√cos θ_o);
        everything else evaluates ``model.evaluate_unchecked`` on the lit pixels only
        (``g`` = Σ w f_r cos θ_i, ``isq`` = 1). ``g`` (the argument) is the traced geometry
        (one ray per pixel, or supersampled).
        """
        wi_nominal, wi_dome, psi = self.pose.beam(theta_i, phi_i)
        if wi_local is None:  # (a tilted sample passes its own)
            wi_local = wi_nominal
        c, s = math.cos(psi), math.sin(psi)
        bx, by = float(wi_dome[0]), float(wi_dome[1])
        r2 = self.source.spot_radius**2
        wis, wsrc = self.source_dirs(model, wi_local, source_samples)
        kp = _ward_kernel_params(model) if kernel else None
        foot = g.q_max**2 > r2
        if kp is not None and visible_only:
            return self._kernel_terms(g, kp, wis, wsrc, k, (c, s, bx, by, r2), foot)
        return self._evaluated_terms(g, model, wis, wsrc, k, (c, s, bx, by, r2), band, visible_only)

    def _kernel_terms(self, g, kp, wis, wsrc, k, frame, foot):
        """:meth:`signal_terms` of a Ward or Lambert model (``kp``: its kernel parameters)
        through the numba kernels; ``frame`` = (cos ψ, sin ψ, beam x, beam y, spot radius²)."""
        from gonio.simulator import _kernels

        c, s, bx, by, r2 = frame
        n = g.idx.size
        kd, ks, iax2, iay2, approx = kp
        lit = np.empty(n, dtype=np.uint8)
        buf = np.empty(n)
        if len(wis) == 1:
            ix, iy, iz = (float(x) for x in wis[0])
            if ks == 0.0:  # Lambertian: no exponent needed
                _kernels.ward_exponent(
                    g.wx, g.wy, g.wz, g.qx, g.qy, foot, ix, iy, iz, c, s, bx, by, r2,
                    0.0, 0.0, False, buf, lit,
                )  # fmt: skip
                return lit, buf, g.isq, k * kd * iz, 0.0
            _kernels.ward_exponent(
                g.wx, g.wy, g.wz, g.qx, g.qy, foot, ix, iy, iz, c, s, bx, by, r2,
                iax2, iay2, approx, buf, lit,
            )  # fmt: skip
            np.exp(buf, out=buf)
            return lit, buf, g.isq, k * kd * iz, k * ks * math.sqrt(iz)
        _kernels.ward_cone(
            g.wx, g.wy, g.wz, g.qx, g.qy, np.ascontiguousarray(wis), wsrc, c, s, bx, by,
            r2, kd, ks, iax2, iay2, approx, buf, lit,
        )  # fmt: skip
        return lit, buf, self.ones(n), 0.0, k

    def _evaluated_terms(self, g, model, wis, wsrc, k, frame, band, visible_only):
        """:meth:`signal_terms` of any model: ``model.evaluate_unchecked`` on the lit
        candidates (``visible_only``), else on every pixel of the image, masked afterwards
        (the benchmark's "no skip" reference); ``frame`` as in :meth:`_kernel_terms`."""
        c, s, bx, by, r2 = frame
        n = g.idx.size
        if visible_only:
            wx, wy, wz, qx, qy = g.wx, g.wy, g.wz, g.qx, g.qy
        else:
            # the "no skip" reference of the benchmark: evaluate the BRDF on every pixel of
            # the image, mask afterwards, then keep the candidates' values
            wx, wy, wz, qx, qy, on, pos = self.optics.all_field_arrays()
        p = qx * bx + qy * by
        litb = (qx * qx + qy * qy - p * p <= r2) & (wz > 0.0)
        if visible_only:  # the lit candidates' directions only
            on = np.flatnonzero(litb)
            wx, wy, wz = wx[on], wy[on], wz[on]
        wo = np.stack([c * wx + s * wy, -s * wx + c * wy, wz], axis=-1)
        acc = np.zeros(wo.shape[0])
        for wi_m, w_m in zip(wis, wsrc):
            f = np.asarray(model.evaluate_unchecked(wi_m, wo), dtype=np.float64)
            if f.ndim == 2:
                f = f.mean(axis=-1) if band is None else f[:, band]
            acc += w_m * f * max(float(wi_m[2]), 0.0)
        if not np.isfinite(acc).all():
            raise ValueError(f"BRDF {model!r} returned non-finite values")
        if visible_only:
            full = np.zeros(n)
            full[on] = acc
            return litb.astype(np.uint8), full, self.ones(n), 0.0, k
        masked = np.where(litb & on, acc, 0.0)
        return (litb & on)[pos].astype(np.uint8), masked[pos], self.ones(n), 0.0, k

    def ones(self, n: int) -> NDArray:
        """An array of ``n`` ones (kept: the generic path's ``isq``)."""
        if self._ones_c is None or self._ones_c.size != n:
            self._ones_c = np.ones(n)
        return self._ones_c

    def delta_terms(
        self, model: BRDF, wi_local: NDArray, wi_dome: NDArray, psi: float, band: int | None,
        sub: int = 8,
    ) -> tuple[NDArray, NDArray] | None:  # fmt: skip
        """Mirror component: radiance ρ_δ E/Ω_s over the image of the source cone.

        Returns ``(pixels, electrons per unit k)`` (add ``k · value``; ``k`` = E T R_m t/N²),
        or None when the model has no mirror reflectance here.
        """
        d_local, rho = model.delta(wi_local)
        rho = np.asarray(rho, dtype=np.float64)
        if rho.ndim == 1:
            rho = rho.mean() if band is None else rho[band]
        rho = float(rho)
        if rho <= 0.0:
            return None
        g = self.optics.geometry(1)
        resp, _ = self.readout.response()
        lens, mirror = self.optics.lens, self.optics.mirror
        c, s = math.cos(psi), math.sin(psi)
        d = np.asarray(d_local, dtype=np.float64)
        d_dome = np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]])
        gam = self.source.divergence
        cosang = g.wx * d_dome[0] + g.wy * d_dome[1] + g.wz * d_dome[2]
        near = np.flatnonzero(cosang >= math.cos(min(gam + 2.0 * g.pixel_angle, math.pi)))
        if near.size == 0:
            return None
        pix = g.idx[near]
        rows, cols = np.divmod(pix, g.width)
        off = (np.arange(sub) + 0.5) / sub - 0.5
        ou, ov = np.meshgrid(off, off)
        uv = np.stack(
            [cols[:, None] + ou.ravel()[None, :], rows[:, None] + ov.ravel()[None, :]], axis=-1
        )
        dirs = lens.unproject(uv)
        tr = mirror.trace(dirs)
        q = tr["sample_point"] - mirror.sample_position
        p = q[..., 0] * wi_dome[0] + q[..., 1] * wi_dome[1]
        ok = (
            tr["valid"]
            & lens.in_field(uv)
            & (q[..., 0] ** 2 + q[..., 1] ** 2 <= self.optics.sample_radius**2)
            & (q[..., 0] ** 2 + q[..., 1] ** 2 - p * p <= self.source.spot_radius**2)
            & (tr["wo"] @ d_dome >= math.cos(gam))
        )
        cover = ok.mean(axis=-1)
        radiance = rho / self.source.solid_angle  # per unit beam irradiance (k carries E)
        return pix, resp[pix] * radiance * cover
