"""Streaming full-body tracking: :class:`Tracker` turns one frame of tracker signals into one SMPL pose.

Per input frame (constant cost: the GRU carries the history):

1. features of the frame (:func:`smplik.tracking.features.tracker_features` on the previous and current frame);
2. one GRU step of the condition encoder;
3. deterministic mode (``samples == 1``): the decoder at the prior's mean -> pose, returned at once;
   sampling mode (``samples == N``): the decoder for N fixed noise vectors in one batch (vector 0 is the
   prior's mean), each pose scored by :func:`anomaly_scores`; the frame waits in a look-ahead buffer of
   ``lookahead`` (tau) frames. Sample selection (Milef et al. 2023, section 3.2, with our score instead of their
   autoencoder): when the current sample's score at the newest frame ``t + tau`` is an outlier among the N
   (above twice the trimmed spread ``median - min`` and above :data:`ANOMALY_THRESHOLD`), the best sample is
   chosen there, and the noise vector of the output is interpolated linearly from the current to the best one
   over ``blend`` frames starting at the output frame ``t``, so the switch completes before the flagged
   frame is shown;
4. foot locking on the output frame: a foot whose predicted contact probability is above the threshold is
   pinned where the contact began by the animation pipeline's two-bone leg IK
   (:func:`smplik.limb_ik.two_bone_ik`, the ankle keeping its world rotation) and blended back to the
   network's foot over ``release_frames`` after the contact ends.

Outputs are :class:`TrackedPose` (numpy). :func:`track_sequence` runs a whole recording through the same
streaming path and returns one pose per input frame; knowing the whole recording, it replaces the causal locks of
step 4 by an offline pass (:func:`offline_foot_lock`, :attr:`TrackerRuntimeConfig.offline_lock`): contact segments
from the predicted probabilities (hysteresis, minimum length), each foot pinned at the median of the network's foot
over its segment, blended in and out by smoothstep.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, PARENTS, Gender
from smplik.rotations import matrix_to_axis_angle_acos_np, quaternion_to_matrix_np
from smplik.tracking.config import TrackerRuntimeConfig
from smplik.tracking.data import body_vector
from smplik.tracking.fast import NumpyTrackingNet, decode_np, fk_np, yaw_matrix
from smplik.tracking.fit import EffectorFit
from smplik.tracking.io import TrackerSignals
from smplik.tracking.model_io import TrackingModel, load_model
from smplik.tracking.network import TrackingNet

_IDENTITY_Q = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (8, 1))
RATE_WINDOW = 30
""":meth:`Tracker.step` with timestamps judges the stream's rate over its last this many frame intervals."""
RATE_TOLERANCE = 0.1
"""... refusing a mean rate more than this share away from the model's once :data:`RATE_MIN_INTERVALS` intervals
have arrived (the sampling jitter of a real headset log averages out) ..."""
RATE_MIN_INTERVALS = 5
RATE_FAR = 0.4
"""... and, from the second frame on, a rate this far away (a 30 or 90 frames/s stream into a 60 frames/s model)."""
ANOMALY_THRESHOLD = 0.02
"""A pose whose :func:`anomaly_scores` exceeds this is implausible (counted in the benchmark's anomaly rate)."""
CROSS_PAIRS = tuple((JOINT_INDEX[f"left_{j}"], JOINT_INDEX[f"right_{j}"]) for j in ("knee", "ankle", "foot"))
CROSS_MIN_M = 0.06
"""Left and right knees, ankles or feet closer than this intersect."""
BELOW_FLOOR_M = 0.02
"""A joint more than this below the floor penetrates it."""
RANGE_MARGIN_RAD = 0.2
"""Tolerance around the training set's rotation range (retargeted BVH leaves some joints, e.g. the hands, at
zero rotation: a few hundredths of a radian there are no anomaly)."""
_COLLARS = {JOINT_INDEX[f"{s}_shoulder"]: JOINT_INDEX[f"{s}_collar"] for s in ("left", "right")}
_COLLARS = np.array([_COLLARS.get(j, 0) for j in range(24)])
_PARENTS = np.array(PARENTS, dtype=np.int64)
_CROSS_PAIRS = np.array(CROSS_PAIRS, dtype=np.int64)


def _kernels():  # noqa: ANN202 (the module, or None without numba)
    """:mod:`smplik.tracking.kernels` when numba is installed, else None (the numpy path)."""
    try:
        from smplik.tracking import kernels
    except ImportError:
        return None
    return kernels


_LEGS = ((JOINT_INDEX["left_hip"], JOINT_INDEX["left_knee"], JOINT_INDEX["left_ankle"], JOINT_INDEX["left_foot"]),
         (JOINT_INDEX["right_hip"], JOINT_INDEX["right_knee"], JOINT_INDEX["right_ankle"], JOINT_INDEX["right_foot"]))


