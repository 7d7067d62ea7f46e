"""How long an LBL campaign takes on the real instrument: motions, exposures, manual steps.

Ward's prototype moves the source arm with a motor and the sample by hand: "the light source
is moved by a computer-controlled motor during data collection, and the sample is rotated
manually. Because the hemisphere of reflected directions is captured in a single image, data
collection proceeds quite rapidly and a complete BRDF can be recorded in a few minutes,
including time for manual rotation of the sample" (Ward 1992, §3.1).

The protocol timed here (:func:`schedule`) is the one that needs the fewest manual steps:
the standard swept over every incidence angle, then the empty holder (the background image),
then the sample at each rotation, one sweep per rotation; between sweeps the sample is
swapped or rotated by hand. At each incidence the arm moves (trapezoidal profile), settles,
and the camera takes the bracket's frames: for each frame the iris is set (except for the
first stop, already set by the previous frame) and the frame is exposed and read. The
campaign's lamp clock (:attr:`gonio.simulator.lbl.LBLInstrument.clock_s`) is this schedule's
time of each capture, so the lamp's warm-up and drift enter the standard and the sample at
the times they would on the real instrument.

Speeds and durations are assumed values (the paper gives only the total). With them Ward's
21 incidence angles at one rotation, three frames a capture, take 530 s (8.8 min, 378 s of
it turning the iris by hand) on the 1992 instrument and 173 s (2.9 min) on a modern one with
a motorised iris: the paper's "a few minutes".

References
----------
Ward, G. J. (1992). Measuring and modeling anisotropic reflection. Computer Graphics
(Proc. SIGGRAPH '92), 26(2), 265-272, §3.1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["TIMINGS", "LBLTiming", "estimate_run_time", "schedule"]


@dataclass(frozen=True)
class LBLTiming:
    """Speeds and durations of one LBL instrument (assumed values).

    Parameters
    ----------
    arm_speed, arm_acceleration : float
        Source arm, rad/s and rad/s² (a stepper on a pivoting arm).
    settle_s : float
        Wait after each arm move (the arm's vibration, the lamp's filament).
    readout_s : float
        Time to read (digitise) one frame: one video frame (1/30 s) in 1992.
    stop_change_s : float
        Time to change the iris: by hand on a 1992 fisheye (~3 s), a motorised iris today.
    rotate_sample_s : float
        Rotating the sample by hand to the next φ (Ward's "manual rotation").
    swap_s : float
        Taking out and putting in a sample or the standard by hand.
    """

    arm_speed: float = math.radians(10.0)
    arm_acceleration: float = math.radians(20.0)
    settle_s: float = 0.5
    readout_s: float = 1.0 / 30.0
    stop_change_s: float = 3.0
    rotate_sample_s: float = 20.0
    swap_s: float = 30.0

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            v = float(getattr(self, name))
            positive = name in ("arm_speed", "arm_acceleration")
            if not math.isfinite(v) or v < 0.0 or (positive and v == 0.0):
                want = "> 0" if positive else ">= 0"
                raise ValueError(f"LBLTiming.{name} must be finite and {want}, got {v!r}")

    def move_time(self, delta: float) -> float:
        """Trapezoidal-profile time of an arm move by ``delta`` radians."""
        d, v, a = abs(float(delta)), self.arm_speed, self.arm_acceleration
        if d == 0.0:
            return 0.0
        return 2.0 * math.sqrt(d / a) if d < v * v / a else d / v + v / a


#: the 1992 prototype and a modern build
TIMINGS: dict[str, LBLTiming] = {
    "ward1992": LBLTiming(),
    "modern": LBLTiming(readout_s=0.05, stop_change_s=0.3, rotate_sample_s=10.0, swap_s=20.0),
}


def _frames_of(frames: int | dict, kind: str, theta: float, rot: float | None) -> list[float]:
    """Exposure times of one capture: ``frames`` is a count (0.01 s each) or a mapping from
    ``(kind, θi in degrees, rotation or None)`` to a list of exposure times."""
    if isinstance(frames, int | np.integer):
        if frames < 1:
            raise ValueError(f"frames must be >= 1 per capture, got {frames!r}")
        return [0.01] * int(frames)
    got = frames.get((kind, float(theta), rot))
    if not got:
        raise ValueError(f"frames has no exposures for capture {(kind, theta, rot)!r}")
    return [float(t) for t in got]


def schedule(
    theta_i_deg: Sequence[float],
    rotations_deg: Sequence[float] = (0.0,),
    frames: int | dict = 3,
    timing: LBLTiming | None = None,
) -> list[dict]:
    """The campaign on the real instrument, capture by capture, with its times.

    Parameters
    ----------
    theta_i_deg : sequence of float
        Incidence angles, degrees (swept in this order, back and forth: each sweep starts
        where the last ended).
    rotations_deg : sequence of float
        Sample rotations; one sample sweep per rotation.
    frames : int or dict
        Frames per capture (each 0.01 s), or ``{(kind, θi, rotation): [exposure_s, ...]}``
        with kind ``"standard"``, ``"background"`` (rotation ``None``) or ``"measured"``.
    timing : LBLTiming, optional
        Default the 1992 instrument's.

    Returns
    -------
    list of dict
        One per capture in time order: ``kind``, ``theta_i_deg``, ``rotation_deg``,
        ``start_s``, ``end_s``; the manual steps as entries of kind ``"manual"``.
    """
    timing = timing or LBLTiming()
    angles = [float(a) for a in theta_i_deg]
    if not angles or any(not (0.0 <= a < 90.0) for a in angles):
        raise ValueError(f"theta_i_deg {theta_i_deg!r}: expected angles in [0, 90)")
    sweeps: list[tuple[str, float | None]] = [("standard", None), ("background", None)]
    sweeps += [("measured", float(r)) for r in rotations_deg]
    t, arm = 0.0, angles[0]
    out: list[dict] = []
    order = angles
    for k, (kind, rot) in enumerate(sweeps):
        if k:
            manual = timing.rotate_sample_s if kind == sweeps[k - 1][0] else timing.swap_s
            out.append({"kind": "manual", "theta_i_deg": arm, "rotation_deg": rot,
                        "start_s": t, "end_s": t + manual})  # fmt: skip
            t += manual
        for th in order:
            t += timing.move_time(math.radians(th - arm))
            t += timing.settle_s if th != arm or not out else 0.0
            arm = th
            start = t
            exp = _frames_of(frames, kind, th, rot)
            t += sum(exp) + len(exp) * timing.readout_s + (len(exp) - 1) * timing.stop_change_s
            out.append({"kind": kind, "theta_i_deg": th, "rotation_deg": rot,
                        "start_s": start, "end_s": t})  # fmt: skip
        order = order[::-1]  # sweep back
    return out


def estimate_run_time(
    theta_i_deg: Sequence[float],
    rotations_deg: Sequence[float] = (0.0,),
    frames: int | dict = 3,
    timing: LBLTiming | None = None,
) -> dict[str, float]:
    """Estimated real-instrument time of an LBL campaign (s), by part.

    Returns ``total_s``, ``move_s`` (arm moves and settling), ``exposure_s`` (integration
    and read-out), ``stop_change_s``, ``manual_s`` (swaps and rotations by hand),
    ``n_captures`` and ``n_frames`` (see :func:`schedule` for the protocol).
    """
    timing = timing or LBLTiming()
    sch = schedule(theta_i_deg, rotations_deg, frames, timing)
    caps = [c for c in sch if c["kind"] != "manual"]
    manual = sum(c["end_s"] - c["start_s"] for c in sch if c["kind"] == "manual")
    n_frames = sum(len(_frames_of(frames, c["kind"], c["theta_i_deg"], c["rotation_deg"]))
                   for c in caps)  # fmt: skip
    expo = sum(
        sum(_frames_of(frames, c["kind"], c["theta_i_deg"], c["rotation_deg"])) for c in caps
    )
    stops = (n_frames - len(caps)) * timing.stop_change_s
    total = sch[-1]["end_s"]
    return {
        "total_s": total,
        "move_s": total - manual - expo - n_frames * timing.readout_s - stops,
        "exposure_s": expo + n_frames * timing.readout_s,
        "stop_change_s": stops,
        "manual_s": manual,
        "n_captures": float(len(caps)),
        "n_frames": float(n_frames),
    }
