"""Sequence solving: every frame of a motion at once, from per-frame effectors, with a temporal term.

A frame-by-frame solve (network + refinement, :mod:`smplik.refine`) sees one frame's effectors: where
they leave the pose open the network decides, a little differently on each frame (and the recovered
effectors themselves change joints from frame to frame), so the poses jitter. :func:`solve_sequence`
solves the frames together, warm-started from per-frame poses (the frame-wise solves, or an estimator's
per-frame poses), in two steps:

1. **Trajectories over all frames** (:func:`smooth_trajectories`): every joint's path ``z_tj`` minimises

   ``sum_t w_tj |z_tj - y_tj|^2  +  smoothness * sum_t |z_t+1,j - 2 z_tj + z_t-1,j|^2``

   (a weighted Whittaker-Henderson smoother, :mod:`smplik.smoothing`: one banded solve per coordinate over the whole
   sequence). The data ``y`` are the warm start's joints (weight 1, or given targets and weights) and,
   where a frame has a position effector on the joint, its target with weight ``effector_weight``
   (times the effector's tolerance weight): the paths pass through the effectors and are smooth where
   nothing holds them.
2. **Poses on the trajectories**: each frame is refined (the Levenberg-Marquardt refinement of
   :mod:`smplik.refine`, batched over all frames, from the warm start, its prior centred on the warm
   start's local rotations) towards its own effectors plus one position effector per joint on the
   smoothed path (tolerance ``trajectory_tolerance``).

So the temporal problem is solved exactly and jointly in joint space (where accelerations are measured),
and the body fits it frame by frame; with smooth paths the fitted poses are smooth too. On CMU mocap the
result is closer to the real motion than the frame-wise solves on both MPJPE and acceleration error
(``benchmarks/animation.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.linalg import solveh_banded
from torch import Tensor

from smplik.conventions import PARENTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.refine import RefineConfig, refine_output, tolerance_weight
from smplik.smoothing import penalty_bands

REFINE_CHUNK = 512
"""Frames refined per call in step 2 (bounds the memory of the torch refinement on long clips)."""


class SequenceError(ValueError):
    """Invalid sequence-solve input or settings (one line)."""


@dataclass(frozen=True)
class SequenceConfig:
    """Settings of :func:`solve_sequence` (chosen on CMU mocap, ``benchmarks/animation.py``)."""

    smoothness: float = 5.0
    """Weight of the joints' squared acceleration (m/frame^2) against a unit-weight squared joint offset (m)."""
    effector_weight: float = 100.0
    """Weight of a position effector's target in the trajectories, against the warm start's joint (1)."""
    trajectory_tolerance: float = 0.0
    """Tolerance of the per-joint path effectors of step 2 (0: they pull as hard as exact effectors)."""
    refine: RefineConfig = field(default_factory=lambda: RefineConfig(iterations=5))
    """The per-frame refinement of step 2 (its prior is centred on the warm start)."""

    def __post_init__(self) -> None:
        for name in ("smoothness", "effector_weight"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1e9:
                raise SequenceError(f"SequenceConfig.{name} must be a number in [0, 1e9], got {value!r:.40}.")
        if not (isinstance(self.trajectory_tolerance, (int, float)) and 0 <= self.trajectory_tolerance <= 1):
            raise SequenceError(f"SequenceConfig.trajectory_tolerance must be in [0, 1], got "
                                f"{self.trajectory_tolerance!r:.40}.")


def smooth_trajectories(y: np.ndarray, weight: np.ndarray, smoothness: float) -> np.ndarray:
    """Weighted Whittaker-Henderson smoothing along time (module docstring, step 1).

    Args:
        y: (T, K, C) data; weight: (T, K) > 0 weight of each frame's data per path; smoothness >= 0.

    Returns:
        (T, K, C) paths ``z`` minimising ``sum_t w_tk |z_tk - y_tk|^2 + smoothness sum_t |D2 z_tk|^2``
        (``D2``: second difference); ``y`` itself when ``T < 3`` or ``smoothness == 0``.
    """
    T, K = weight.shape
    if y.shape[:2] != (T, K):
        raise SequenceError(f"smooth_trajectories: data {y.shape} and weights {weight.shape} do not match.")
    if T < 3 or smoothness == 0:
        return np.array(y, dtype=np.float64)
    main, off1, off2 = penalty_bands(np.full(T - 2, float(smoothness)))  # smoothness * D2^T D2
    out = np.empty(y.shape, dtype=np.float64)
    banded = np.zeros((3, T))  # upper form for solveh_banded
    banded[0, 2:] = off2
    banded[1, 1:] = off1
    for k in range(K):
        banded[2] = weight[:, k] + main
        out[:, k] = solveh_banded(banded, weight[:, k, None] * y[:, k], check_finite=False)
    return out


def _position_data(y: np.ndarray, w: np.ndarray, eff: EffectorBatch, effector_weight: float, eta: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Add each position effector's target to the path data: y (T, J, 3), w (T, J) -> blended (y, w)."""
    y, w = y.copy(), w.copy()
    is_pos = ((eff.type == int(EffectorType.POSITION)) & eff.mask).numpy()
    weights = (effector_weight * tolerance_weight(eff.tolerance.double(), eta)).numpy()
    data = eff.data[..., :3].double().numpy()
    for t, n in zip(*np.nonzero(is_pos), strict=True):
        j, we = int(eff.joint[t, n]), float(weights[t, n])
        y[t, j] = (w[t, j] * y[t, j] + we * data[t, n]) / (w[t, j] + we)
        w[t, j] += we
    return y, w


def solve_sequence(R_local: Tensor, transl: Tensor, J_rest: Tensor, eff: EffectorBatch | None = None,
                   cfg: SequenceConfig = SequenceConfig(), *, joint_targets: np.ndarray | None = None,
                   joint_weights: np.ndarray | None = None, parents: tuple[int, ...] = PARENTS
                   ) -> tuple[Tensor, Tensor]:
    """Solve a motion's frames together (module docstring).

    Args:
        R_local: (T, J, 3, 3) warm-start local rotations (also the refinement prior's centre); transl: (T, 3).
        J_rest: (J, 3) rest joints of the body (one body for the whole motion).
        eff: T rows of N effectors (SMPL space), one row per frame, or None.
        joint_targets: (T, J, 3) data of the paths (default: the warm start's joints).
        joint_weights: (T, J) > 0 weights of ``joint_targets`` (default 1).

    Returns:
        ``(R_local (T, J, 3, 3), transl (T, 3))`` float64.
    """
    T, J = R_local.shape[:2]
    if R_local.shape[1:] != (len(parents), 3, 3) or transl.shape != (T, 3) \
            or (eff is not None and eff.joint.shape[0] != T):
        raise SequenceError(f"solve_sequence: shapes do not match: R_local {tuple(R_local.shape)}, transl "
                            f"{tuple(transl.shape)}, effectors for {None if eff is None else eff.joint.shape[0]} "
                            "frames.")
    dt = torch.float64
    R0, t0, J_rest = R_local.detach().to(dt), transl.detach().to(dt), J_rest.detach().to(dt)
    R_world, p_world = forward_kinematics(R0, J_rest, t0, parents)
    if T < 3:
        return R0.clone(), t0.clone()
    y = p_world.numpy() if joint_targets is None else np.asarray(joint_targets, dtype=np.float64)
    w = np.ones((T, J)) if joint_weights is None else np.asarray(joint_weights, dtype=np.float64)
    if y.shape != (T, J, 3) or w.shape != (T, J) or not (np.isfinite(y).all() and (w > 0).all()):
        raise SequenceError(f"solve_sequence: joint targets {y.shape} / weights {w.shape} must be finite, "
                            f"({T}, {J}, 3) / ({T}, {J}) with weights > 0.")
    if eff is not None:
        y, w = _position_data(y, w, eff, cfg.effector_weight, cfg.refine.tolerance_eta)
    paths = torch.from_numpy(smooth_trajectories(y, w, cfg.smoothness))
    joints = torch.arange(J).expand(T, J)
    path_eff = EffectorBatch(joints, torch.full((T, J), int(EffectorType.POSITION)),
                             torch.cat([paths, torch.zeros(T, J, 3, dtype=dt)], -1),
                             torch.full((T, J), float(cfg.trajectory_tolerance), dtype=dt),
                             torch.ones(T, J, dtype=torch.bool))
    if eff is not None:
        path_eff = EffectorBatch(*(torch.cat([getattr(eff, f).to(getattr(path_eff, f).dtype), getattr(path_eff, f)], 1)
                                   for f in ("joint", "type", "data", "tolerance", "mask")))
    R_out, t_out = R0.clone(), t0.clone()
    for lo in range(0, T, REFINE_CHUNK):  # frames are independent here; chunks bound the memory
        hi = min(T, lo + REFINE_CHUNK)
        start = IKOutput(R0[lo:hi], R_world[lo:hi], p_world[lo:hi], p_world[lo:hi], t0[lo:hi])
        chunk = EffectorBatch(*(getattr(path_eff, f)[lo:hi] for f in ("joint", "type", "data", "tolerance", "mask")))
        out = refine_output(start, J_rest.expand(hi - lo, J, 3).contiguous(), chunk, cfg.refine, parents)
        R_out[lo:hi], t_out[lo:hi] = out.R_local.to(dt), out.transl.to(dt)
    return R_out, t_out
