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
and the camera takes the bracket's frames (:func:`bracket_s`): for each frame the iris is set
where its stop differs from the one already set, and the frame is exposed and read. A
bracket given by its exposure times alone (a count, or times without f-numbers) is taken to
change the iris between its frames only (its first stop already set).

How many frames a capture takes is the instrument's automatic bracket
(:mod:`gonio.simulator.lbl_exposure`: as many f-stops as the scene's dynamic range needs),
so a campaign's time is that of its brackets (:func:`brackets_of`: each capture's exposure
times and f-numbers, from its frames' metadata, which a laboratory's instrument records).
A fixed three frames a capture, the estimate before, is too long: the default campaign
(rolled brass, 21 angles x 3 rotations, instrument 0) took 146 frames on the ``modern``
preset and 153 on ``ward1992``, not 315; its time from its own brackets is 229.4 s and 492.6
s, against 281.8 s (1.23 times) and 883.6 s (1.79 times) at three frames a capture. Its
f-numbers count: the iris moves between captures too (the standard at f/2.8, the background
at f/2, each sample capture from its own darkest stop), 69 and 82 changes against 41 and 48
within the brackets alone (221.0 s and 390.6 s from the exposure times alone). Instruments
0-9 of each preset took 227.1-231.7 s (``modern``) and 465.3-692.1 s (``ward1992``: 147-189
frames).

The campaign's lamp clock (:meth:`gonio.campaign.lbl._SimulatedLBL.clock_s`) is this
schedule's time of each capture at three frames a capture (the lamp's warm-up and drift enter
the standard and the sample about when they would on the real instrument; kept so, since
changing it changes every campaign's samples).

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

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "TIMINGS",
    "Bracket",
    "LBLTiming",
    "bracket_s",
    "brackets_of",
    "estimate_run_time",
    "schedule",
]


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


#: one capture's frames: exposure times (s), or (exposure time, f-number) pairs
Bracket = Sequence[float] | Sequence[tuple[float, float]]


@functools.lru_cache(maxsize=16)
def _counted(n: int) -> list[tuple[float, None]]:
    return [(0.01, None)] * n


def _frames_of(frames: int | Mapping, kind: str, theta: float, rot: float | None
               ) -> list[tuple[float, float | None]]:  # fmt: skip
    """One capture's frames as ``(exposure_s, f_number or None)``: ``frames`` is a count
    (0.01 s each, no f-number) or a mapping from ``(kind, θi in degrees, rotation or None)``
    to a :data:`Bracket`."""
    if isinstance(frames, int | np.integer) and not isinstance(frames, bool):
        if frames < 1:
            raise ValueError(f"frames must be >= 1 per capture, got {frames!r}")
        return _counted(int(frames))
    if not isinstance(frames, Mapping):
        raise ValueError(f"frames must be a count or a mapping of brackets, got {frames!r}")
    got = frames.get((kind, float(theta), rot))
    if got is None or not len(got):
        raise ValueError(f"frames has no exposures for capture {(kind, theta, rot)!r}")
    out = []
    for f in got:
        e, n = (f, None) if np.ndim(f) == 0 else (f[0], f[1])
        e = float(e)
        n = None if n is None else float(n)
        if not (math.isfinite(e) and e > 0) or (n is not None and not (math.isfinite(n) and n > 0)):
            raise ValueError(
                f"frames of capture {(kind, theta, rot)!r}: exposure {e!r} s, f-number {n!r}; "
                "expected positive finite numbers"
            )
        out.append((e, n))
    return out


def bracket_s(
    bracket: Bracket, timing: LBLTiming | None = None, iris: float | None = None
) -> tuple[float, int, float | None]:
    """Time of one capture's frames: each frame's exposure and read-out, and the iris set
    before each frame whose stop differs from the one set.

    Parameters
    ----------
    bracket : sequence
        The frames' exposure times (s; the iris changed between frames, its first stop
        already set), or ``(exposure_s, f_number)`` pairs.
    timing : LBLTiming, optional
        Default the 1992 instrument's.
    iris : float, optional
        The f-number set before the capture (the previous frame's); None: the bracket's
        first stop is already set.

    Returns
    -------
    tuple
        ``(seconds, iris changes, the f-number set after the bracket or None)``.
    """
    fr = _frames_of({("capture", 0.0, None): bracket}, "capture", 0.0, None)
    return _bracket_time(fr, timing or LBLTiming(), iris)


