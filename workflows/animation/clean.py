"""Cleaning an estimated motion: temporal smoothing, foot contacts, foot locking, and the metrics that judge them.

All functions are pure and batched over frames (axis 0 is time, ``T`` frames at ``fps``).

The default cleaning, ``"adaptive"`` (:func:`denoise_motion`), smooths every channel (each joint's quaternion
components, the root's axes) as much as its own measured noise asks (:mod:`.denoise`), after repairing
single-frame glitches found against the clip's own noise (:func:`glitch_frames`); foot locks then release on a
lift (:func:`split_on_lift`), blend by offset at most ``blend_max_m`` per frame (:func:`lock_targets`) and move
the root by the locked feet's offsets first (:func:`root_shift_from_locks`). :func:`sequence_clean` (a sequence
solve, :mod:`smplik.sequence`, with an optional pose budget) and the filters below are the other choices, measured
against a known truth in ``benchmarks/animation_truth.py``.

Smoothing (:func:`smooth_motion`) filters the local joint rotations as unit quaternions (scalar
first, made sign-continuous over time, renormalised after filtering) and the root translation:

* ``"one_euro"``: the One-Euro filter (Casiez, Roussel and Vogel, CHI 2012), a low-pass whose
  cutoff rises with the signal's speed, ``fc = min_cutoff + beta * |dx/dt|``: slow parts (where
  jitter shows) are smoothed hard, fast real motion passes with little lag. Run forward then
  backward (``zero_phase``) so the result has no lag at all.
* ``"savgol"``: a plain Savitzky-Golay filter (:func:`smplik.smoothing.savgol_smooth`, as
  ``scipy.signal.savgol_filter``), the baseline.

Foot contacts (:func:`foot_contacts`): a foot (SMPL's ``left_foot``/``right_foot``, the ball of the
foot) touches the floor where it is low (within ``height_m`` of the clip's floor, :func:`floor_plane`: a
plane fitted under the standing feet, level by default, tilted where the feet show it, e.g. a camera's
pitch in camera space; y is up) **and** slow (per axis below ``speed_mps`` or ``noise_ratio`` times the
clip's own foot noise on that axis, :func:`foot_noise`, whichever is larger: a monocular estimator's depth
jitters several times its image axes); runs extend over neighbouring low frames up to ``release_ratio``
times that (hysteresis), and runs shorter than ``min_frames`` are dropped. Locking (:func:`lock_feet`) pins the
foot to its mean position over each contact run (blended in and out, :func:`lock_targets`) by a two-bone IK of the leg
(:func:`two_bone_ik`: hip, knee, ankle) that keeps the ankle's world rotation, so the foot joint
lands on the locked point exactly when the leg can reach it.

Plausibility (:func:`glitch_frames`): single-frame glitches (a pose that jumps away and comes back, as
when a tracker briefly swaps limbs: joint positions, limb joints' rotations, :func:`rotation_spikes`, and
left/right swaps, :func:`swap_frames`, each against the clip's own noise) are flagged and, before smoothing,
replaced by interpolating their neighbours.

Metrics (:func:`motion_metrics`), on joint positions ``(T, 24, 3)`` in metres: jitter = mean joint
acceleration ``|p[t+1] - 2 p[t] + p[t-1]|`` (mm/frame^2); skating = mean speed of the foot joints
during contact (mm/frame); pose fidelity = MPJPE to reference joints with both pelvises at the origin (mm, as
HMR papers report MPJPE); trajectory change = mean pelvis distance (mm), reported separately.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.contacts import (  # the detector moved to smplik (the tracker's labels use it); its names stay here
    FLOOR_TILT_PRIOR as FLOOR_TILT_PRIOR,
)
from smplik.contacts import (
    FOOT_JOINTS,
    _runs,
    foot_contacts,
    foot_noise,
    ground_drift,
    ground_of,
    joint_speed,
)
from smplik.contacts import contact_threshold as contact_threshold
from smplik.contacts import floor_plane as floor_plane
from smplik.contacts import ground_velocity as ground_velocity
from smplik.contacts import height_above_floor as height_above_floor
from smplik.contacts import stance_noise as stance_noise
from smplik.conventions import JOINT_INDEX, PARENTS
from smplik.limb_ik import two_bone_ik
from smplik.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from smplik.smoothing import savgol_smooth

LEG_CHAINS = ((JOINT_INDEX["left_hip"], JOINT_INDEX["left_knee"], JOINT_INDEX["left_ankle"]),
              (JOINT_INDEX["right_hip"], JOINT_INDEX["right_knee"], JOINT_INDEX["right_ankle"]))
"""(hip, knee, ankle) per side (left, right)."""

SmoothingMethod = Literal["adaptive", "sequence", "one_euro", "savgol", "none"]


class CleanError(ValueError):
    """Invalid cleaning settings (one line)."""


@dataclass(frozen=True)
class CleanConfig:
    """How :func:`smooth_motion` and :func:`lock_feet` clean a motion."""

    smoothing: SmoothingMethod = "adaptive"
    """``"adaptive"`` (the default: each channel smoothed as much as its measured noise asks,
    :func:`denoise_motion`), ``"sequence"`` (a sequence solve on the estimator's joints, foot locks included:
    :func:`sequence_clean`), ``"one_euro"`` (zero-phase), ``"savgol"`` (plain Savitzky-Golay) or ``"none"``."""
    noise_gain: float = 1.0
    """Adaptive: multiplier of each channel's smoothness (chosen by :func:`.denoise.sure_smoothness`);
    noise correlated over frames raises it further (:func:`correlation_gain`)."""
    clean_noise_share: float = 0.3
    """Adaptive: a clip whose noise is below this share of its frame-to-frame change (median over channels,
    :func:`.denoise.noise_share`: 0.36-0.7 on noisy estimates and the known-truth checks, 0.11-0.22 on the clean
    world-frame estimates of GVHMR, WHAM, AIST++) is a *clean estimate*: smoothed at least ``min_smoothness``,
    without ``motion_trust`` (measured against a noise far below the motion, the trust would hand the estimator's
    own jitter back). Noisy clips keep the measured smoothness and the trust: a floor there bends fast motion."""
    min_smoothness: float = 3.0
    """Adaptive: the least smoothness of every channel of a clean estimate (per-frame Whittaker weight; the
    previous default's sequence solve used 2 on joint paths; 0: the measured noise alone decides)."""
    motion_trust: float = 1.0
    """Adaptive: how much more the data count where the smoothing would bend fast motion
    (:func:`workflows.animation.denoise.motion_weights`; 0: not at all)."""
    smoothness: float = 2.0
    """Sequence: weight of the joints' squared acceleration (m/frame^2) against their squared offset (m) from
    the estimate (:class:`smplik.sequence.SequenceConfig`); higher smooths more."""
    pose_budget_mm: float | None = None
    """Sequence: most the smoothing may move the pose from the estimate (pelvis-aligned MPJPE of the smoothed
    joint paths, character space, mm): ``smoothness`` is halved until it does not (:func:`budgeted_smoothness`).
    None (the default): no cap. (A cap keeps the estimator's own error: the aim is the true motion.)"""
    lock_weight: float = 1000.0
    """Sequence: weight of a locked foot's position against the estimate's (1)."""
    min_cutoff_hz: float = 3.0
    """One-Euro: cutoff (Hz) of slow motion; lower smooths more."""
    beta: float = 1.0
    """One-Euro: how fast the cutoff rises with speed (per unit/s: rad/s for rotations, m/s for the root)."""
    d_cutoff_hz: float = 1.0
    """One-Euro: cutoff (Hz) of the speed estimate."""
    savgol_window: int = 9
    """Savitzky-Golay: window length in frames (odd)."""
    savgol_order: int = 2
    """Savitzky-Golay: polynomial order."""
    foot_lock: bool = True
    """Detect foot contacts and lock the feet by leg IK."""
    contact_height_m: float = 0.08
    """A foot within this height of the floor may be in contact."""
    contact_speed_mps: float = 0.35
    """... and slower than this (m/s)."""
    contact_noise_ratio: float = 3.0
    """Per axis, the speed threshold is at least this many times the clip's foot noise speed on that axis
    (:func:`foot_noise`): a still foot of a noisy estimate (PHALP's depth from the box scale) still counts as
    slow; a clean estimate (noise far below ``contact_speed_mps``) keeps ``contact_speed_mps``."""
    stance_noise_ratio: float | None = 3.5
    """Adaptive, world frames: per axis, the speed threshold is at least this many times what a planted foot of the
    smoothed motion still moves (:func:`smplik.contacts.stance_noise`: the smoothing keeps part of a noisy
    estimate's noise, most of it where the noise drifts over frames), and the lift release (``release_m``) grows
    ``release_noise_gain`` times as much as the threshold; a clean estimate keeps ``contact_speed_mps`` and
    ``release_m``. None: ``contact_speed_mps`` alone (the earlier rule). Chosen on the known-truth validation split
    (``benchmarks/animation_truth.py --split validation``)."""
    stance_share: float = 0.25
    """The share of the low foot-frames taken as planted to measure that noise
    (:func:`smplik.contacts.stance_noise`)."""
    release_noise_gain: float = 4.0
    """How much more than the speed threshold the lift release grows on a noisy estimate (above)."""
    slide_speed_mps: float = 0.7
    """With a threshold raised by ``stance_noise_ratio``: a contact run whose foot moves faster than this on average
    (first to last frame, m/s; :func:`drop_sliding_runs`) is no contact (a sliding or walking foot, where noise
    averages out over a planted one)."""
    contact_release_ratio: float = 1.5
    """Hysteresis: a contact run, once found, extends over neighbouring low frames up to this many times the
    speed threshold (a landing or stance whose slowest frames alone are too short)."""
    contact_min_frames: int = 3
    """Contact runs shorter than this are dropped."""
    blend_frames: int = 3
    """Frames over which a lock is blended in before and out after a contact run (at least; more where the
    offset to blend is larger than ``blend_max_m`` per frame)."""
    blend_max_m: float = 0.02
    """Most a lock's blend moves the foot from one frame to the next (m): no snap at a release."""
    hold_frames: int = 1
    """Adaptive: frames before and after each contact run that the lock also holds (0 or 1; :func:`lock_plan`):
    the blends happen outside the run, so the foot is still (zero speed by central differences) on every frame
    reported as contact; frames where a lock hands over to the next one are reported free."""
    hold_within_m: float | None = None
    """Adaptive: a frame next to a run is held only if its foot is within this of the lock (m; None: always)."""
    blend_ease: bool = True
    """Adaptive: blends in and out follow a half cosine rather than a straight ramp (:func:`lock_plan`)."""
    root_from_locks: bool = True
    """Adaptive: move the root by the locked feet's smoothed offsets before the leg IK
    (:func:`root_shift_from_locks`): the root's noise goes into the root, not the legs."""
    lock_turn_prior: float | None = 0.001
    """Adaptive: after the root's shift, the whole body turns about the locked feet (:func:`turn_from_locks`) by as
    much as their remaining offsets ask where both feet are locked (one foot forward, the other back: a yaw of the
    estimate's root, which a shift cannot undo and the leg IK would turn into bent legs), against this weight
    (m^2 per rad^2) of the turn's square. None: no turn (the earlier rule)."""
    bridge_frames: int = 15
    """Adaptive, noisy estimates: two runs of one foot at most this many frames apart, whose foot stays low between
    them and whose locks are within the lift release, are one run (:func:`bridge_short_gaps`: a planted foot of an
    estimate whose noise drifts over frames wanders out of the speed threshold for up to half a second)."""
    lock_knee_turn_deg: float | None = 3.0
    """Adaptive: most a foot lock's leg IK changes a knee's angle (degrees; :func:`lock_feet`): a nearly straight
    stance leg would bend its knee by degrees (moving it centimetres) for a few millimetres of reach; beyond this,
    the foot stays short of its lock along the leg. None: no limit (the earlier rule)."""
    root_lock_smoothness: float = 1.0
    """Smoothness (frames^2 weight of the squared acceleration) of that root shift, at 30 frames/s (scaled by
    ``(fps / 30) ** 4`` at other rates, so it spans the same time)."""
    release_m: float = 0.03
    """A lock releases when the (smoothed) foot leaves its locked point by this much (m): a lift or a step."""
    ground_moves: bool = False
    """The ground may move through the frame (a camera-space clip: a camera panning with the person, a
    treadmill): contacts are feet slow *relative to the ground* and locks move with it (:func:`ground_of`). Off
    for world-frame motion, whose ground is still; ``scene animate`` turns it on for camera-space clips."""
    ground_smoothness: float | None = 10.0
    """With ``ground_moves``: the ground's velocity may vary over time (a pan that speeds up and slows down),
    smoothed with this weight of its squared second difference at 30 frames/s (:func:`smplik.contacts.ground_track`;
    scaled by ``(fps / 30) ** 4``), where that explains far more low feet than a constant velocity. None: always
    constant."""
    repair_glitches: bool = True
    """Detect single-frame glitches (:func:`glitch_frames`) and replace them by interpolation before smoothing."""
    glitch_sigmas: float = 5.5
    """A glitch moves some joint from the midpoint of its neighbouring frames by more than this many times the
    clip's own robust spread of that offset (per joint and axis: :func:`glitch_frames`) ..."""
    glitch_min_m: float = 0.03
    """... and at least this far (m; only matters on a nearly noise-free clip) ..."""
    glitch_ratio: float = 2.0
    """... and more than this many times the distance between those neighbours (fast real motion does not)."""
    glitch_rotation_sigmas: float = 11.0
    """A glitch may also turn a limb's joint (one with at least two joints below it) away from the midpoint of its
    neighbouring frames' rotations by more than this many times the clip's own robust spread of that rotation's
    spike (:func:`glitch_frames`): a limb's own turn stands out of one joint's rotation noise where its joints'
    positions, which add up the noise and the motion of every joint above them, do not (a fast dance's arms)."""

    def __post_init__(self) -> None:
        if self.smoothing not in ("adaptive", "sequence", "one_euro", "savgol", "none"):
            raise CleanError(f"smoothing must be 'adaptive', 'sequence', 'one_euro', 'savgol' or 'none', got "
                             f"{self.smoothing!r}.")
        for name in ("smoothness", "lock_weight", "min_cutoff_hz", "d_cutoff_hz", "contact_height_m",
                     "contact_speed_mps", "contact_noise_ratio", "glitch_min_m", "glitch_ratio", "glitch_sigmas",
                     "glitch_rotation_sigmas",
                     "noise_gain", "blend_max_m", "release_m", "root_lock_smoothness", "release_noise_gain",
                     "slide_speed_mps"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise CleanError(f"{name} must be a positive number, got {value}.")
        if self.ground_smoothness is not None and not (np.isfinite(self.ground_smoothness)
                                                       and self.ground_smoothness > 0):
            raise CleanError(f"ground_smoothness must be a positive number or None, got {self.ground_smoothness}.")
        if self.pose_budget_mm is not None and not (np.isfinite(self.pose_budget_mm) and self.pose_budget_mm > 0):
            raise CleanError(f"pose_budget_mm must be a positive number or None, got {self.pose_budget_mm}.")
        if not (np.isfinite(self.clean_noise_share) and self.clean_noise_share >= 0):
            raise CleanError(f"clean_noise_share must be >= 0, got {self.clean_noise_share}.")
        if not (np.isfinite(self.min_smoothness) and self.min_smoothness >= 0):
            raise CleanError(f"min_smoothness must be >= 0, got {self.min_smoothness}.")
        if not (np.isfinite(self.motion_trust) and self.motion_trust >= 0):
            raise CleanError(f"motion_trust must be >= 0, got {self.motion_trust}.")
        if not (np.isfinite(self.beta) and self.beta >= 0):
            raise CleanError(f"beta must be >= 0, got {self.beta}.")
        if self.savgol_window < 3 or self.savgol_window % 2 == 0 or self.savgol_order >= self.savgol_window:
            raise CleanError(f"savgol_window must be odd, >= 3 and above savgol_order; got {self.savgol_window} "
                             f"and order {self.savgol_order}.")
        if not (np.isfinite(self.contact_release_ratio) and self.contact_release_ratio >= 1):
            raise CleanError(f"contact_release_ratio must be >= 1, got {self.contact_release_ratio}.")
        if self.contact_min_frames < 1 or self.blend_frames < 0:
            raise CleanError("contact_min_frames must be >= 1 and blend_frames >= 0.")
        if self.stance_noise_ratio is not None and not (np.isfinite(self.stance_noise_ratio)
                                                        and self.stance_noise_ratio > 0):
            raise CleanError(f"stance_noise_ratio must be a positive number or None, got {self.stance_noise_ratio}.")
        if not 0 < self.stance_share <= 1:
            raise CleanError(f"stance_share must be in (0, 1], got {self.stance_share}.")
        if self.lock_turn_prior is not None and not (np.isfinite(self.lock_turn_prior) and self.lock_turn_prior > 0):
            raise CleanError(f"lock_turn_prior must be a positive number or None, got {self.lock_turn_prior}.")
        if self.lock_knee_turn_deg is not None and not (np.isfinite(self.lock_knee_turn_deg)
                                                        and self.lock_knee_turn_deg > 0):
            raise CleanError(f"lock_knee_turn_deg must be a positive number or None, got {self.lock_knee_turn_deg}.")
        if self.bridge_frames < 0:
            raise CleanError(f"bridge_frames must be >= 0, got {self.bridge_frames}.")
        if self.hold_frames not in (0, 1):
            raise CleanError(f"hold_frames must be 0 or 1, got {self.hold_frames}.")


# ----------------------------------------------------------------------------- filters


def _alpha(cutoff_hz: np.ndarray | float, fps: float) -> np.ndarray:
    tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff_hz))
    return 1.0 / (1.0 + tau * fps)


