"""Calibration of a VR recording: device poses -> joint trackers, the floor, the user's stature and body shape.

* **Devices -> trackers** (:func:`signals_from_devices`): a :class:`DeviceRecording` (headset, two controllers and
  optionally a waist tracker, OpenVR axes: metres, y up, right-handed, the headset looking along its -z) is
  resampled to the model's rate; the headset gives the ``head`` joint (turned half a turn about its y axis, moved
  by :data:`smplik.tracking.io.HMD_TO_HEAD_M`), each controller gives its wrist at the controller's wrist point
  (:data:`CONTROLLERS`: the wrist joint in the controller's own frame) when the controller's rotation is known.
* **Floor and stature** (:func:`calibrate`): the *standing head height* is a high quantile of the head tracker's
  height over the recording (:data:`STANDING_QUANTILE`: the user stands upright for part of it); the body's β is
  chosen so that its rest head joint is that high above its soles (:func:`betas_for_head_height`), unless the
  stature (``--height``) or β (``--betas``) is given. The recording's floor is y = 0 (OpenVR's standing universe)
  when the standing head height is a standing adult's or child's (:data:`HEAD_RANGE_M`); otherwise the origin is
  not the floor (the headset at y ~ 0: a seated or eye-level universe) and the recording is moved so that the
  standing head is where the body's head is (one printed line), or, where the head height is ambiguous and no
  stature is given, refused with one line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np

from smplik.tracking.controllers import CONTROLLERS, controller_offset

STANDING_QUANTILE = 0.95
"""Quantile of the head tracker's height taken as the user's standing head height (robust to crouching, sitting
and looking down for most of the recording; a jump lasts less than 5 % of most recordings)."""
SLOW_MPS = 0.2
"""Vertical head speed (m/s) below which a frame counts toward the standing head height."""
STANDING_SAG_M = 0.010
"""A standing, walking user's head joint is this much lower than the upright rest pose's (chosen on the CMU
validation subjects' clips: 0.3-1.5 cm)."""
HEAD_RANGE_M = (1.0, 2.3)
"""Standing head-joint heights (metres above the floor) taken as a floor-origin recording without asking."""
ORIGIN_NEAR_ZERO_M = 0.5
"""A standing head height below this (in absolute value) means the origin is at the headset, not the floor."""
HEIGHT_MISMATCH_M = 0.15
"""With the stature given, a standing head this far from the body's head height means the origin is off."""


class CalibrationError(ValueError):
    """A recording cannot be calibrated (one line naming the file and the reason)."""


@dataclass(frozen=True)
class DeviceRecording:
    """Raw device poses of a VR recording, N samples (irregular times), OpenVR axes (metres, y up, right-handed).

    Attributes: times (N,) seconds, increasing; hmd, left, right: (positions (N, 3), quaternions (N, 4) w first,
    valid (N,) bool); rotations of a controller may be absent (``has_controller_rotation`` False); waist: the same
    triple or None; source (the file); producer (the layout's name); notes (what the reader detected, one phrase
    each).
    """

    times: np.ndarray
    hmd: tuple[np.ndarray, np.ndarray, np.ndarray]
    left: tuple[np.ndarray, np.ndarray, np.ndarray]
    right: tuple[np.ndarray, np.ndarray, np.ndarray]
    waist: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    has_controller_rotation: bool = True
    source: str = ""
    producer: str = ""
    notes: tuple[str, ...] = ()


def _resample(times: np.ndarray, out_t: np.ndarray, track: tuple[np.ndarray, np.ndarray, np.ndarray], what: str,
              source: str) -> tuple[np.ndarray, np.ndarray]:
    """A device's valid samples linearly interpolated at ``out_t`` (quaternions sign-continuous, renormalised)."""
    P, Q, valid = track
    if valid.sum() < 1:
        raise CalibrationError(f"{source}: the {what} has no valid pose.")
    t, P, Q = times[valid], P[valid], Q[valid].copy()
    flips = np.cumsum(np.r_[False, np.einsum("ij,ij->i", Q[1:], Q[:-1]) < 0]) % 2 == 1
    Q[flips] = -Q[flips]
    p = np.stack([np.interp(out_t, t, P[:, i]) for i in range(3)], -1)
    q = np.stack([np.interp(out_t, t, Q[:, i]) for i in range(4)], -1)
    return p, q / np.linalg.norm(q, axis=-1, keepdims=True)


def signals_from_devices(rec: DeviceRecording, fps: float = 60.0, controller: str = "none") -> Any:
    """A :class:`DeviceRecording` -> :class:`smplik.tracking.io.TrackerSignals` at ``fps`` (module docstring):
    ``head`` (with rotation), ``left_wrist``, ``right_wrist`` (positions: the controllers' wrist points) and
    ``pelvis`` (position) when a waist tracker is present. Left is the controller on the headset's left at the
    first frame (the file's labels are kept when they agree; a swap is corrected)."""
    from smplik.limits import LimitError, check_resampled_frames
    from smplik.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
    from smplik.tracking.io import HMD_TO_HEAD_M, TrackerSignals

    span = float(rec.times[-1] - rec.times[0])
    try:
        check_resampled_frames(span, fps, f"{rec.source}: timestamps {rec.times[0]:g}..{rec.times[-1]:g} s")
    except LimitError as exc:
        raise CalibrationError(str(exc)) from None
    n = int(np.floor(span * fps + 0.05)) + 1  # a span 5 % of a frame short (timestamps in whole ms) still counts
    out_t = rec.times[0] + np.arange(n) / fps
    p_hmd, q_hmd = _resample(rec.times, out_t, rec.hmd, "headset", rec.source)
    R_hmd = quat_wxyz_to_matrix(q_hmd)
    R_head = R_hmd @ np.diag([-1.0, 1.0, -1.0])
    p_head = p_hmd + (R_hmd @ HMD_TO_HEAD_M[:, None])[..., 0]
    if rec.has_controller_rotation and controller not in CONTROLLERS:
        raise CalibrationError(f"unknown controller {controller!r}; choose from {', '.join(CONTROLLERS)}.")
    wrists = {}
    for side, track in (("left", rec.left), ("right", rec.right)):
        p, q = _resample(rec.times, out_t, track, f"{side} controller", rec.source)
        if rec.has_controller_rotation:
            p = p + (quat_wxyz_to_matrix(q) @ controller_offset(controller, side)[:, None])[..., 0]
        wrists[side] = p
    left, right = wrists["left"], wrists["right"]
    if (left[0] - right[0]) @ R_head[0][:, 0] < 0:  # SMPL's head frame has +x to the body's left
        left, right = right, left
    names, P = ["head", "left_wrist", "right_wrist"], [p_head, left, right]
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    Q, has = [matrix_to_quat_wxyz(R_head), ident, ident], [True, False, False]
    if rec.waist is not None:
        names.append("pelvis")
        P.append(_resample(rec.times, out_t, rec.waist, "waist tracker", rec.source)[0])
        Q.append(ident)
        has.append(False)
    return TrackerSignals(float(fps), tuple(names), np.stack(P, 1), np.stack(Q, 1), np.asarray(has), rec.source)


# ----------------------------------------------------------------------------- body heights


@lru_cache(maxsize=8)
def _height_table(gender: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid (33,) of beta_0 in [-4, 4], rest head-joint height above the soles (33,), stature (33,)), metres."""
    import torch

    from smplik.body_model import BodyModelSet
    from smplik.conventions import JOINT_INDEX

    grid = np.linspace(-4.0, 4.0, 33)
    betas = torch.zeros(len(grid), 10)
    betas[:, 0] = torch.as_tensor(grid, dtype=torch.float32)
    model = BodyModelSet.load()[gender]
    z = torch.zeros(len(grid), 3)
    with torch.no_grad():
        verts, joints = model.vertices(z, torch.zeros(len(grid), 23, 3), z, betas)
    low = verts[..., 1].min(-1).values
    head = (joints[:, JOINT_INDEX["head"], 1] - low).double().numpy()
    stature = (verts[..., 1].max(-1).values - low).double().numpy()
    return grid, head, stature


def body_heights(betas: Sequence[float] | np.ndarray, gender: Any = "neutral") -> tuple[float, float]:
    """(rest head-joint height above the soles, stature) of the body ``betas`` (10,), metres."""
    import torch

    from smplik.body_model import BodyModelSet
    from smplik.conventions import JOINT_INDEX, Gender

    b = torch.as_tensor(np.asarray(betas, dtype=np.float32)).reshape(1, 10)
    z = torch.zeros(1, 3)
    with torch.no_grad():
        verts, joints = BodyModelSet.load()[Gender.parse(gender)].vertices(z, torch.zeros(1, 23, 3), z, b)
    low = float(verts[0, :, 1].min())
    return float(joints[0, JOINT_INDEX["head"], 1]) - low, float(verts[0, :, 1].max()) - low


def _betas_for(value: float, column: int, gender: Any, what: str) -> np.ndarray:
    from smplik.conventions import Gender

    grid, head, stature = _height_table(Gender.parse(gender))
    y = (head, stature)[column]
    if not y.min() <= value <= y.max():
        raise CalibrationError(f"{what} {value:.2f} m is outside this body model's range ({y.min():.2f}-"
                               f"{y.max():.2f} m); give --betas instead.")
    out = np.zeros(10)
    out[0] = float(np.interp(value, y, grid))
    return out


def betas_for_head_height(head_m: float, gender: Any = "neutral") -> np.ndarray:
    """β (10,) whose first component puts the rest head joint ``head_m`` above the soles, the others zero."""
    return _betas_for(head_m, 0, gender, "a standing head height of")


def betas_for_stature(stature_m: float, gender: Any = "neutral") -> np.ndarray:
    """β (10,) whose first component gives a rest body of stature ``stature_m`` (max - min vertex height)."""
    if not np.isfinite(stature_m) or not 0.5 <= stature_m <= 2.6:
        raise CalibrationError(f"--height must be a stature in metres in [0.5, 2.6], got {stature_m}.")
    return _betas_for(stature_m, 1, gender, "--height")


# ----------------------------------------------------------------------------- floor and stature


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate` found. floor_y: the recording's floor height (subtracted from every tracker);
    standing_head_m: the standing head height above that floor; stature_m and betas (10,): the body; source of
    the stature: ``"recording"``, ``"--height"`` or ``"--betas"``; message: one line when the origin was moved
    (else empty)."""

    floor_y: float
    standing_head_m: float
    stature_m: float
    betas: np.ndarray
    stature_from: str
    message: str = ""

    def summary(self) -> str:
        """One line for the command's output."""
        src = {"recording": "estimated from the headset", "--height": "given", "--betas": "of --betas"}
        return (f"stature {self.stature_m:.2f} m ({src.get(self.stature_from, self.stature_from)}), standing head "
                f"{self.standing_head_m:.2f} m above the floor")


def standing_head_height(head_y: np.ndarray, fps: float) -> float:
    """The standing head height (the rest pose's head-joint height) of a head-tracker height series (T,) at
    ``fps``: the :data:`STANDING_QUANTILE` quantile of the heights where the head moves up or down slower than
    :data:`SLOW_MPS` (jumps and their apexes pass quickly), plus :data:`STANDING_SAG_M`."""
    y = np.asarray(head_y, dtype=np.float64)
    slow = np.abs(np.gradient(y) * fps) < SLOW_MPS if len(y) > 1 else np.ones(len(y), bool)
    if slow.sum() < 10:
        slow[:] = True
    return float(np.quantile(y[slow], STANDING_QUANTILE)) + STANDING_SAG_M


def calibrate(signals: Any, *, height: float | None = None, betas: Sequence[float] | None = None,
              gender: Any = "neutral") -> Calibration:
    """Floor, standing head height and body of a recording (module docstring). ``signals`` must have a ``head``
    tracker. Raises :class:`CalibrationError` (one line naming the file) where the origin is ambiguous."""
    if "head" not in signals.names:
        raise CalibrationError(f"{signals.source}: no head tracker; the floor and stature come from the headset.")
    head_y = signals.positions[:, signals.names.index("head"), 1]
    h = standing_head_height(head_y, float(signals.fps))
    src = signals.source or "trackers"
    if betas is not None and height is not None:
        raise CalibrationError("give --betas or --height, not both.")
    if betas is not None:
        body = np.asarray(betas, dtype=np.float64)
        head_m, stature = body_heights(body, gender)
        given = "--betas"
    elif height is not None:
        body = betas_for_stature(float(height), gender)
        head_m, stature = body_heights(body, gender)
        given = "--height"
    else:
        body, given = None, "recording"
        head_m, stature = body_heights(np.zeros(10), gender)  # the default body, if the origin must be moved
    lo, hi = HEAD_RANGE_M
    floor, message = 0.0, ""
    plausible = lo <= h <= hi and (given == "recording" or abs(h - head_m) <= HEIGHT_MISMATCH_M)
    if not plausible:
        if given == "recording" and abs(h) >= ORIGIN_NEAR_ZERO_M:
            raise CalibrationError(
                f"{src}: the standing headset is {h:.2f} m above the origin, not a standing user's head height "
                f"({lo:g}-{hi:g} m): the origin is not the floor or the user never stands; give --height (the "
                "user's stature) to place the floor.")
        floor = h - head_m
        how = f"a {stature:.2f} m user, {'the default body: give --height' if given == 'recording' else given}"
        message = (f"{src}: the standing headset is {h:.2f} m above the origin: the origin is not the floor; "
                   f"moved the floor to {floor:+.2f} m ({how})")
        h = head_m
    if body is None:
        try:
            body = betas_for_head_height(h, gender)
        except CalibrationError as exc:
            raise CalibrationError(f"{src}: {exc}") from None
        stature = body_heights(body, gender)[1]
    return Calibration(float(floor), float(h), float(stature), body, given, message)


def apply_floor(signals: Any, cal: Calibration) -> Any:
    """``signals`` with the floor at y = 0 (every tracker moved down by ``cal.floor_y``)."""
    if cal.floor_y == 0.0:
        return signals
    return replace(signals, positions=signals.positions - np.array([0.0, cal.floor_y, 0.0]))