def _bracket_time(fr: list[tuple[float, float | None]], timing: LBLTiming, iris: float | None
                  ) -> tuple[float, int, float | None]:  # fmt: skip
    """:func:`bracket_s` of frames :func:`_frames_of` checked."""
    changes, t = 0, 0.0
    for k, (e, n) in enumerate(fr):
        if (n is None and k > 0) or (n is not None and iris is not None and n != iris):
            changes += 1
        iris = n
        t += e + timing.readout_s
    return t + changes * timing.stop_change_s, changes, fr[-1][1]


def brackets_of(captures: Mapping[tuple, Sequence[Mapping]]) -> dict[tuple, list[tuple]]:
    """The brackets a campaign took, for :func:`schedule`: ``{(kind, θi, rotation):
    [(exposure_s, f_number), ...]}`` from each capture's frames' metadata (``exposure_s``,
    ``f_number``: what the instrument records with each frame)."""
    out = {}
    for key, metas in captures.items():
        try:
            out[key] = [(float(m["exposure_s"]), float(m["f_number"])) for m in metas]
        except (KeyError, TypeError) as e:
            raise ValueError(f"capture {key!r}: a frame without exposure_s or f_number") from e
    return out


def schedule(
    theta_i_deg: Sequence[float],
    rotations_deg: Sequence[float] = (0.0,),
    frames: int | Mapping = 3,
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
    frames : int or mapping
        Frames per capture (each 0.01 s), or ``{(kind, θi, rotation): bracket}`` with kind
        ``"standard"``, ``"background"`` (rotation ``None``) or ``"measured"`` and each
        bracket as :func:`bracket_s` takes it (e.g. :func:`brackets_of` a campaign's frames).
    timing : LBLTiming, optional
        Default the 1992 instrument's.

    Returns
    -------
    list of dict
        One per capture in time order: ``kind``, ``theta_i_deg``, ``rotation_deg``,
        ``start_s``, ``end_s`` and, for a capture, ``n_frames``, ``integration_s`` (its
        exposures) and ``stop_changes``; the manual steps as entries of kind ``"manual"``.
    """
    timing = timing or LBLTiming()
    angles = [float(a) for a in theta_i_deg]
    if not angles or any(not (0.0 <= a < 90.0) for a in angles):
        raise ValueError(f"theta_i_deg {theta_i_deg!r}: expected angles in [0, 90)")
    sweeps: list[tuple[str, float | None]] = [("standard", None), ("background", None)]
    sweeps += [("measured", float(r)) for r in rotations_deg]
    t, arm = 0.0, angles[0]
    iris: float | None = None
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
            dt, changes, iris = _bracket_time(exp, timing, iris)
            t += dt
            out.append({"kind": kind, "theta_i_deg": th, "rotation_deg": rot,
                        "start_s": start, "end_s": t, "n_frames": len(exp),
                        "integration_s": sum(e for e, _ in exp),
                        "stop_changes": changes})  # fmt: skip
        order = order[::-1]  # sweep back
    return out


def estimate_run_time(
    theta_i_deg: Sequence[float],
    rotations_deg: Sequence[float] = (0.0,),
    frames: int | Mapping = 3,
    timing: LBLTiming | None = None,
) -> dict[str, float]:
    """Estimated real-instrument time of an LBL campaign (s), by part.

    Returns ``total_s``, ``move_s`` (arm moves and settling), ``exposure_s`` (integration
    and read-out), ``stop_change_s``, ``manual_s`` (swaps and rotations by hand),
    ``n_captures`` and ``n_frames`` (see :func:`schedule` for the protocol and ``frames``:
    the instrument's brackets, :func:`brackets_of`, or a count of frames a capture).
    """
    timing = timing or LBLTiming()
    sch = schedule(theta_i_deg, rotations_deg, frames, timing)
    caps = [c for c in sch if c["kind"] != "manual"]
    manual = sum(c["end_s"] - c["start_s"] for c in sch if c["kind"] == "manual")
    n_frames = sum(c["n_frames"] for c in caps)
    expo = sum(c["integration_s"] for c in caps)
    stops = sum(c["stop_changes"] for c in caps) * timing.stop_change_s
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
