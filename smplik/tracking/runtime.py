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
   (:func:`workflows.motion_clean.two_bone_ik`, the ankle keeping its world rotation) and blended back to the
   network's foot over ``release_frames`` after the contact ends.

Outputs are :class:`TrackedPose` (numpy). :func:`track_sequence` runs a whole recording through the same
streaming path and returns one pose per input frame.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, Gender
from smplik.kinematics import forward_kinematics
from smplik.rotations import matrix_to_axis_angle, quaternion_to_matrix
from smplik.tracking.config import TrackerRuntimeConfig
from smplik.tracking.data import body_vector
from smplik.tracking.features import decode_pose, tracker_features
from smplik.tracking.io import TrackerSignals
from smplik.tracking.model_io import TrackingModel, load_model
from smplik.tracking.network import TrackingNet

ANOMALY_THRESHOLD = 0.02
"""A pose whose :func:`anomaly_scores` exceeds this is implausible (counted in the benchmark's anomaly rate)."""
CROSS_PAIRS = tuple((JOINT_INDEX[f"left_{j}"], JOINT_INDEX[f"right_{j}"]) for j in ("knee", "ankle", "foot"))
CROSS_MIN_M = 0.06
"""Left and right knees, ankles or feet closer than this intersect."""
BELOW_FLOOR_M = 0.02
"""A joint more than this below the floor penetrates it."""
_LEGS = ((JOINT_INDEX["left_hip"], JOINT_INDEX["left_knee"], JOINT_INDEX["left_ankle"], JOINT_INDEX["left_foot"]),
         (JOINT_INDEX["right_hip"], JOINT_INDEX["right_knee"], JOINT_INDEX["right_ankle"], JOINT_INDEX["right_foot"]))


def anomaly_scores(R_local: Tensor, p_world: Tensor, pose_lo: Tensor, pose_hi: Tensor, floor_y: float = 0.0) -> Tensor:
    """Implausibility (N,) of poses: metres of joints below the floor (past :data:`BELOW_FLOOR_M`) + metres of leg
    self-intersection (knees, ankles or feet closer than :data:`CROSS_MIN_M`) + 0.1 x radians of local
    axis-angle components outside the training range [pose_lo, pose_hi] (24, 3). R_local (N, 24, 3, 3),
    p_world (N, 24, 3). 0 for a plausible pose."""
    below = torch.relu(floor_y - BELOW_FLOOR_M - p_world[..., 1]).sum(-1)
    cross = sum(torch.relu(CROSS_MIN_M - (p_world[..., a, :] - p_world[..., b, :]).norm(dim=-1)) for a, b in CROSS_PAIRS)
    aa = matrix_to_axis_angle(R_local[..., 1:, :, :])
    out = (torch.relu(pose_lo[1:] - aa) + torch.relu(aa - pose_hi[1:])).sum((-1, -2))
    return below + cross + 0.1 * out


@dataclass(frozen=True)
class TrackedPose:
    """One output frame: R_local (24, 3, 3) local rotations (root in world), transl (3,) smplx translation,
    contacts (2,) bool (left, right), the sample shown, and its anomaly score."""

    frame: int
    R_local: np.ndarray
    transl: np.ndarray
    contacts: np.ndarray
    sample: int
    anomaly: float