def one_euro(x: np.ndarray, fps: float, *, min_cutoff_hz: float = 1.0, beta: float = 0.3, d_cutoff_hz: float = 1.0,
             zero_phase: bool = True) -> np.ndarray:
    """One-Euro filter along time. x (T, ..., C) -> (T, ..., C); one cutoff per ``(...)`` group, from the norm
    of the group's speed over its C components (units per second)."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[0] < 2:
        return x.copy()

    def forward(sig: np.ndarray) -> np.ndarray:
        out = np.empty_like(sig)
        out[0] = sig[0]
        dx_hat = np.zeros_like(sig[0])
        a_d = _alpha(d_cutoff_hz, fps)
        for t in range(1, sig.shape[0]):
            dx = (sig[t] - out[t - 1]) * fps
            dx_hat = a_d * dx + (1.0 - a_d) * dx_hat
            cutoff = min_cutoff_hz + beta * np.linalg.norm(dx_hat, axis=-1, keepdims=True)
            a = _alpha(cutoff, fps)
            out[t] = a * sig[t] + (1.0 - a) * out[t - 1]
        return out

    y = forward(x)
    return forward(y[::-1])[::-1].copy() if zero_phase else y


def continuous_quaternions(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, J, 3, 3) -> unit quaternions (T, J, 4), scalar first, with q[t] . q[t-1] >= 0."""
    T = R.shape[0]
    q = matrix_to_quat_wxyz(R)
    for t in range(1, T):
        flip = (q[t] * q[t - 1]).sum(-1) < 0
        q[t, flip] *= -1.0
    return q