def anomaly_scores(R_local: np.ndarray, p_world: np.ndarray, pose_lo: np.ndarray, pose_hi: np.ndarray,
                   floor_y: float = 0.0) -> np.ndarray:
    """Implausibility (N,) of poses: metres of joints below the floor (past :data:`BELOW_FLOOR_M`) + metres of leg
    self-intersection (knees, ankles or feet closer than :data:`CROSS_MIN_M`) + 0.1 x radians of local
    axis-angle components outside the training range [pose_lo, pose_hi] (24, 3) widened by
    :data:`RANGE_MARGIN_RAD`. R_local (N, 24, 3, 3), p_world (N, 24, 3). 0 for a plausible pose."""
    below = np.maximum(floor_y - BELOW_FLOOR_M - p_world[..., 1], 0.0).sum(-1)
    cross = sum(np.maximum(CROSS_MIN_M - np.linalg.norm(p_world[..., a, :] - p_world[..., b, :], axis=-1), 0.0)
                for a, b in CROSS_PAIRS)
    aa = matrix_to_axis_angle_acos_np(R_local[..., 1:, :, :])
    out = (np.maximum(pose_lo[1:] - RANGE_MARGIN_RAD - aa, 0.0)
           + np.maximum(aa - pose_hi[1:] - RANGE_MARGIN_RAD, 0.0)).sum((-1, -2))
    return below + cross + 0.1 * out


def frame_features(p: np.ndarray, R: np.ndarray, p_prev: np.ndarray, yaw_prev: float, has_rot: np.ndarray,
                   fps: float) -> tuple[np.ndarray, float, np.ndarray]:
    """One frame of :func:`smplik.tracking.features.tracker_features` in numpy: p (K, 3), R (K, 3, 3), the
    previous frame's positions and heading -> ``(x (K * 13 + 2,), yaw, origin (3,))``."""
    yaw = float(np.arctan2(R[0, 0, 2], R[0, 2, 2]))
    Y_inv = yaw_matrix(-yaw)
    origin = np.array([p[0, 0], 0.0, p[0, 2]], dtype=np.float32)
    pos = (p - origin) @ Y_inv.T
    vel = ((p - p_prev) * fps) @ Y_inv.T
    R_h = Y_inv @ R
    mask = has_rot.astype(np.float32)
    rot = np.concatenate([R_h[:, :, 0], R_h[:, :, 1]], axis=1) * mask[:, None]
    per = np.concatenate([pos, vel * 0.1, rot, mask[:, None]], axis=1)
    d = yaw - yaw_prev
    return np.concatenate([per.ravel(), [np.sin(d), np.cos(d)]]).astype(np.float32), yaw, origin


@dataclass(frozen=True)
class TrackedPose:
    """One output frame: R_local (24, 3, 3) local rotations (root in world), transl (3,) smplx translation,
    contacts (2,) bool (left, right), the sample shown, its anomaly score, and the predicted contact
    probabilities (2,) (left, right)."""

    frame: int
    R_local: np.ndarray
    transl: np.ndarray
    contacts: np.ndarray
    sample: int
    anomaly: float
    contact_prob: np.ndarray | None = None


class _FootLock:
    """Causal foot locking on a stream of poses (module docstring, step 4). A foot locks where its predicted
    contact starts while the network's foot is low (within ``max_height_m`` of the floor) and slow (below
    ``max_speed_mps``, the animation pipeline's contact speed), and stays locked while the contact lasts, the
    network's foot moves below 1.5 times that speed and stays within ``max_drift_m`` of the lock (a contact label
    the pose disagrees with is dropped rather than stretching the leg)."""

    def __init__(self, threshold: float, release_frames: int, floor_y: float = 0.0, fps: float = 60.0,
                 max_height_m: float = 0.12, max_speed_mps: float = 0.35, max_drift_m: float = 0.08,
                 fast: bool = True) -> None:
        kernels = _kernels() if fast else None
        if kernels is None:
            from smplik.limb_ik import two_bone_ik
        else:
            two_bone_ik = kernels.two_bone_ik
        self.two_bone_ik = two_bone_ik
        self.threshold, self.release_frames, self.fps = threshold, release_frames, fps
        self.floor_y, self.max_height_m, self.max_drift_m = floor_y, max_height_m, max_drift_m
        self.max_speed_mps = max_speed_mps
        self.prev_feet: np.ndarray | None = None
        self.lock: list[np.ndarray | None] = [None, None]
        self.release = [0, 0]
        self.release_from = [np.zeros(3), np.zeros(3)]

    def apply(self, R_local: np.ndarray, R_world: np.ndarray, p: np.ndarray, prob: np.ndarray) -> np.ndarray:
        """Locked local rotations (24, 3, 3) of one pose (world rotations R_world, joints p), float64."""
        rows, targets = [], []
        feet = p[[leg[3] for leg in _LEGS]]
        speed = (np.zeros(2) if self.prev_feet is None
                 else np.linalg.norm(feet - self.prev_feet, axis=-1) * self.fps)
        self.prev_feet = feet.copy()
        for side, (_, _, _, foot) in enumerate(_LEGS):
            lock = self.lock[side]
            contact = prob[side] > self.threshold
            if (contact and lock is None and p[foot, 1] - self.floor_y < self.max_height_m
                    and speed[side] < self.max_speed_mps):
                lock = self.lock[side] = p[foot].copy()
            if (contact and lock is not None and np.linalg.norm(p[foot] - lock) < self.max_drift_m
                    and speed[side] < 1.5 * self.max_speed_mps):
                rows.append(side)
                targets.append(lock)
                continue
            if self.lock[side] is not None:
                self.release[side], self.release_from[side] = self.release_frames, self.lock[side]
                self.lock[side] = None
            if self.release[side] > 0:
                w = self.release[side] / (self.release_frames + 1)
                self.release[side] -= 1
                rows.append(side)
                targets.append(w * self.release_from[side] + (1 - w) * p[foot])
        if not rows:
            return R_local
        legs = np.array([_LEGS[s] for s in rows])  # (n, 4)
        hip, knee, ankle, foot = legs.T
        target = np.stack(targets) - (p[foot] - p[ankle])
        R_a, R_b = self.two_bone_ik(p[hip], p[knee], p[ankle], target, -R_world[knee, :, 0])
        out = R_local.copy()
        G_hip = R_a @ R_world[hip]
        G_knee = R_a @ R_b @ R_world[knee]
        parent_hip = R_world[0]  # both hips hang from the pelvis
        out[hip] = parent_hip.T @ G_hip
        out[knee] = np.swapaxes(G_hip, -1, -2) @ G_knee
        out[ankle] = np.swapaxes(G_knee, -1, -2) @ R_world[ankle]
        return out