class _FootLock:
    """Causal foot locking on a stream of poses (module docstring, step 4)."""

    def __init__(self, threshold: float, release_frames: int) -> None:
        self.threshold, self.release_frames = threshold, release_frames
        self.lock = [None, None]
        self.release = [0, 0]
        self.release_from = [np.zeros(3), np.zeros(3)]

    def apply(self, R_local: np.ndarray, R_world: np.ndarray, p: np.ndarray, prob: np.ndarray) -> np.ndarray:
        """Locked local rotations (24, 3, 3) of one pose (world rotations R_world, joints p)."""
        from workflows.motion_clean import two_bone_ik

        rows, targets = [], []
        for side, (_, _, _, foot) in enumerate(_LEGS):
            if prob[side] > self.threshold:
                if self.lock[side] is None:
                    self.lock[side] = p[foot].copy()
                rows.append(side)
                targets.append(self.lock[side])
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
        R_a, R_b = two_bone_ik(p[hip], p[knee], p[ankle], target, -R_world[knee, :, 0])
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
        self.model, self.net, self.cfg = model, model.net, config
        self.trackers = model.cfg.trackers
        self.fps = model.cfg.fps
        self.J_rest = J_rest  # (24, 3)
        self.body = body  # (13,)
        g = torch.Generator().manual_seed(config.seed)
        self.eps = torch.randn(config.samples, model.cfg.latent, generator=g)
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
        self.has_rot = torch.from_numpy(has)
        self.h: Tensor | None = None
        self.prev: tuple[Tensor, Tensor] | None = None
        self.frame_in = 0
        self.frame_out = 0
        self.buffer: deque[tuple[Tensor, Tensor, Tensor]] = deque()
        self.current = 0
        self.transition: tuple[int, int, int] | None = None  # (from, to, first output frame)
        self.lock = _FootLock(self.cfg.contact_threshold, self.cfg.release_frames)

    @property
    def latency(self) -> int:
        """Frames between an input and its output pose."""
        return self.cfg.lookahead if self.cfg.samples > 1 else 0

    @torch.inference_mode()
    def step(self, positions: np.ndarray, rotations: np.ndarray | None = None) -> TrackedPose | None:
        """One frame: positions (K, 3) metres, rotations (K, 4) unit quaternions (w, x, y, z) (rows of trackers
        without rotation are ignored), in the model's tracker order (:attr:`trackers`). Returns the output pose of
        frame ``frame_in - latency``, or None while the look-ahead buffer fills."""
        p = torch.as_tensor(np.asarray(positions, dtype=np.float32)).reshape(len(self.trackers), 3)
        if rotations is None:
            R = torch.eye(3).expand(len(self.trackers), 3, 3)
        else:
            q = torch.as_tensor(np.asarray(rotations, dtype=np.float32)).reshape(len(self.trackers), 4)
            R = quaternion_to_matrix(q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8))
        prev = self.prev if self.prev is not None else (p, R)
        self.prev = (p, R)
        x, yaw, origin = tracker_features(torch.stack([prev[0], p]), torch.stack([prev[1], R]), self.has_rot, self.fps)
        h, self.h = self.net.condition(x[None, 1:], self.body[None], self.h)
        h = h[0, 0]
        self.frame_in += 1
        if self.cfg.samples == 1:
            return self._emit(h, yaw[1], origin[1], self.eps[0])
        self._select(h, yaw[1], origin[1])
        self.buffer.append((h, yaw[1], origin[1]))
        if len(self.buffer) > self.cfg.lookahead:
            return self._pop()
        return None

    @torch.inference_mode()
    def flush(self) -> list[TrackedPose]:
        """The poses still in the look-ahead buffer (call once at the end of a recording)."""
        out = []
        while self.buffer:
            out.append(self._pop())
        return out

    def _select(self, h: Tensor, yaw: Tensor, origin: Tensor) -> None:
        """Score the N samples at the newest frame; start a transition when the current one is an outlier."""
        N = self.cfg.samples
        out = self.net.sample(h.expand(N, -1), self.eps, self.body.expand(N, -1))
        R, transl, _ = decode_pose(out, yaw, origin, self.J_rest)
        _, p = forward_kinematics(R, self.J_rest, transl)
        s = anomaly_scores(R, p, self.model.pose_lo, self.model.pose_hi, self.cfg.floor_y)
        if self.transition is not None:
            return
        r = float(s.median() - s.min())
        cur = float(s[self.current])
        if cur > ANOMALY_THRESHOLD and cur > 2.0 * r:
            best = int(s.argmin())
            if best != self.current:
                first = self.frame_out  # the next output frame
                self.transition = (self.current, best, first)

    def _pop(self) -> TrackedPose:
        h, yaw, origin = self.buffer.popleft()
        eps = self.eps[self.current]
        if self.transition is not None:
            a, b, first = self.transition
            w = min(1.0, (self.frame_out - first + 1) / self.cfg.blend)
            eps = (1 - w) * self.eps[a] + w * self.eps[b]
            if w >= 1.0:
                self.current, self.transition = b, None
        return self._emit(h, yaw, origin, eps)

    def _emit(self, h: Tensor, yaw: Tensor, origin: Tensor, eps: Tensor) -> TrackedPose:
        out = self.net.sample(h[None], eps[None], self.body[None])
        R, transl, prob = decode_pose(out, yaw, origin, self.J_rest)
        R_w, p = forward_kinematics(R, self.J_rest, transl)
        score = float(anomaly_scores(R, p, self.model.pose_lo, self.model.pose_hi, self.cfg.floor_y)[0])
        R_np, prob_np = R[0].numpy().astype(np.float64), prob[0].numpy()
        if self.cfg.foot_lock:
            R_np = self.lock.apply(R_np, R_w[0].numpy().astype(np.float64), p[0].numpy().astype(np.float64), prob_np)
        pose = TrackedPose(self.frame_out, R_np, transl[0].numpy().astype(np.float64),
                           prob_np > self.cfg.contact_threshold, self.current if self.transition is None
                           else self.transition[1], score)
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
    T = signals.num_frames
    if abs(signals.fps - fps) < 1e-6:
        return signals.positions, signals.rotations, np.arange(T)
    t_in = np.arange(T) / signals.fps
    t_out = np.arange(0.0, t_in[-1] + 1e-9, 1.0 / fps)
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


def track_sequence(tracker: Tracker, signals: TrackerSignals) -> TrackResult:
    """Run a recording through :meth:`Tracker.step` (after :meth:`Tracker.reset`); one pose per input frame
    (recordings at another rate are resampled to the model's and mapped back to the nearest frame)."""
    sig = signals.select(tracker.trackers)
    tracker.reset(sig.has_rotation)
    P, Q, nearest = resample_signals(sig, tracker.fps)
    poses: list[TrackedPose] = []
    for t in range(P.shape[0]):
        pose = tracker.step(P[t], Q[t])
        if pose is not None:
            poses.append(pose)
    poses.extend(tracker.flush())
    assert len(poses) == P.shape[0]
    poses = [poses[i] for i in nearest]
    return TrackResult(np.stack([p.R_local for p in poses]), np.stack([p.transl for p in poses]),
                       np.stack([p.contacts for p in poses]), np.array([p.sample for p in poses]),
                       np.array([p.anomaly for p in poses]))