def smooth_motion(R_parent_joint: np.ndarray, transl: np.ndarray, fps: float, cfg: CleanConfig
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Smooth local rotations (T, 24, 3, 3) and root translation (T, 3) over time (see the module docstring)."""
    if cfg.smoothing == "none" or R_parent_joint.shape[0] < 3:
        return R_parent_joint.copy(), transl.copy()
    if cfg.smoothing == "adaptive":
        return denoise_motion(R_parent_joint, transl, cfg)
    q = continuous_quaternions(R_parent_joint)
    if cfg.smoothing == "savgol":
        window = min(cfg.savgol_window, q.shape[0] - (1 - q.shape[0] % 2))
        if window <= cfg.savgol_order:
            return R_parent_joint.copy(), transl.copy()
        q_s = savgol_smooth(q, window, cfg.savgol_order)
        t_s = savgol_smooth(transl, window, cfg.savgol_order)
    else:
        kw = {"min_cutoff_hz": cfg.min_cutoff_hz, "beta": cfg.beta, "d_cutoff_hz": cfg.d_cutoff_hz}
        q_s = one_euro(q, fps, **kw)
        t_s = one_euro(transl, fps, **kw)
    return quat_wxyz_to_matrix(q_s / np.linalg.norm(q_s, axis=-1, keepdims=True)), t_s


CORRELATION_SLOPE = 100.0
"""Gain per unit of excess lag-1 residual autocorrelation (:func:`correlation_gain`; chosen on validation clips,
``benchmarks/animation_truth.py --split validation``)."""
CORRELATION_GAIN_MAX = 20.0
"""Most :func:`correlation_gain` multiplies the smoothness by."""


ROOT_CORRELATION_SHARE = 0.4
"""The root's correlation gain is at least this share of the rotations' (:func:`denoise_motion`): its three
channels measure their correlation poorly (a median of three residuals, a run's bounce in them; on the test run
09_06 with AR(1) noise their lag-1 autocorrelation looks white while the rotations' gives a gain of 20), and an
estimator's slow drift moves the body and the root alike. Left at 1, the root's residual drift made the foot locks
of a run's 3-5 frame stances shift the root frame by frame (acceleration error 16.7 against Savitzky-Golay's 15.2;
13.0 with it). 0.3-0.5 change no check on either split but that one; 0.7 made the walk 02_01 (AR(1)) skate."""


def correlation_gain(lag1: np.ndarray) -> float:
    """Smoothness multiplier for a group of channels whose fit residuals have lag-1 autocorrelations ``lag1``
    (C,) (:class:`workflows.animation.denoise.ChannelNoise`): 1 for independent noise; noise correlated over frames (an
    estimator's slow drift) looks partly like motion to the unbiased risk, which then smooths too little: up to
    :data:`CORRELATION_GAIN_MAX` times more, from the median excess over :data:`.denoise.WHITE_LAG1`."""
    from workflows.animation.denoise import WHITE_LAG1

    excess = float(np.median(lag1)) - WHITE_LAG1 - 0.03
    return float(np.clip(1.0 + CORRELATION_SLOPE * excess, 1.0, CORRELATION_GAIN_MAX))


CORRELATED_GAIN = 9.0
"""A rotation correlation gain (:func:`correlation_gain`) at least this marks noise correlated over frames for
:data:`WHITE_NOISE_TRUST` (frame-independent noise gave 1-8 on the known-truth clips, the short runs' the highest;
AR(1) noise 10.3-19.6)."""
WHITE_NOISE_TRUST = 1.25
"""Multiplier of ``motion_trust`` where the noise is not correlated over frames (:data:`CORRELATED_GAIN`): there the
estimate's fast motion is the body's, not a drift, and a short run's lift-off kept sharper lets the foot lock hold
its stance to the end (run 09_06 with glitches: skating on the truth's contacts 8.9 -> 5.3 mm/frame against a
bound of 7.7). Under correlated noise a stronger trust hands the drift back (2 made the AR(1) walks skate)."""


def denoise_motion(R_parent_joint: np.ndarray, transl: np.ndarray, cfg: CleanConfig
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The adaptive smoothing (``smoothing="adaptive"``, the default) of local rotations (T, 24, 3, 3) and the root
    (T, 3): every channel (each joint's sign-continuous quaternion components, the root's x, y and z) gets its
    own noise level (:func:`.denoise.estimate_noise`) and from it its own smoothness (the unbiased-risk
    choice, :func:`.denoise.sure_smoothness`, times ``noise_gain`` and :func:`correlation_gain` of the
    rotation channels or of the root's, the latter at least :data:`ROOT_CORRELATION_SHARE` of the former; on a
    clean estimate, ``clean_noise_share``, at least ``min_smoothness``),
    then a Whittaker smoothing; with ``motion_trust`` (times :data:`WHITE_NOISE_TRUST` where the noise is not
    correlated over frames), on a noisy clip, a second pass weighs the estimate more where the first bent fast motion
    (:func:`workflows.animation.denoise.motion_weights`).

    Returns: local rotations (T, 24, 3, 3) (renormalised quaternions) and the root (T, 3)."""
    from workflows.animation.denoise import estimate_noise, motion_weights, noise_share, sure_smoothness, whittaker

    T, J = R_parent_joint.shape[:2]
    if T < 3:
        return R_parent_joint.copy(), np.array(transl, dtype=np.float64)
    q = continuous_quaternions(R_parent_joint).reshape(T, 4 * J)
    y = np.concatenate([q, np.asarray(transl, dtype=np.float64)], axis=1)  # (T, 4J + 3)
    noise = estimate_noise(y)
    lam = cfg.noise_gain * sure_smoothness(y, noise.sigma)
    rotation_gain = correlation_gain(noise.lag1[:4 * J])
    lam[:4 * J] *= rotation_gain
    lam[4 * J:] *= max(correlation_gain(noise.lag1[4 * J:]), ROOT_CORRELATION_SHARE * rotation_gain)
    share = noise_share(y, noise.sigma)  # constant channels (NaN) say nothing about the estimate's noise
    clean = bool(np.isfinite(share).any() and np.nanmedian(share) < cfg.clean_noise_share)
    if clean:
        lam = np.maximum(lam, cfg.min_smoothness)
    z = whittaker(y, np.ones_like(y), lam)
    if cfg.motion_trust > 0 and not clean:
        trust = cfg.motion_trust * (WHITE_NOISE_TRUST if rotation_gain < CORRELATED_GAIN else 1.0)
        z = whittaker(y, motion_weights(y, z, noise.sigma, trust), lam)
    q_s = z[:, :4 * J].reshape(T, J, 4)
    return quat_wxyz_to_matrix(q_s / np.linalg.norm(q_s, axis=-1, keepdims=True)), z[:, 4 * J:]


# ----------------------------------------------------------------------------- plausibility


ROOT_GLITCH_SMOOTHNESS = 10.0
"""Smoothness of the robust root path that :func:`glitch_frames` measures the root's jumps from."""


def _root_outliers(root: np.ndarray) -> np.ndarray:
    """The root's offsets (T, 3) from a robust smoothing of its path (T, 3): Whittaker smoothing, then again with
    the frames beyond 3 robust spreads nearly ignored (a jump does not pull the path towards itself)."""
    from workflows.animation.denoise import whittaker

    weights = np.ones_like(root)
    for _ in range(2):
        offset = root - whittaker(root, weights, np.full(3, ROOT_GLITCH_SMOOTHNESS))
        spread = 1.4826 * np.median(np.abs(offset - np.median(offset, axis=0)), axis=0)
        weights = np.where(np.abs(offset) > 3.0 * np.maximum(spread, 1e-6), 1e-3, 1.0)
    return offset


def glitch_frames(p_world: np.ndarray, min_m: float = 0.03, ratio: float = 2.0, sigmas: float = 5.5,
                  R_parent_joint: np.ndarray | None = None, rotation_sigmas: float = 11.0) -> np.ndarray:
    """Single-frame glitches (T,) bool of joint positions p_world (T, J, 3) (a pose that jumps away and comes back,
    as when a tracker briefly swaps limbs or misjudges the depth).

    The root (joint 0) is tested on its world path, every other joint relative to the root (so the root's noise, a
    monocular depth's above all, does not hide a limb's glitch). Per joint and axis, the spike of a frame is its
    fourth difference ``-(p[t-2] - 4 p[t-1] + 6 p[t] - 4 p[t+1] + p[t+2]) / 4`` (1.5 times a single-frame jump;
    smooth motion, even with a strong acceleration, gives almost none; the root, whose path is smooth, uses its
    offset from the midpoint of its neighbouring frames, which measures its noise better), in units of the clip's
    own robust spread of it (1.4826 times its median absolute deviation over the clip, per joint and axis: the depth
    is noisier than the image axes). A frame is a glitch where some joint's scaled spike is above ``sigmas``, is the
    largest of its frame and the two neighbouring frames (a jump's neighbours see two thirds of it), moves the joint
    at least ``min_m`` from the midpoint of the neighbouring frames and, for joints other than the root, more than
    ``ratio`` times the distance between those neighbours (a fast limb advances more than it bends). The first and
    last two frames are never flagged.

    With the local rotations ``R_parent_joint`` (T, J, 3, 3), a frame is also a glitch where a limb's joint (one
    with at least two joints below it: hips, knees, shoulders, elbows, the spine; not the feet, hands or head,
    whose turns move little) turns away and comes back (:func:`rotation_spikes`): the fourth difference of its
    sign-continuous quaternion, scaled by its robust spread over the clip, above ``rotation_sigmas``, the largest of
    its frame and the neighbouring frames, an angle from the neighbours' mean rotation above ``ratio`` times the
    angle between them, and some joint below it moved at least twice ``min_m`` from the midpoint of its
    neighbouring frames (relative to the root: on a nearly noise-free clip, a limb's few-degree wobble is not a
    glitch). Such a test does not depend on how fast the body moves: one joint's rotation
    noise is what a limb's turn is measured against, not the summed noise and motion of its parents. With them, a
    frame is a glitch too where the left and right legs or arms are swapped (:func:`swap_frames`), and a joint
    other than the root jumps in position only where some joint above it (the root's rotation included) turns out
    of its noise (:func:`rotation_scores` above ``sigmas``): a limb cannot jump without a turn, and noise summed
    along a limb's chain, with no joint standing out, is no glitch."""
    T = p_world.shape[0]
    flags = np.zeros(T, dtype=bool)
    if T < 5:
        return flags
    p = p_world - p_world[:, :1]
    p[:, 0] = p_world[:, 0]
    spike = np.zeros_like(p)
    spike[2:-2] = -(p[:-4] - 4 * p[1:-3] + 6 * p[2:-2] - 4 * p[3:-1] + p[4:]) / 4.0
    spike[:, 0] = _root_outliers(p[:, 0])
    inner = spike[2:-2]
    spread = np.maximum(1.4826 * np.median(np.abs(inner - np.median(inner, axis=0)), axis=0), 1e-4)  # (J, 3)
    score = np.linalg.norm(spike / spread, axis=-1)  # (T, J)
    peak = np.zeros_like(score, dtype=bool)
    peak[1:-1] = (score[1:-1] >= score[:-2]) & (score[1:-1] >= score[2:])
    offset = np.zeros(p.shape[:2])
    gap = np.zeros(p.shape[:2])
    offset[1:-1] = np.linalg.norm(p[1:-1] - 0.5 * (p[2:] + p[:-2]), axis=-1)
    gap[1:-1] = np.linalg.norm(p[2:] - p[:-2], axis=-1)
    jumps = offset > ratio * gap
    jumps[:, 0] = True
    hit = (score > sigmas) & peak & (offset >= min_m) & jumps
    if R_parent_joint is not None and p.shape[1] == len(PARENTS):  # a limb's jump needs a turn above it
        turns = rotation_scores(continuous_quaternions(R_parent_joint))  # (T, J)
        for j in range(1, len(PARENTS)):
            hit[:, j] &= turns[:, sorted(_ancestors(j))].max(-1) > sigmas
    strength = np.where(hit, score, 0.0).max(-1)  # (T,)
    if R_parent_joint is not None:
        strength = np.maximum(strength, sigmas / rotation_sigmas * rotation_spikes(
            R_parent_joint, offset, min_m, ratio, rotation_sigmas))
        strength = np.where(swap_frames(R_parent_joint, offset, min_m, ratio) & (strength == 0.0), sigmas,
                            strength)
    for t in np.argsort(-strength):  # a strong jump's neighbours two frames away may pass too: keep the jump
        if strength[t] == 0.0:
            break
        if 2 <= t < T - 2 and not flags[max(0, t - 2):t + 3].any():
            flags[t] = True
    return flags


def _ancestors(j: int) -> set[int]:
    """The joints above joint j in SMPL's tree."""
    out: set[int] = set()
    while PARENTS[j] >= 0:
        j = PARENTS[j]
        out.add(j)
    return out


LIMB_JOINTS = tuple(j for j in range(1, len(PARENTS))
                    if sum(1 for k in range(len(PARENTS)) if k != j and j in _ancestors(k)) >= 2)
"""Joints with at least two joints below them (hips, knees, spine, collars, shoulders, elbows), tested by
:func:`rotation_spikes`."""


def rotation_scores(q: np.ndarray) -> np.ndarray:
    """Each joint's rotation spike (T, J) of sign-continuous quaternions q (T, J, 4) (T >= 5): the fourth difference
    of each component over its robust spread over the clip (1.4826 MAD), the norm over the components."""
    spike = np.zeros_like(q)
    spike[2:-2] = -(q[:-4] - 4 * q[1:-3] + 6 * q[2:-2] - 4 * q[3:-1] + q[4:]) / 4.0
    inner = spike[2:-2]
    spread = np.maximum(1.4826 * np.median(np.abs(inner - np.median(inner, axis=0)), axis=0), 1e-5)  # (J, 4)
    return np.linalg.norm(spike / spread, axis=-1)


def rotation_spikes(R_parent_joint: np.ndarray, offset: np.ndarray, min_m: float = 0.03, ratio: float = 2.0,
                    sigmas: float = 11.0) -> np.ndarray:
    """The strongest limb-joint rotation glitch score (T,) of local rotations R_parent_joint (T, J, 3, 3), 0 where
    none (:func:`glitch_frames`); offset (T, J): each joint's distance (m) from the midpoint of its neighbouring
    frames, relative to the root."""
    T, J = R_parent_joint.shape[:2]
    out = np.zeros(T)
    if T < 5:
        return out
    q = continuous_quaternions(R_parent_joint)  # (T, J, 4)
    score = rotation_scores(q)
    peak = np.zeros_like(score, dtype=bool)
    peak[1:-1] = (score[1:-1] >= score[:-2]) & (score[1:-1] >= score[2:])
    mid = q[:-2] + q[2:]
    mid /= np.maximum(np.linalg.norm(mid, axis=-1, keepdims=True), 1e-12)
    turn = np.zeros((T, J))
    gap = np.zeros((T, J))
    turn[1:-1] = np.abs((q[1:-1] * mid).sum(-1))  # cosines of half the angles: smaller is farther
    gap[1:-1] = np.abs((q[:-2] * q[2:]).sum(-1))
    away = 2 * np.arccos(np.clip(turn, 0.0, 1.0)) > ratio * 2 * np.arccos(np.clip(gap, 0.0, 1.0))
    for j in LIMB_JOINTS:
        below = [k for k in range(J) if k != j and j in _ancestors(k)]
        hit = (score[:, j] > sigmas) & peak[:, j] & away[:, j] & (offset[:, below].max(-1) >= 2.0 * min_m)
        out = np.maximum(out, np.where(hit, score[:, j], 0.0))
    out[:2] = 0.0
    out[-2:] = 0.0
    return out


SWAP_LIMBS = tuple(tuple((JOINT_INDEX[f"left_{j}"], JOINT_INDEX[f"right_{j}"]) for j in joints)
                   for joints in (("hip", "knee", "ankle", "foot"),
                                  ("collar", "shoulder", "elbow", "wrist", "hand")))
"""Left / right joint pairs of the legs and the arms, tested for a swap by :func:`swap_frames`."""
MIRROR_QUATERNION = np.array([1.0, 1.0, -1.0, -1.0])
"""A local rotation mirrored across SMPL's sagittal (x = 0) plane: quaternion (w, x, y, z) -> (w, x, -y, -z)."""


def swap_frames(R_parent_joint: np.ndarray, offset: np.ndarray, min_m: float = 0.03, ratio: float = 2.0
                ) -> np.ndarray:
    """Left/right limb swaps (T,) bool of local rotations R_parent_joint (T, J, 3, 3) (:func:`glitch_frames`).

    For each limb pair (:data:`SWAP_LIMBS`: the legs, the arms), a frame's *misfit* is the summed angle of the
    limbs' local rotations from the mean rotation of the neighbouring frames, once as estimated and once with the
    left and right limbs exchanged (each mirrored). A frame is a swap where the estimated misfit is more than
    ``ratio`` times the exchanged one, exceeds it by more than the clip's median misfit (the noise of a typical
    frame) and some joint of the limbs moved at least twice ``min_m`` from the midpoint of its neighbouring frames
    (offset (T, J), relative to the root). How fast the body moves does not enter: a swap fits the neighbours once
    undone, a fast real move does not. The first and last frames are never flagged."""
    T = R_parent_joint.shape[0]
    out = np.zeros(T, dtype=bool)
    if T < 5:
        return out
    q = continuous_quaternions(R_parent_joint)  # (T, J, 4)
    mid = q[:-2] + q[2:]
    mid /= np.maximum(np.linalg.norm(mid, axis=-1, keepdims=True), 1e-12)
    mirrored = q[1:-1] * MIRROR_QUATERNION

    def misfit(rows: np.ndarray, joints: list[int]) -> np.ndarray:
        cos = np.abs((rows * mid[:, joints]).sum(-1))
        return 2 * np.arccos(np.clip(cos, 0.0, 1.0)).sum(-1)  # (T - 2,)

    for pairs in SWAP_LIMBS:
        left, right = [a for a, _ in pairs], [b for _, b in pairs]
        as_is = misfit(q[1:-1, left + right], left + right)
        swapped = misfit(np.concatenate([mirrored[:, right], mirrored[:, left]], axis=1), left + right)
        gain = as_is - swapped
        hit = (as_is > ratio * swapped) & (gain > np.median(as_is)) \
            & (offset[1:-1, left + right].max(-1) >= 2.0 * min_m)
        out[1:-1] |= hit
    out[:2] = False
    out[-2:] = False
    return out


# ----------------------------------------------------------------------------- contacts


def local_to_world(R_parent_joint: np.ndarray) -> np.ndarray:
    """(..., 24, 3, 3) local -> world rotations (parents before children)."""
    G = np.empty_like(R_parent_joint)
    for j, p in enumerate(PARENTS):
        G[..., j, :, :] = R_parent_joint[..., j, :, :] if p < 0 else G[..., p, :, :] @ R_parent_joint[..., j, :, :]
    return G


def lock_feet(R_parent_joint: np.ndarray, p_world: np.ndarray, contact: np.ndarray, blend_frames: int = 3,
              ground: np.ndarray | None = None, blend_max: float | None = None, hold: int = 0, ease: bool = False,
              hold_within: float | None = None, knee_turn: float | None = None) -> np.ndarray:
    """Pin each foot joint to its lock (:func:`lock_targets`) over each contact run by two-bone leg IK.

    Args:
        R_parent_joint: (T, 24, 3, 3) local rotations; p_world: (T, 24, 3) their joint positions;
        contact: (T, 2) bool (left, right) from :func:`foot_contacts`; ground: (3,) or (T, 3) the ground's
        velocity (units per frame; default still); blend_max, hold, ease: as in :func:`lock_plan`;
        knee_turn: most the IK may change a knee's angle (rad; None: no limit). A nearly straight leg (a stance)
        reaches a few millimetres farther or nearer only by bending its knee by degrees, which moves the knee by
        centimetres: the foot then stays short of its lock along the leg (mostly vertically) instead
        (:func:`limit_knee_turn`).

    Returns: new local rotations (T, 24, 3, 3); only the hips, knees and ankles of locked legs change
    (the ankles keep their world rotations).
    """
    R_out = R_parent_joint.copy()
    G = local_to_world(R_parent_joint)
    targets, weights = lock_targets(p_world, contact, blend_frames, ground, blend_max, hold, ease, hold_within)
    for side, ((hip, knee, ankle), foot) in enumerate(zip(LEG_CHAINS, FOOT_JOINTS, strict=True)):
        rows = np.nonzero(weights[:, side] > 0)[0]
        if rows.size == 0:
            continue
        ankle_target = targets[rows, side] - (p_world[rows, foot] - p_world[rows, ankle])
        if knee_turn is not None:
            ankle_target = limit_knee_turn(p_world[rows, hip], p_world[rows, knee], p_world[rows, ankle],
                                           ankle_target, knee_turn)
        R_a, R_b = two_bone_ik(p_world[rows, hip], p_world[rows, knee], p_world[rows, ankle], ankle_target,
                               -G[rows, knee, :, 0])
        G_hip = R_a @ G[rows, hip]
        G_knee = R_a @ R_b @ G[rows, knee]
        R_out[rows, hip] = np.swapaxes(G[rows, PARENTS[hip]], -1, -2) @ G_hip
        R_out[rows, knee] = np.swapaxes(G_hip, -1, -2) @ G_knee
        R_out[rows, ankle] = np.swapaxes(G_knee, -1, -2) @ G[rows, ankle]
    return R_out


def limit_knee_turn(p_hip: np.ndarray, p_knee: np.ndarray, p_ankle: np.ndarray, target: np.ndarray,
                    max_turn: float) -> np.ndarray:
    """The ankle target (..., 3) moved along the line from the hip so that reaching it changes the knee's angle by
    at most ``max_turn`` (rad): the hip-to-target distance clamped to those the knee reaches within that turn (law
    of cosines), the direction kept. p_hip, p_knee, p_ankle, target (..., 3)."""
    upper = np.linalg.norm(p_knee - p_hip, axis=-1)
    lower = np.linalg.norm(p_ankle - p_knee, axis=-1)

    def angle(distance: np.ndarray) -> np.ndarray:  # the knee's interior angle for a hip-to-ankle distance
        return np.arccos(np.clip((upper ** 2 + lower ** 2 - distance ** 2) / (2 * upper * lower), -1.0, 1.0))

    reach = target - p_hip
    distance = np.linalg.norm(reach, axis=-1)
    now = angle(np.linalg.norm(p_ankle - p_hip, axis=-1))
    wanted = np.clip(angle(distance), now - max_turn, now + max_turn)
    allowed = np.sqrt(np.maximum(upper ** 2 + lower ** 2 - 2 * upper * lower * np.cos(wanted), 0.0))
    return p_hip + reach * (allowed / np.maximum(distance, 1e-12))[..., None]


# ----------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class MotionMetrics:
    """What :func:`motion_metrics` measures (millimetres)."""

    jitter_mm: float
    """Mean joint acceleration magnitude, mm/frame^2."""
    skating_mm: float
    """Mean speed of the foot joints during contact, mm/frame (0 without contacts)."""
    mpjpe_mm: float
    """Pose fidelity: mean per-joint position error to the reference with both pelvises at the origin (the MPJPE
    of HMR papers), mm."""
    contact_frames: int
    """Foot-frames in contact (both feet counted)."""
    trajectory_mm: float = 0.0
    """Trajectory change: mean distance between the pelvises, mm."""

    def to_dict(self) -> dict[str, float]:
        return {"jitter_mm_per_frame2": round(self.jitter_mm, 3), "skating_mm_per_frame": round(self.skating_mm, 3),
                "mpjpe_mm": round(self.mpjpe_mm, 3), "trajectory_mm": round(self.trajectory_mm, 3),
                "contact_frames": int(self.contact_frames)}


def jitter(p: np.ndarray) -> float:
    """Mean joint acceleration |p[t+1] - 2p[t] + p[t-1]| in p's units per frame^2. p (T, J, 3)."""
    if p.shape[0] < 3:
        return 0.0
    return float(np.linalg.norm(p[2:] - 2.0 * p[1:-1] + p[:-2], axis=-1).mean())


def foot_skating(p: np.ndarray, contact: np.ndarray, ground: np.ndarray | None = None) -> float:
    """Mean speed (units/frame) of the foot joints over their contact frames, relative to the ground moving at
    ``ground`` (3,) or (T, 3) units/frame (:func:`ground_drift`; default still). p (T, 24, 3), contact (T, 2)."""
    speed = joint_speed(p[:, list(FOOT_JOINTS)] - ground_drift(ground, p.shape[0])[:, None])
    return float(speed[contact].mean()) if contact.any() else 0.0


def motion_metrics(p: np.ndarray, reference: np.ndarray, contact: np.ndarray, ground: np.ndarray | None = None
                   ) -> MotionMetrics:
    """Jitter, skating (on ``contact``), pelvis-aligned MPJPE and trajectory change (pelvis distance) to
    ``reference`` of joints p (T, 24, 3) in metres."""
    aligned = (p - p[:, :1]) - (reference - reference[:, :1])
    mpjpe = float(np.linalg.norm(aligned, axis=-1).mean())
    trajectory = float(np.linalg.norm(p[:, 0] - reference[:, 0], axis=-1).mean())
    return MotionMetrics(1000 * jitter(p), 1000 * foot_skating(p, contact, ground), 1000 * mpjpe, int(contact.sum()),
                         1000 * trajectory)


# ----------------------------------------------------------------------------- sequence cleaning


HOLD_REACH = 1.0
"""Most of the leg's length (hip to ankle, straight) a frame held next to a contact run may ask of it
(:func:`lock_plan`): a target beyond the leg's reach (a toe-off or a heel strike of a run, the leg straight) would
flip the knee under the leg IK, so such a frame is blended instead."""


def _holdable(p: np.ndarray, target: np.ndarray, side: int, within: float | None) -> bool:
    """Whether the foot of joints p (24, 3) on ``side`` may be held at ``target`` (3,) one frame beyond its run:
    within ``within`` of it (None: any distance) and within the leg's reach (:data:`HOLD_REACH`)."""
    hip, knee, ankle = LEG_CHAINS[side]
    foot = FOOT_JOINTS[side]
    if within is not None and np.linalg.norm(target - p[foot]) > within:
        return False
    length = np.linalg.norm(p[knee] - p[hip]) + np.linalg.norm(p[ankle] - p[knee])
    return bool(np.linalg.norm(target - (p[foot] - p[ankle]) - p[hip]) <= HOLD_REACH * length)


def lock_targets(p_world: np.ndarray, contact: np.ndarray, blend_frames: int, ground: np.ndarray | None = None,
                 blend_max: float | None = None, hold: int = 0, ease: bool = False, hold_within: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Where each foot should be and how firmly (the lock blend weight in [0, 1]) over its contact runs: the targets
    (T, 2, 3) and weights (T, 2) of :func:`lock_plan` (same arguments)."""
    targets, weights, _ = lock_plan(p_world, contact, blend_frames, ground, blend_max, hold, ease, hold_within)
    return targets, weights


def lock_plan(p_world: np.ndarray, contact: np.ndarray, blend_frames: int, ground: np.ndarray | None = None,
              blend_max: float | None = None, hold: int = 0, ease: bool = False, hold_within: float | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each foot should be and how firmly (the lock blend weight in [0, 1]) over its contact runs, and the
    contact frames on which the lock holds the foot still.

    Args: p_world (T, 24, 3) joint positions, contact (T, 2) bool (left, right), ground (3,) or (T, 3) the
    ground's velocity (units per frame, :func:`ground_drift`; default still); blend_max: most the target may move
    relative to the foot from one frame to the next during a blend (units; None: no limit); hold: frames before and
    after each run also held at its lock (0 or 1), so that the blends happen outside the run and the foot's speed
    (central differences) is zero on every frame of it; ease: blends follow a half cosine (no kink where they meet
    the held frame or the free foot) instead of a straight ramp.

    Returns: foot targets (T, 2, 3), weights (T, 2) and ``held`` (T, 2) bool, the contact frames whose foot and
    both neighbouring frames' feet are at one lock (with ``hold`` 1: every contact frame but those a hand-over
    between two runs moves; with 0: ``contact`` itself). Inside a run (and ``hold`` frames around it), the target
    is the run's mean foot position relative to the ground (moving with the ground). Around it the lock is
    blended as an offset: before, the foot plus ``k / (n + 1)`` of the offset (lock minus foot) at the first held
    frame (k = 1..n, n frames); after, the foot plus the shrinking offset of the last held frame, so the foot
    follows its own motion and the offset changes by the same step each frame: ``n`` is ``blend_frames``, or more
    where the offset divided by ``n + 1`` would exceed ``blend_max`` (no snap at a release). The weight ramps the
    same way. Between two runs of one foot at most ``2 * blend_frames`` frames apart, the offset moves from the
    first lock's to the second's in equal steps (weight 1), over the gap (less the held frames) and as many frames
    at the runs' ends as keep a step within ``blend_max``; with ``hold``, those run frames are not ``held``.
    """
    if hold not in (0, 1):
        raise CleanError(f"hold must be 0 or 1, got {hold}.")
    T = p_world.shape[0]
    targets = p_world[:, list(FOOT_JOINTS)].copy()
    weights = np.zeros(contact.shape)
    held = contact.copy()
    drift = ground_drift(ground, T)
    for side, foot in enumerate(FOOT_JOINTS):
        for s, e in _runs(contact[:, side]):
            lock = (p_world[s:e, foot] - drift[s:e]).mean(0) + drift  # (T, 3)
            first, last = s, e - 1
            if hold and s > 0 and _holdable(p_world[s - 1], lock[s - 1], side, hold_within):
                first = s - 1
            if hold and e < T and _holdable(p_world[e], lock[e], side, hold_within):
                last = e
            inside = np.arange(first, last + 1)
            inside = inside[(weights[inside, side] < 1.0) | contact[inside, side]]  # a held frame beats a blend
            targets[inside, side] = lock[inside]
            weights[inside, side] = 1.0
            for edge, direction in ((first, -1), (last, 1)):
                offset = lock[edge] - p_world[edge, foot]
                n = blend_frames
                if blend_max is not None and blend_max > 0:  # an eased blend's steepest step is pi/2 times the mean
                    n = max(n, int(np.ceil((np.pi / 2 if ease else 1.0) * np.linalg.norm(offset) / blend_max)) - 1)
                for k in range(1, n + 1):
                    t = edge + direction * k
                    if not 0 <= t < T:
                        break
                    w = 0.5 + 0.5 * np.cos(np.pi * k / (n + 1)) if ease else 1.0 - k / (n + 1)
                    if w > weights[t, side]:  # the offset is the same in the camera's and the ground's frame
                        targets[t, side] = p_world[t, foot] + w * offset
                        weights[t, side] = w
        runs = _runs(contact[:, side])
        for (s0, e0), (s1, e1) in zip(runs[:-1], runs[1:], strict=True):
            if s1 - e0 > 2 * blend_frames:
                continue  # the blends out of one run and into the next do not meet
            # two locks close in time (a run cut by a lift or a slide, split_on_lift): move the offset from the
            # first lock's to the second's in equal steps, over the gap and as many frames at the runs' ends as keep
            # each step within blend_max (otherwise the foot jumps from one lock to the next: a snap)
            a, b = e0 - 1 + hold, s1 - hold
            if a >= b:  # one free frame between the runs: both locks would hold it
                a, b = e0 - 1, s1
            lock0 = (p_world[s0:e0, foot] - drift[s0:e0]).mean(0)  # the locks, relative to the ground
            lock1 = (p_world[s1:e1, foot] - drift[s1:e1]).mean(0)
            while True:
                start = lock0 + drift[a] - p_world[a, foot]  # the held offsets (target minus foot)
                stop = lock1 + drift[b] - p_world[b, foot]
                change = stop - start
                if blend_max is None or np.linalg.norm(change) <= blend_max * (b - a) or (a == s0 and b == e1 - 1):
                    break
                a, b = max(s0, a - 1), min(e1 - 1, b + 1)
            for t in range(a + 1, b):
                targets[t, side] = p_world[t, foot] + start + change * (t - a) / (b - a)
                weights[t, side] = 1.0
            if hold:  # the hand-over's ends are held at the locks; the frames that move and their ends are not still
                targets[a, side], targets[b, side] = lock0 + drift[a], lock1 + drift[b]
                weights[a, side] = weights[b, side] = 1.0
                held[a:b + 1, side] = False
    return targets, weights, held


def root_shift_from_locks(p_world: np.ndarray, contact: np.ndarray, blend_frames: int, ground: np.ndarray | None,
                          blend_max: float | None, smoothness: float, hold: int = 0, ease: bool = False,
                          hold_within: float | None = None) -> np.ndarray:
    """How far to move the root (T, 3) so that the locked feet's offsets go into the root, not the legs.

    A still foot of a noisy estimate moves with the root's noise (a monocular depth's above all); pinning it by leg
    IK alone bends the legs by that noise. The lock-weighted mean offset (lock target minus foot,
    :func:`lock_targets`) of the feet in contact, per frame, is smoothed over time (Whittaker, ``smoothness``; data
    weight the summed lock weights, a small pull to zero where no foot is locked): that is the root's noise the
    locks see, and the root takes it. p_world (T, 24, 3), contact (T, 2)."""
    from workflows.animation.denoise import whittaker

    targets, weights = lock_targets(p_world, contact, blend_frames, ground, blend_max, hold, ease, hold_within)
    offset = targets - p_world[:, list(FOOT_JOINTS)]  # (T, 2, 3)
    total = weights.sum(1)  # (T,)
    mean = (weights[..., None] * offset).sum(1) / np.maximum(total, 1e-9)[:, None]
    w = np.repeat((total + 1e-3)[:, None], 3, axis=1)
    return whittaker(mean, w, np.full(3, smoothness))


def turn_from_locks(R_parent_joint: np.ndarray, transl: np.ndarray, p_world: np.ndarray, contact: np.ndarray,
                    blend_frames: int, ground: np.ndarray | None, blend_max: float | None, prior: float,
                    smoothness: float, hold: int = 0, ease: bool = False, hold_within: float | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Turn the whole body about its locked feet so that their remaining offsets go into the root's rotation, not
    the legs: local rotations (T, 24, 3, 3) and transl (T, 3) with the root turned.

    A root shift (:func:`root_shift_from_locks`) moves both feet alike; where both are locked and their offsets
    (lock target minus foot, :func:`lock_targets`) differ (an estimate's yaw or tilt of the whole body: one foot
    forward, the other back), the leg IK would bend the legs by the difference, which a similarity-aligned error
    (PA-MPJPE) counts and a turn of the whole body does not. Per frame, the small turn ``w`` (rotation vector, rad)
    about the lock-weighted centre ``c`` of the feet minimises ``sum_i weight_i |w x (f_i - c) - offset_i|^2 +
    prior |w|^2`` (a closed form: the feet's moment of inertia about ``c`` plus ``prior``); it is smoothed over
    time (Whittaker, ``smoothness``; data weight the smaller lock weight of the two feet, so single support
    interpolates) and applied to the root's rotation, the root moved so that ``c`` stays. p_world (T, 24, 3) the
    joints of ``R_parent_joint`` and ``transl``; contact (T, 2); the rest as :func:`lock_plan`."""
    from workflows.animation.denoise import whittaker

    targets, weights = lock_targets(p_world, contact, blend_frames, ground, blend_max, hold, ease, hold_within)
    feet = p_world[:, list(FOOT_JOINTS)]  # (T, 2, 3)
    offset = targets - feet
    total = weights.sum(1)
    centre = (weights[..., None] * feet).sum(1) / np.maximum(total, 1e-9)[:, None]  # (T, 3)
    arm = feet - centre[:, None]  # (T, 2, 3)
    inertia = (weights * (arm ** 2).sum(-1))[..., None, None] * np.eye(3) \
        - weights[..., None, None] * arm[..., :, None] * arm[..., None, :]
    turn = np.linalg.solve(inertia.sum(1) + prior * np.eye(3),
                           (weights[..., None] * np.cross(arm, offset)).sum(1)[..., None])[..., 0]  # (T, 3)
    both = np.repeat((weights.min(1) + 1e-3)[:, None], 3, axis=1)
    turn = Rotation.from_rotvec(whittaker(turn, both, np.full(3, smoothness))).as_matrix()  # (T, 3, 3)
    R_out = R_parent_joint.copy()
    R_out[:, 0] = turn @ R_parent_joint[:, 0]
    pelvis = p_world[:, 0]
    return R_out, transl + np.einsum("tij,tj->ti", turn, pelvis - centre) + centre - pelvis


def split_on_lift(feet: np.ndarray, contact: np.ndarray, release: float, min_frames: int = 1,
                  both_ways: bool = False) -> np.ndarray:
    """Contacts (T, 2) with every run cut where its foot leaves its lock: a foot (T, 2, 3) positions (ground frame,
    smoothed) more than ``release`` from the mean of its run so far (a lift or a step of that size) ends the run
    there (that frame is left free), and a new run starts at the next frame; runs shorter than ``min_frames`` are
    dropped. ``both_ways``: also cut backwards in time (a foot that still settles into its stance, the last
    ``release`` of a landing, is not locked either; found on 4D-Humans walks).
    """
    if both_ways:
        forward = split_on_lift(feet, contact, release, min_frames)
        return forward & split_on_lift(feet[::-1], forward[::-1], release, min_frames)[::-1]
    out = np.zeros_like(contact)
    for side in range(contact.shape[1]):
        for s, e in _runs(contact[:, side]):
            start = s
            while start < e:
                total = feet[start, side].copy()
                stop = start + 1
                while stop < e and np.linalg.norm(feet[stop, side] - total / (stop - start)) <= release:
                    total += feet[stop, side]
                    stop += 1
                if stop - start >= min_frames:
                    out[start:stop, side] = True
                start = stop + 1  # the frame that left the lock is free: the next run is a run of its own
    return out


def bridge_short_gaps(feet: np.ndarray, contact: np.ndarray, max_gap: int, max_move: float,
                      low: np.ndarray | None = None) -> np.ndarray:
    """Contacts (T, 2) with each gap of at most ``max_gap`` frames between two runs of one foot filled where the two
    runs' mean positions are within ``max_move`` (units) of each other and (with ``low`` (T, 2) bool) the foot stays
    low throughout the gap: the foot never left (a noisy estimate's planted foot wobbles out of the speed threshold
    for a few frames); a step or a stride lifts it or moves it further.
    feet (T, 2, 3) positions (ground frame, smoothed), contact (T, 2) bool."""
    out = contact.copy()
    for side in range(2):
        runs = _runs(contact[:, side])
        for (s0, e0), (s1, e1) in zip(runs[:-1], runs[1:], strict=True):
            if s1 - e0 > max_gap or (low is not None and not low[e0:s1, side].all()):
                continue
            if np.linalg.norm(feet[s1:e1, side].mean(0) - feet[s0:e0, side].mean(0)) <= max_move:
                out[e0:s1, side] = True
    return out


def drop_sliding_runs(feet: np.ndarray, contact: np.ndarray, max_speed: float) -> np.ndarray:
    """Contacts (T, 2) without the runs whose foot moves on average faster than ``max_speed`` (units per frame):
    the displacement from the run's first frame to its last over its length. Noise makes a planted foot's
    frame-to-frame speed large but averages out over the run; a sliding or walking foot keeps its velocity.
    feet (T, 2, 3) positions (ground frame, smoothed), contact (T, 2) bool."""
    out = contact.copy()
    for side in range(2):
        for s, e in _runs(contact[:, side]):
            if e - s >= 2 and np.linalg.norm(feet[e - 1, side] - feet[s, side]) > max_speed * (e - 1 - s):
                out[s:e, side] = False
    return out


def trim_sliding_runs(feet: np.ndarray, contact: np.ndarray, max_speed: float, min_frames: int = 3) -> np.ndarray:
    """Contacts (T, 2) with each run that moves on average faster than ``max_speed`` (units per frame, as
    :func:`drop_sliding_runs`) trimmed, one end frame at a time (the one farther from the run's median position),
    until what is left does not (a stance whose detected run also holds the foot's landing or lift-off: a fast
    run's contacts last 3-5 frames at 30 frames/s, the low frames around them move a metre a second); a run
    shorter than ``min_frames`` by then is dropped. feet (T, 2, 3) positions (ground frame, smoothed), contact
    (T, 2) bool."""
    out = contact.copy()
    for side in range(contact.shape[1]):
        for s, e in _runs(contact[:, side]):
            a, b = s, e
            while b - a >= min_frames and np.linalg.norm(feet[b - 1, side] - feet[a, side]) > max_speed * (b - 1 - a):
                median = np.median(feet[a:b, side], axis=0)
                if np.linalg.norm(feet[a, side] - median) > np.linalg.norm(feet[b - 1, side] - median):
                    a += 1
                else:
                    b -= 1
            out[s:e, side] = False
            if b - a >= min_frames:
                out[a:b, side] = True
    return out


BUDGET_MARGIN = 0.85
"""Share of ``pose_budget_mm`` the smoothed paths may use; the body fit and the foot locks use the rest."""


def budgeted_smoothness(p_raw: np.ndarray, cfg: CleanConfig, scale: float = 1.0) -> float:
    """The sequence smoothness for joints p_raw (T, 24, 3) (SMPL space): ``cfg.smoothness``, halved until the
    smoothed paths (:func:`smplik.sequence.smooth_trajectories`) move the pose, pelvis-aligned MPJPE times
    ``scale``, at most :data:`BUDGET_MARGIN` times ``cfg.pose_budget_mm``; 0 (no smoothing) when even
    1/1000 of it does not fit."""
    from smplik.sequence import smooth_trajectories

    if cfg.pose_budget_mm is None or p_raw.shape[0] < 3:
        return cfg.smoothness
    limit = BUDGET_MARGIN * cfg.pose_budget_mm / 1000.0
    rel_raw = p_raw - p_raw[:, :1]
    ones = np.ones(p_raw.shape[:2])
    smoothness = cfg.smoothness
    while smoothness >= cfg.smoothness / 1000.0:
        z = smooth_trajectories(p_raw, ones, smoothness)
        if scale * np.linalg.norm(z - z[:, :1] - rel_raw, axis=-1).mean() <= limit:
            return smoothness
        smoothness /= 2.0
    return 0.0


def sequence_clean(R_parent_joint: np.ndarray, transl: np.ndarray, J_rest: np.ndarray, fps: float, cfg: CleanConfig,
                   scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clean a motion by a sequence solve (:func:`smplik.sequence.solve_sequence`) on its own joints.

    The estimate's joints are the data of every joint's path (weight 1); foot contacts are detected on the
    smoothed paths (:func:`foot_contacts`), and each contact run's locked foot position (:func:`lock_targets`)
    joins the data with weight ``lock_weight`` times its blend weight; the smoothed paths (``smoothness``)
    are then fitted frame by frame, the prior centred on the estimate's local rotations. Foot locking and
    smoothing are one solve, so a lock cannot re-introduce jitter. The locks move the legs too: while the result
    moves the pose (pelvis-aligned MPJPE) more than ``pose_budget_mm``, the smoothness is halved and the solve
    repeated (down to none; locks that alone exceed the budget are kept).

    Args: R_parent_joint (T, 24, 3, 3) local rotations, transl (T, 3), J_rest (24, 3) (SMPL space); the
    contact thresholds are in character space (``scale`` times SMPL space).

    Returns: local rotations (T, 24, 3, 3), transl (T, 3), contacts (T, 2) bool.
    """
    import torch

    from smplik.kinematics import forward_kinematics
    from smplik.sequence import SequenceConfig, smooth_trajectories, solve_sequence

    T = R_parent_joint.shape[0]
    R = torch.as_tensor(R_parent_joint, dtype=torch.float64)
    J = torch.as_tensor(J_rest, dtype=torch.float64)
    p_raw = forward_kinematics(R, J, torch.as_tensor(transl, dtype=torch.float64))[1].numpy()
    weights = np.ones(p_raw.shape[:2])
    targets = p_raw.copy()
    contacts = np.zeros((T, 2), dtype=bool)
    smoothness = budgeted_smoothness(p_raw, cfg, scale)
    if cfg.foot_lock and T >= 3:
        smooth = smooth_trajectories(p_raw, weights, cfg.smoothness)  # contacts are found on the smooth paths
        noise = foot_noise(p_raw, smooth, fps) * scale
        ground = ground_of(smooth, fps, cfg, scale, noise)
        contacts = foot_contacts(smooth * scale, fps, cfg, ground * scale, noise)
        drift = ground_drift(ground, T)[:, None]
        contacts = split_on_lift((smooth[:, list(FOOT_JOINTS)] - drift) * scale, contacts, cfg.release_m,
                                 cfg.contact_min_frames)
        feet, lock = lock_targets(smooth, contacts, cfg.blend_frames, ground, cfg.blend_max_m / scale)
        w_lock = cfg.lock_weight * lock
        foot_idx = list(FOOT_JOINTS)
        targets[:, foot_idx] = (p_raw[:, foot_idx] + w_lock[..., None] * feet) / (1.0 + w_lock[..., None])
        weights[:, foot_idx] += w_lock
    rel_raw = p_raw - p_raw[:, :1]
    while True:  # the locks move the pose too: smooth less until smoothing and locks fit the budget together
        R_s, t_s = solve_sequence(R, torch.as_tensor(transl, dtype=torch.float64), J, None,
                                  SequenceConfig(smoothness=smoothness), joint_targets=targets,
                                  joint_weights=weights)
        R_out, t_out = R_s.numpy(), t_s.numpy()
        if contacts.any():  # the fitted feet are near their locks; two-bone IK puts them on it exactly
            p_s = forward_kinematics(R_s, J, t_s)[1].numpy()
            R_out = lock_feet(R_out, p_s, contacts, cfg.blend_frames, ground, cfg.blend_max_m / scale)
        if cfg.pose_budget_mm is None or smoothness == 0.0 or not contacts.any():
            break
        p_out = forward_kinematics(torch.as_tensor(R_out), J, t_s)[1].numpy()
        change_mm = 1000.0 * scale * np.linalg.norm(p_out - p_out[:, :1] - rel_raw, axis=-1).mean()
        if change_mm <= cfg.pose_budget_mm:
            break
        smoothness = smoothness / 2.0 if smoothness / 2.0 >= cfg.smoothness / 1000.0 else 0.0
    return R_out, t_out, contacts
