"""The LBL instrument's true geometry and the posed sample: where the beam comes from in the
sample's and the dome's frames, the ideal trace bent by the dome's figure error and cut by
occlusion (lens body, holder rim), and the sample in its own tilted, raised frame.

This part knows the optics (:class:`~gonio.simulator.lbl_trace.Optics`), the source arm's
azimuth, the geometric effects' magnitudes and the instrument seed; of the camera only each
candidate pixel's response (which it carries along when a pose drops candidates). It knows
nothing of the BRDF, the sensor's read-out or the exposure.

References
----------
.. [Ward1992] G. J. Ward, "Measuring and modeling anisotropic reflection", Computer Graphics
   (Proc. SIGGRAPH '92) 26(2), 265-272, 1992. https://doi.org/10.1145/142920.134078

Ward 1992, §3: the source arm sets θ_i, the sample holder's rotation φ_i. The effects'
physical sources are in :mod:`gonio.simulator.effects`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from gonio.simulator.lbl_readout import Readout
from gonio.simulator.lbl_trace import Geometry, Optics, _trace_geometry
from gonio.simulator.source import Source
from numpy.typing import NDArray

__all__ = ["GEOMETRY_FX", "SamplePose"]

#: the effects that change the traced geometry
GEOMETRY_FX = ("dome_slope_error", "lens_body_height", "holder_rim_height")


def _base_radii(base: list) -> NDArray:
    """The radii ``hypot(qx, qy)`` of the unmoved sample points of a posed geometry's cached
    base (:meth:`SamplePose.posed`), computed once a base."""
    if len(base) == 7:
        base.append(np.hypot(base[3], base[4]))
    return base[7]


def _near_rim(g: Any, r_min: float) -> NDArray[np.int64]:
    """Ascending indices of the candidates of ``g`` whose sample point lies farther than
    ``r_min`` from the axis, ``hypot(qx, qy) > r_min``. A raised sample's points are its
    unmoved points shifted by at most ``shift``: only those unmoved beyond ``r_min -
    shift`` are tested (the same values, a fraction of the work)."""
    r_q = g.__dict__.get("_r_q")
    if r_q is not None:
        return np.flatnonzero(r_q > r_min)
    bound = g.__dict__.get("_r_bound")
    if bound is None:
        r_q = g.__dict__["_r_q"] = np.hypot(g.qx, g.qy)
        return np.flatnonzero(r_q > r_min)
    base, shift = bound
    cand = np.flatnonzero(_base_radii(base) > r_min - shift - 1e-9 * (1.0 + shift))
    return cand[np.hypot(g.qx[cand], g.qy[cand]) > r_min]


@dataclass(eq=False)
class SamplePose:
    """The sample as the instrument holds it: its incidence frames, its true traced
    geometry and its pose."""

    optics: Optics
    #: the source arm (its azimuth)
    source: Source
    #: each candidate pixel's response, carried along when a pose drops candidates
    readout: Readout
    #: the instrument's non-zero effect magnitudes
    fx: Mapping[str, float]
    #: the instrument seed (the tilt's azimuth)
    seed: int
    #: the dome's traced points and reflected rays (once), the true geometries (per height)
    _dome_trace: Any = field(default=None, init=False, repr=False)
    _true_geometry: dict[float, Geometry] = field(default_factory=dict, init=False, repr=False)
    #: the tilted directions of a geometry per holder rotation: ``(id(g), psi) -> (g, base)``;
    #: this instrument's own (its tilt, its tilt's azimuth and its pixels' response), not the
    #: geometry's, which instruments with the same optics share
    _tilted: dict[tuple[int, float], tuple[Geometry, list]] = field(
        default_factory=dict, init=False, repr=False
    )

    def beam(self, theta_i: float, phi_i: float) -> tuple[NDArray, NDArray, float]:
        """(wi_local, wi_dome, psi): psi = dome azimuth of the sample's x axis."""
        psi = self.source.arm_azimuth - phi_i
        st = math.sin(theta_i)
        wi_local = np.array([st * math.cos(phi_i), st * math.sin(phi_i), math.cos(theta_i)])
        a = self.source.arm_azimuth
        wi_dome = np.array([st * math.cos(a), st * math.sin(a), math.cos(theta_i)])
        return wi_local, wi_dome, psi

    def true_geometry(self, kind: str, rays: int) -> Geometry:
        """The true geometry: the dome's figure error, occlusion, and (for a sample) the
        sample plane at its height; the ideal traced geometry when none applies."""
        fx = self.fx
        h = fx.get("sample_height", 0.0) if kind == "brdf" else 0.0
        if h == 0.0 and not any(k in fx for k in GEOMETRY_FX):
            return self.optics.geometry(rays)
        if rays != 1:
            raise ValueError(
                "rays_per_pixel > 1 is not supported with the dome, occlusion or sample-height "
                "effects (set them to 0 or use one ray per pixel)"
            )
        cache = self._true_geometry
        g = cache.get(h)
        if g is None:
            from gonio.simulator import lbl_effects as le

            m, optics = self.optics.mirror, self.optics
            slope = None
            if fx.get("dome_slope_error", 0.0):
                r = max(m.semi_axes)
                mag, seed = fx["dome_slope_error"], self.seed
                slope = lambda p: le.slope_field(p, mag, r, seed)  # noqa: E731
            hit = self._dome_trace  # (mirror points, reflected rays): once

            def tracer(dirs):
                nonlocal hit
                if hit is None:
                    hit = self._dome_trace = le.dome_rays(m, dirs, slope)
                return le.to_plane(*hit, h)

            keep = None
            if fx.get("lens_body_height", 0.0) or fx.get("holder_rim_height", 0.0):

                def keep(tr, q):
                    return ~le.view_blocked(
                        tr["sample_point"], tr["wo"], tr["point"], m, optics.sample_radius, fx
                    )

            # the ideal trace's camera rays: the same lens and pixels
            g = _trace_geometry(
                m, optics.lens, optics.sample_radius, 1, tracer, keep, optics.geometry(1)
            )
            cache[h] = g
        return g

    def posed(self, g: Geometry, theta_i: float, wi_local, wi_dome, psi: float):
        """The sample's geometry in its own (tilted, raised) frame: ``(geometry, wi_local)``.

        The tilt is fixed in the sample (azimuth from the instrument seed), so it turns with
        the holder: reflected directions are rotated by ``Rz(ψ) T Rz(-ψ)`` in the dome frame
        (the kernels then apply ``Rz(-ψ)``) and the incidence by ``T``; candidates whose
        direction falls below the tilted horizon are dropped. A raised sample moves the
        beam footprint by ``h tan θi`` towards the source (the plane's tilt within the
        footprint, below 0.1 mm, is neglected).
        """
        from gonio.simulator import lbl_effects as le
        from gonio.simulator.effects import effect_rng

        fx = self.fx
        tilt = fx.get("sample_tilt", 0.0)
        h = fx.get("sample_height", 0.0)
        c_arr = np.ascontiguousarray
        hit = self._tilted.get((id(g), psi))  # the tilted directions, once per holder rotation
        base = None if hit is None else hit[1]
        if base is None:
            rc = self.readout.candidate_response(g, 1)
            if tilt:
                az = effect_rng(self.seed, "sample_tilt").uniform(0, 2 * math.pi)
                t = le.tilt_rotation(tilt, float(az))
                c, s = math.cos(psi), math.sin(psi)
                rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                mm = rz @ t @ rz.T
                w = [mm[j, 0] * g.wx + mm[j, 1] * g.wy + mm[j, 2] * g.wz for j in range(3)]
                keep = np.flatnonzero(w[2] > 1e-9)
                if keep.size == g.idx.size:
                    keep = None
                else:
                    w = [a[keep] for a in w]
            else:
                t, w, keep = np.eye(3), [g.wx, g.wy, g.wz], None
            sub = (lambda a: a) if keep is None else (lambda a: c_arr(a[keep]))
            base = [
                t, [c_arr(a) for a in w], sub(g.idx), sub(g.qx), sub(g.qy), sub(rc),
                1.0 / np.sqrt(w[2]),
            ]  # fmt: skip
            self._tilted[(id(g), psi)] = (g, base)  # (g held: its id is not reused)
        t, (wx, wy, wz), idx, qx, qy, rc, isq = base[:7]
        if h:
            qx = qx - h * wi_dome[0] / wi_dome[2]
            qy = qy - h * wi_dome[1] / wi_dome[2]
        posed = replace(
            g, idx=idx, wx=wx, wy=wy, wz=wz, qx=qx, qy=qy, isq=isq,
            q_max=float(np.sqrt((qx * qx + qy * qy).max(initial=0.0))),
        )  # fmt: skip
        posed.__dict__["_rc"] = rc
        posed.__dict__["_runs"] = g.runs() if idx is g.idx else False
        # its points' radii lie within |h| tan θi of the unmoved ones' (see _near_rim)
        shift = abs(h) * math.hypot(wi_dome[0] / wi_dome[2], wi_dome[1] / wi_dome[2]) if h else 0.0
        posed.__dict__["_r_bound"] = (base, shift)
        posed.__dict__["_theta_o_key"] = (id(g), psi)  # (one albedo map per rotation)
        return posed, t @ wi_local

    def rim_shadow(self, g: Geometry, lit: NDArray, theta_i: float, wi_dome: NDArray) -> NDArray:
        """``lit`` with the candidates of ``g`` in the holder rim's shadow unlit (a copy when
        any is; only points within ``h tan θi`` of the rim can be in its shadow)."""
        from gonio.simulator.lbl_effects import beam_shadowed

        optics = self.optics
        h_rim = self.fx["holder_rim_height"]
        near = _near_rim(g, 1.25 * optics.sample_radius - h_rim * math.tan(theta_i) - 1e-12)
        if near.size:
            shadow = beam_shadowed(
                g.qx[near], g.qy[near], wi_dome, optics.mirror.half_separation,
                optics.sample_radius, h_rim,
            )  # fmt: skip
            lit = lit.copy()
            lit[near[shadow]] = 0
        return lit