class Tracker:
    """Streaming inference (module docstring). Create with :meth:`load`; feed :meth:`step` once per frame at the
    model's rate; call :meth:`flush` at the end of a recording for the frames still in the look-ahead buffer."""

    def __init__(self, model: TrackingModel, J_rest: Tensor, body: Tensor, config: TrackerRuntimeConfig) -> None:
        if not isinstance(model.net, TrackingNet):
            raise ValueError("Tracker needs a cvae tracking model.")
        if config.samples < 1:
            raise ValueError(f"samples must be at least 1, got {config.samples}.")
        if config.lock_centre not in ("median", "min"):
            raise ValueError(f"lock_centre must be 'median' or 'min', got {config.lock_centre!r}.")
        if not config.contact_off <= config.contact_on:
            raise ValueError(f"contact_off ({config.contact_off}) must not exceed contact_on ({config.contact_on}).")
        if config.min_contact_frames < 1 or config.lock_blend_frames < 0 or config.lock_smooth_frames < 0:
            raise ValueError("min_contact_frames must be at least 1, lock_blend_frames and lock_smooth_frames at "
                             "least 0.")
        self.stream_lock = True  # the causal locks of step 4 (track_sequence turns them off for its offline pass)
        self.model, self.net, self.cfg = model, model.net, config
        self.trackers = model.cfg.trackers
        self.fps = model.cfg.fps
        self.J_rest = J_rest.numpy().astype(np.float32)  # (24, 3)
        self.body = body.numpy().astype(np.float32)  # (13,)
        self.fast = NumpyTrackingNet(model.net)
        self.pose_lo, self.pose_hi = model.pose_lo.numpy(), model.pose_hi.numpy()
        self.kernels = _kernels() if config.fast else None
        self.J_rest64 = self.J_rest.astype(np.float64)
        self.x = np.zeros(self.fast.x_mean.shape[0], dtype=np.float32)  # the frame's features (kernel path)
        rng = np.random.default_rng(config.seed)
        self.eps = rng.standard_normal((config.samples, model.cfg.latent)).astype(np.float32)
        self.eps[0] = 0.0
        self.reset()

    @classmethod
    def load(cls, path: str | Path | None = None, *, betas: np.ndarray | None = None,
             gender: Gender | str = Gender.NEUTRAL, config: TrackerRuntimeConfig | None = None,
             model_dir: str | Path | None = None) -> Tracker:
        """The shipped model (or ``path``) for a body ``betas`` (10,) (default zeros) and ``gender``."""
        from smplik.body_model import BodyModelSet
        from smplik.validation import check_betas

        model = load_model(path)
        b = torch.zeros(10) if betas is None else torch.as_tensor(check_betas(betas), dtype=torch.float32).reshape(10)
        gi = torch.tensor(Gender.parse(gender).index)
        J_rest = BodyModelSet.load(model_dir).rest_joints(b, gi).float()
        return cls(model, J_rest, body_vector(b, gi), config or TrackerRuntimeConfig())

    def reset(self, has_rotation: np.ndarray | None = None) -> None:
        """Start a new recording (zero GRU state, empty buffers). has_rotation (K,) bool: which trackers carry
        rotations (default all; the first, the heading reference, must)."""
        K = len(self.trackers)
        has = np.ones(K, bool) if has_rotation is None else np.asarray(has_rotation, bool)
        if has.shape != (K,):
            raise ValueError(f"has_rotation has shape {has.shape}; expected ({K},).")
        if not has[0]:
            raise ValueError(f"the {self.trackers[0]} tracker needs a rotation (the heading reference).")
        self.has_rot = has
        self.h = np.zeros(self.fast.H, dtype=np.float32)
        self.prev: tuple[np.ndarray, float] | None = None
        self.frame_in = 0
        self.frame_out = 0
        self.times: deque[float] = deque(maxlen=RATE_WINDOW)  # the last timestamps given to step
        self.buffer: deque[tuple[np.ndarray, float, np.ndarray, tuple[np.ndarray, np.ndarray]]] = deque()
        self.current = 0
        self.transition: tuple[int, int, int] | None = None  # (from, to, first output frame)
        c = self.cfg
        self.lock = _FootLock(c.contact_threshold, c.release_frames, c.floor_y, self.fps, max_height_m=c.lock_height_m,
                              max_speed_mps=c.lock_speed_mps, max_drift_m=c.lock_drift_m,
                              fast=self.kernels is not None)
        self.effector_fit = (EffectorFit(self.trackers, has, self.J_rest64, c.fit, fast=self.kernels is not None)
                             if c.effector_fit else None)

    @property
    def latency(self) -> int:
        """Frames between an input and its output pose."""
        return self.cfg.lookahead if self.cfg.samples > 1 else 0

    def step(self, positions: np.ndarray, rotations: np.ndarray | None = None, *,
             time_s: float | None = None) -> TrackedPose | None:
        """One frame: positions (K, 3) metres, rotations (K, 4) unit quaternions (w, x, y, z) (rows of trackers
        without rotation are ignored), in the model's tracker order (:attr:`trackers`). Returns the output pose of
        frame ``frame_in - latency``, or None while the look-ahead buffer fills.

        The model runs at :attr:`fps` frames per second (its velocities are per frame at that rate). ``time_s``:
        the frame's timestamp (seconds, any origin); given, the stream's rate is checked before the frame is
        used, and a stream at another rate (its mean over the last :data:`RATE_WINDOW` intervals more than
        :data:`RATE_TOLERANCE` away, or :data:`RATE_FAR` from the second frame on) or timestamps that do not
        increase raise ValueError (one line): resample such a stream to the model's rate first
        (:class:`workflows.tracking.live.TickResampler` does, as ``smplik track --live --fps`` uses it)."""
        if time_s is not None:
            self._check_time(time_s)
        K = len(self.trackers)
        if self.kernels is not None:
            p = np.asarray(positions, dtype=np.float64).reshape(K, 3)
            q = _IDENTITY_Q[:K] if rotations is None else np.asarray(rotations, dtype=np.float64).reshape(K, 4)
            R = np.empty((K, 3, 3))
            p_prev, yaw_prev = self.prev if self.prev is not None else (p, 0.0)
            yaw, ox, oz = self.kernels.frame_features(p, q, p_prev, yaw_prev, self.has_rot, self.fps,
                                                      self.prev is None, self.x, R)
            x, origin = self.x, np.array([ox, 0.0, oz])
        else:
            p = np.asarray(positions, dtype=np.float32).reshape(K, 3)
            if rotations is None:
                R = np.broadcast_to(np.eye(3, dtype=np.float32), (K, 3, 3))
            else:
                R = quaternion_to_matrix_np(np.asarray(rotations, dtype=np.float32).reshape(K, 4))
            p_prev, yaw_prev = self.prev if self.prev is not None else (p, None)
            x, yaw, origin = frame_features(p, R, p_prev, yaw_prev if yaw_prev is not None else 0.0, self.has_rot,
                                            self.fps)
            if yaw_prev is None:  # the first frame: no heading change (as the batch features)
                x[-2:] = (0.0, 1.0)
        self.prev = (p, yaw)
        self.h = self.fast.condition_step(x, self.body, self.h)
        self.frame_in += 1
        if self.cfg.samples == 1:
            return self._emit(self.h, yaw, origin, self.eps[0], (p, R))
        self._select(self.h, yaw, origin)
        self.buffer.append((self.h, yaw, origin, (p, R)))
        if len(self.buffer) > self.cfg.lookahead:
            return self._pop()
        return None

    def _check_time(self, time_s: float) -> None:
        """Refuse a timestamp that does not increase or a stream whose rate is not the model's (:meth:`step`)."""
        t = float(time_s)
        times = self.times
        if not np.isfinite(t):
            raise ValueError(f"Tracker.step: time_s must be a finite number of seconds, got {time_s!r}.")
        if times and t <= times[-1]:
            raise ValueError(f"Tracker.step: timestamps must increase; frame {self.frame_in} is at {t:g} s, the "
                             f"previous one at {times[-1]:g} s.")
        if times:
            n = min(len(times), RATE_WINDOW)
            rate = n / (t - times[-n])
            off = abs(rate / self.fps - 1.0)
            if off > RATE_FAR or (n >= RATE_MIN_INTERVALS and off > RATE_TOLERANCE):
                raise ValueError(f"Tracker.step: the stream runs at {rate:.1f} frames/s (mean of its last {n} "
                                 f"intervals); this model runs at {self.fps:g}: resample it to {self.fps:g} frames/s "
                                 "first (workflows.tracking.live.TickResampler).")
        times.append(t)

    def flush(self) -> list[TrackedPose]:
        """The poses still in the look-ahead buffer (call once at the end of a recording)."""
        out = []
        while self.buffer:
            out.append(self._pop())
        return out

    def _score(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        if self.kernels is not None:
            return self.kernels.anomaly_scores(R, p, self.pose_lo, self.pose_hi, self.cfg.floor_y, BELOW_FLOOR_M,
                                               CROSS_MIN_M, _CROSS_PAIRS, RANGE_MARGIN_RAD)
        return anomaly_scores(R, p, self.pose_lo, self.pose_hi, self.cfg.floor_y)

    def _decode(self, out: np.ndarray, yaw: float, origin: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Network outputs (N, OUT_DIM) -> ``(R_local (N, 24, 3, 3), transl (N, 3), contact_prob (N, 2),
        R_world (N, 24, 3, 3), p_world (N, 24, 3))``."""
        if self.kernels is None:
            R, transl, prob = decode_np(out, yaw, origin, self.J_rest)
            G, p = fk_np(R, self.J_rest, transl)
            return R, transl, prob, G, p
        N = out.shape[0]
        R, G = np.empty((N, 24, 3, 3)), np.empty((N, 24, 3, 3))
        transl, prob, p = np.empty((N, 3)), np.empty((N, 2)), np.empty((N, 24, 3))
        self.kernels.decode_fk(out, yaw, origin, self.J_rest64, _PARENTS, R, transl, prob, G, p)
        return R, transl, prob, G, p

    def _fit_trackers(self, R: np.ndarray, transl: np.ndarray, p_trk: np.ndarray, R_trk: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Meet the trackers (:attr:`TrackerRuntimeConfig.tracker_fit`). R (1, 24, 3, 3), transl (1, 3)."""
        from smplik.limb_ik import two_bone_ik

        R, transl = R.copy(), transl.copy()
        idx = {name: k for k, name in enumerate(self.trackers)}
        if "pelvis" in idx:
            k = idx["pelvis"]
            if self.has_rot[k]:
                R[0, 0] = R_trk[k]
            transl[0] = p_trk[k] - self.J_rest[0]
        arms = [(side, idx[f"{side}_wrist"]) for side in ("left", "right") if f"{side}_wrist" in idx]
        if arms:
            G, p = fk_np(R, self.J_rest, transl)
            G, p = G[0], p[0]
            chains = np.array([[JOINT_INDEX[f"{s}_shoulder"], JOINT_INDEX[f"{s}_elbow"], JOINT_INDEX[f"{s}_wrist"]]
                               for s, _ in arms])
            a, b, c = chains.T
            target = p_trk[[k for _, k in arms]]
            # a straight arm bends about the elbow's local y axis (used only when the arm is straight)
            R_a, R_b = two_bone_ik(p[a], p[b], p[c], target, G[b][:, :, 1])
            G_a = R_a @ G[a]
            G_b = R_a @ R_b @ G[b]
            R[0, a] = np.swapaxes(G[_COLLARS[a]], -1, -2) @ G_a
            R[0, b] = np.swapaxes(G_a, -1, -2) @ G_b
            for (_, k), elbow_world, wrist in zip(arms, G_b, c, strict=True):
                if self.has_rot[k]:  # else the wrist keeps its local rotation and follows the forearm
                    R[0, wrist] = elbow_world.T @ R_trk[k]
        if "head" in idx and self.has_rot[idx["head"]]:
            G, _ = fk_np(R, self.J_rest, transl)
            R[0, JOINT_INDEX["head"]] = G[0, JOINT_INDEX["neck"]].T @ R_trk[idx["head"]]
        return R, transl

    def _select(self, h: np.ndarray, yaw: float, origin: np.ndarray) -> None:
        """Score the N samples at the newest frame; start a transition when the current one is an outlier."""
        R, _, _, _, p = self._decode(self.fast.sample(h, self.eps, self.body), yaw, origin)
        s = self._score(R, p)
        if self.transition is not None:
            return
        r = float(np.median(s) - s.min())
        cur = float(s[self.current])
        if cur > ANOMALY_THRESHOLD and cur > 2.0 * r:
            best = int(s.argmin())
            if best != self.current:
                self.transition = (self.current, best, self.frame_out)

    def _pop(self) -> TrackedPose:
        h, yaw, origin, signals = self.buffer.popleft()
        eps = self.eps[self.current]
        if self.transition is not None:
            a, b, first = self.transition
            w = min(1.0, (self.frame_out - first + 1) / self.cfg.blend)
            eps = (1 - w) * self.eps[a] + w * self.eps[b]
            if w >= 1.0:
                self.current, self.transition = b, None
        return self._emit(h, yaw, origin, eps, signals)

    def _emit(self, h: np.ndarray, yaw: float, origin: np.ndarray, eps: np.ndarray,
              signals: tuple[np.ndarray, np.ndarray]) -> TrackedPose:
        R, transl, prob, R_w, p = self._decode(self.fast.sample(h, eps[None], self.body), yaw, origin)
        if self.cfg.tracker_fit:
            R, transl = self._fit_trackers(R.astype(np.float32), transl.astype(np.float32), *signals)
            R_w, p = fk_np(R, self.J_rest, transl)
        if self.effector_fit is not None:
            R, transl, R_w, p = (a[None] for a in self.effector_fit.apply(R[0], transl[0], *signals))
        score = float(self._score(R, p)[0])
        R_np, prob_np = R[0].astype(np.float64), prob[0]
        locking = self.cfg.foot_lock and self.stream_lock
        if locking:
            R_np = self.lock.apply(R_np, R_w[0].astype(np.float64), p[0].astype(np.float64), prob_np)
        contacts = (np.array([lk is not None for lk in self.lock.lock]) if locking
                    else prob_np > self.cfg.contact_threshold)
        pose = TrackedPose(self.frame_out, R_np, transl[0].astype(np.float64), contacts,
                           self.current if self.transition is None else self.transition[1], score,
                           np.asarray(prob_np, dtype=np.float64))
        self.frame_out += 1
        return pose


@dataclass(frozen=True)
class TrackResult:
    """A whole recording's poses, one per input frame: R_local (T, 24, 3, 3), transl (T, 3), contacts (T, 2),
    sample (T,) int, anomaly (T,)."""

    R_local: np.ndarray
    transl: np.ndarray
    contacts: np.ndarray
    sample: np.ndarray
    anomaly: np.ndarray


def resample_signals(signals: TrackerSignals, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (S, K, 3) and quaternions (S, K, 4) at ``fps`` (linear / normalised-linear interpolation), and the
    index (T,) of the resampled frame nearest each input frame."""
    from smplik.limits import TRACK_FRAMES, check_resampled_frames

    T = signals.num_frames
    same = abs(signals.fps - fps) < 1e-6
    # what will be made, before it is made: the resampled frames (span x rate), and the input frames mapped back
    S = T if same else check_resampled_frames((T - 1) / signals.fps, fps, signals.source or "tracker recording")
    TRACK_FRAMES.check(max(S, T), f"{signals.source or 'tracker recording'} ({T} frames at {signals.fps:g} "
                       f"frames/s; {S} at the model's {fps:g} frames/s)")
    if same:
        return signals.positions, signals.rotations, np.arange(T)
    t_in = np.arange(T) / signals.fps
    t_out = np.arange(S) / fps
    q = signals.rotations.copy()
    for i in range(1, T):
        q[i] *= np.where((q[i] * q[i - 1]).sum(-1) < 0, -1.0, 1.0)[:, None]
    P = np.stack([[np.interp(t_out, t_in, signals.positions[:, k, c]) for c in range(3)]
                  for k in range(len(signals.names))]).transpose(2, 0, 1)
    Q = np.stack([[np.interp(t_out, t_in, q[:, k, c]) for c in range(4)]
                  for k in range(len(signals.names))]).transpose(2, 0, 1)
    Q /= np.linalg.norm(Q, axis=-1, keepdims=True)
    nearest = np.clip(np.rint(t_in * fps).astype(int), 0, len(t_out) - 1)
    return P, Q, nearest


def contact_segments(prob: np.ndarray, on: float, off: float, min_frames: int) -> list[tuple[int, int]]:
    """Contact segments ``[start, end)`` of one foot's contact probabilities prob (T,): a segment starts where the
    probability exceeds ``on`` and ends at the first frame below ``off`` (hysteresis); segments shorter than
    ``min_frames`` are dropped."""
    segments, start = [], None
    for t, q in enumerate(np.asarray(prob, dtype=np.float64)):
        if start is None and q > on:
            start = t
        elif start is not None and q < off:
            segments.append((start, t))
            start = None
    if start is not None:
        segments.append((start, len(prob)))
    return [(a, b) for a, b in segments if b - a >= min_frames]


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def lock_weights(segments: list[tuple[int, int]], T: int, blend: int) -> np.ndarray:
    """Weights (S, T) of S segments ``[start, end)``: 1 inside, smoothstep ramps over ``blend`` frames before
    and after (0 at the frame ``blend + 1`` away), 0 elsewhere."""
    W = np.zeros((len(segments), T))
    ramp = _smoothstep(1.0 - np.arange(1, blend + 1) / (blend + 1))  # (blend,) from near 1 down to near 0
    for k, (a, b) in enumerate(segments):
        W[k, a:b] = 1.0
        before = np.arange(a - 1, a - blend - 1, -1)
        after = np.arange(b, b + blend)
        W[k, before[before >= 0]] = ramp[before >= 0]
        W[k, after[after < T]] = ramp[after < T]
    return W


def heel_rise(foot: np.ndarray, ankle_offset: np.ndarray, hip: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """The least rotation (n, 3, 3) of the foot about its foot joint (toe pivot) that brings the ankle within
    ``reach`` (n,) of the hip: foot targets (n, 3), ankle offsets ankle - foot (n, 3), hips (n, 3). Identity where
    the ankle is already within reach; the ankle turns as far toward the hip as it can where it cannot reach."""
    d = hip - foot
    D = np.linalg.norm(d, axis=-1)
    r = np.linalg.norm(ankle_offset, axis=-1)
    u, a = d / np.maximum(D, 1e-9)[:, None], ankle_offset / np.maximum(r, 1e-9)[:, None]
    # |foot + v' - hip| = reach  <=>  angle(v', u) = psi;  v rotates toward u only when it is farther than psi
    psi = np.arccos(np.clip((D ** 2 + r ** 2 - reach ** 2) / np.maximum(2.0 * D * r, 1e-9), -1.0, 1.0))
    phi_u = np.arccos(np.clip((a * u).sum(-1), -1.0, 1.0))
    axis = np.cross(a, u)
    n = np.linalg.norm(axis, axis=-1)
    angle = np.where(n > 1e-9, np.maximum(phi_u - psi, 0.0), 0.0)
    from scipy.spatial.transform import Rotation

    rotvec = axis / np.maximum(n, 1e-9)[:, None] * angle[:, None]
    return Rotation.from_rotvec(rotvec).as_matrix().reshape(-1, 3, 3)


def offline_foot_lock(R_local: np.ndarray, transl: np.ndarray, prob: np.ndarray, J_rest: np.ndarray,
                      cfg: TrackerRuntimeConfig) -> tuple[np.ndarray, np.ndarray]:
    """Foot locks over a whole recording. R_local (T, 24, 3, 3), transl (T, 3), contact probabilities prob (T, 2)
    (left, right), rest joints J_rest (24, 3) -> ``(R_local (T, 24, 3, 3), locked (T, 2) bool)``.

    Per foot: contact segments (:func:`contact_segments`: above ``cfg.contact_on`` to below ``cfg.contact_off``,
    at least ``cfg.min_contact_frames`` long); a segment over which the network's foot strays horizontally farther
    than ``cfg.lock_spread_m`` from its median is dropped (the pose disagrees with the contact). Each segment's
    lock is the median of the network's foot joint over the segment (its height the median or, with
    ``cfg.lock_centre == "min"``, the low point); the foot's target is the lock inside the segment, blended from
    and back to the network's foot by smoothstep over ``cfg.lock_blend_frames`` frames on each side
    (:func:`lock_weights`; overlapping ramps of two segments share the weight). The legs reach the targets by
    two-bone IK (:func:`smplik.limb_ik.two_bone_ik`, hip and knee; the ankle keeps its world rotation); where the
    ankle would then be farther from the hip than ``cfg.lock_reach`` of the leg's length, the foot first pivots
    about its foot joint (:func:`heel_rise`, the heel lifting as at toe-off) so the knee stays off full extension.
    With ``cfg.lock_smooth_frames`` > 0 the legs' corrections (rotation vectors of hip, knee and ankle) are
    smoothed in time by a Gaussian of that sigma (the IK follows the network's hip jitter near full extension:
    acceleration), and with ``cfg.lock_repin`` the feet are pinned again on the segments' own frames. The rest of
    the body is untouched."""
    from smplik.tracking.fast import fk_np

    R_local = np.asarray(R_local, dtype=np.float64)
    J_rest, transl = np.asarray(J_rest, dtype=np.float64), np.asarray(transl, dtype=np.float64)
    T = R_local.shape[0]
    _, p = fk_np(R_local, J_rest, transl)
    locked = np.zeros((T, 2), dtype=bool)
    frames, sides, targets, inside = [], [], [], []
    for side, leg in enumerate(_LEGS):
        segments = contact_segments(prob[:, side], cfg.contact_on, cfg.contact_off, cfg.min_contact_frames)
        if not segments:
            continue
        foot = p[:, leg[3]]
        centres = [np.median(foot[a:b], axis=0) for a, b in segments]
        kept = [k for k, ((a, b), c) in enumerate(zip(segments, centres, strict=True))
                if np.linalg.norm((foot[a:b] - c)[:, [0, 2]], axis=-1).max() <= cfg.lock_spread_m]
        if not kept:
            continue
        segments = [segments[k] for k in kept]
        locks = np.stack([centres[k] for k in kept])
        for k, (a, b) in enumerate(segments):
            if cfg.lock_centre == "min":
                locks[k, 1] = foot[a:b, 1].min()
            locked[a:b, side] = True
        W = lock_weights(segments, T, cfg.lock_blend_frames)
        total = W.sum(0)
        active = np.flatnonzero(total > 0)
        mix = (W[:, active].T @ locks) / total[active, None]
        w = np.minimum(total[active], 1.0)[:, None]
        frames.append(active)
        sides.append(np.full(active.size, side))
        targets.append(foot[active] + w * (mix - foot[active]))
        inside.append(locked[active, side])
    if not frames:
        return R_local.copy(), locked
    t, side, target = np.concatenate(frames), np.concatenate(sides), np.concatenate(targets)
    out = _pin_feet(R_local, J_rest, transl, t, side, target, cfg.lock_reach)
    if cfg.lock_smooth_frames > 0:  # low-pass the legs' corrections (rotation vectors) over time
        from scipy.ndimage import gaussian_filter1d
        from scipy.spatial.transform import Rotation

        js = np.unique(np.array(_LEGS)[side][:, :3])
        delta = out[:, js] @ np.swapaxes(R_local[:, js], -1, -2)  # (T, J, 3, 3)
        rv = Rotation.from_matrix(delta.reshape(-1, 3, 3)).as_rotvec().reshape(T, js.size, 3)
        rv = gaussian_filter1d(rv, cfg.lock_smooth_frames, axis=0, mode="nearest")
        out[:, js] = Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(T, js.size, 3, 3) @ R_local[:, js]
        if cfg.lock_repin:  # the smoothed legs pinned again on the contact frames themselves
            keep = np.concatenate(inside)
            out = _pin_feet(out, J_rest, transl, t[keep], side[keep], target[keep], cfg.lock_reach)
    return out, locked


def _pin_feet(R_local: np.ndarray, J_rest: np.ndarray, transl: np.ndarray, t: np.ndarray, side: np.ndarray,
              foot_target: np.ndarray, reach: float) -> np.ndarray:
    """R_local (T, 24, 3, 3) with the legs of rows (frame t (n,), side (n,)) turned by two-bone IK so that their
    foot joints reach foot_target (n, 3) (the ankle keeps its world rotation, after a :func:`heel_rise` where the
    ankle would be farther than ``reach`` x the leg's length from the hip)."""
    from smplik.limb_ik import two_bone_ik
    from smplik.tracking.fast import fk_np

    R_world, p = fk_np(R_local, J_rest, transl)
    out = R_local.copy()
    hip, knee, ankle, foot = np.array(_LEGS)[side].T
    offset = p[t, ankle] - p[t, foot]
    G_ankle = R_world[t, ankle]
    if reach < 1.0:
        length = (np.linalg.norm(p[t, knee] - p[t, hip], axis=-1) + np.linalg.norm(p[t, ankle] - p[t, knee], axis=-1))
        R_heel = heel_rise(foot_target, offset, p[t, hip], reach * length)
        offset, G_ankle = (R_heel @ offset[..., None])[..., 0], R_heel @ G_ankle
    R_a, R_b = two_bone_ik(p[t, hip], p[t, knee], p[t, ankle], foot_target + offset, -R_world[t, knee, :, 0])
    G_hip = R_a @ R_world[t, hip]
    G_knee = R_a @ R_b @ R_world[t, knee]
    out[t, hip] = np.swapaxes(R_world[t, 0], -1, -2) @ G_hip  # both hips hang from the pelvis
    out[t, knee] = np.swapaxes(G_hip, -1, -2) @ G_knee
    out[t, ankle] = np.swapaxes(G_knee, -1, -2) @ G_ankle
    return out


def track_sequence(tracker: Tracker, signals: TrackerSignals) -> TrackResult:
    """Run a recording through :meth:`Tracker.step` (after :meth:`Tracker.reset`); one pose per input frame
    (recordings at another rate are resampled to the model's and mapped back to the nearest frame). With
    ``foot_lock`` and ``offline_lock`` (the default) the feet are locked by :func:`offline_foot_lock` over the
    whole recording instead of causally; ``contacts`` are then the locked frames."""
    sig = signals.select(tracker.trackers)
    tracker.reset(sig.has_rotation)
    offline = tracker.cfg.foot_lock and tracker.cfg.offline_lock
    P, Q, nearest = resample_signals(sig, tracker.fps)
    poses: list[TrackedPose] = []
    tracker.stream_lock = not offline
    try:
        for t in range(P.shape[0]):
            pose = tracker.step(P[t], Q[t])
            if pose is not None:
                poses.append(pose)
        poses.extend(tracker.flush())
    finally:
        tracker.stream_lock = True
    assert len(poses) == P.shape[0]
    R, transl = np.stack([p.R_local for p in poses]), np.stack([p.transl for p in poses])
    contacts = np.stack([p.contacts for p in poses])
    if offline:
        R, contacts = offline_foot_lock(R, transl, np.stack([p.contact_prob for p in poses]), tracker.J_rest64,
                                        tracker.cfg)
    return TrackResult(R[nearest], transl[nearest], contacts[nearest], np.array([p.sample for p in poses])[nearest],
                       np.array([p.anomaly for p in poses])[nearest])
