"""Single-limb edits from real motion: pair selection and metrics of the edit benchmark.

An *edit pair* is two frames ``(t0, t1)`` of a clip, ``t1 - t0`` between :attr:`EditPairConfig.min_dt` and
:attr:`~EditPairConfig.max_dt` seconds apart, in which exactly one limb end (a wrist or an ankle,
:data:`LIMB_ENDS`) moves at least :attr:`~EditPairConfig.min_move` metres while every other limb end and the
head move less than :attr:`~EditPairConfig.max_still` metres, all **relative to the pelvis** (positions in
the pelvis's own frame, so walking or turning does not count as a move): an edit a real person made with one
limb. The benchmark (``benchmarks/edit_benchmark.py``, :mod:`workflows.edit_benchmark.run`) moves that limb end's
effector of frame ``t0`` to its position at ``t1`` and compares the solved pose with frame ``t1``.

Frame ``t1`` is first expressed in frame ``t0``'s pelvis frame (:func:`align_to_pelvis`): the target and
the ground truth are where the limb end went relative to a pelvis that did not move.

Metrics (:func:`edit_metrics`), per pair:

* ``mpjpe_mm``: mean joint error over the 24 joints against the aligned frame ``t1``;
* ``collateral_mm``: the same over the joints outside the edited limb (:data:`~smplik.conventions.LIMB_CHAINS`);
* ``reach_mm``: distance of the dragged joint from its target;
* contortions: joints whose local rotation leaves the range seen in the training motion
  (:class:`JointRanges`, with a margin) where the real frame ``t1`` stays inside it, and torso joints
  (:data:`TORSO_JOINTS`, world orientation) turned more than :data:`TORSO_TURN_DEG` further from the
  unedited pose than the real motion turned them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, LIMB_CHAINS, NUM_JOINTS
from smplik.rotations import geodesic_distance

LIMB_ENDS: tuple[str, ...] = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")
"""The joints an edit drags, in the order used by :func:`find_edit_pairs`."""
STILL_JOINTS: tuple[str, ...] = (*LIMB_ENDS, "head")
"""Joints that must stay put (all but the dragged one)."""
LIMB_OF_END: dict[str, str] = {"left_wrist": "left_arm", "right_wrist": "right_arm",
                               "left_ankle": "left_leg", "right_ankle": "right_leg"}
"""The limb (:data:`~smplik.conventions.LIMB_CHAINS` key) of each limb end."""
LIMB_ROOT: dict[str, str] = {"left_wrist": "left_shoulder", "right_wrist": "right_shoulder",
                             "left_ankle": "left_hip", "right_ankle": "right_hip"}
"""The first joint of each limb end's two-bone chain (its reach is measured from there)."""
TORSO_JOINTS: tuple[str, ...] = ("spine1", "spine2", "spine3", "neck", "head")
"""Joints whose turn counts as a contortion when it exceeds the real motion's by :data:`TORSO_TURN_DEG`."""
TORSO_TURN_DEG = 20.0
RANGE_MARGIN_DEG = 5.0
"""Slack added on each side of the training range of every rotation-vector component."""


@dataclass(frozen=True)
class EditPairConfig:
    """What makes two frames a single-limb edit."""

    min_dt: float = 0.3
    """Shortest time between the frames (s)."""
    max_dt: float = 1.5
    """Longest time between the frames (s)."""
    min_move: float = 0.15
    """The dragged limb end moves at least this far relative to the pelvis (m)."""
    max_still: float = 0.03
    """Every other limb end and the head move less than this relative to the pelvis (m)."""
    min_gap: float = 0.2
    """Start frames of a clip's pairs are at least this far apart (s), so pairs are not near-copies."""

    def __post_init__(self) -> None:
        if not 0 < self.min_dt <= self.max_dt:
            raise ValueError(f"EditPairConfig: need 0 < min_dt <= max_dt, got {self.min_dt}, {self.max_dt}.")
        if not 0 <= self.max_still < self.min_move:
            raise ValueError(f"EditPairConfig: need 0 <= max_still < min_move, got {self.max_still}, "
                             f"{self.min_move}.")


@dataclass(frozen=True)
class EditPair:
    """One single-limb edit of a clip: frames ``t0 -> t1``; ``end`` moved ``move_m`` metres (pelvis frame)."""

    clip: int
    t0: int
    t1: int
    end: str
    move_m: float


def pelvis_relative(p_world: Tensor, R_world_pelvis: Tensor) -> Tensor:
    """Joint positions in the pelvis's frame: ``R_world_pelvis^T (p - p_pelvis)``.

    p_world (..., 24, 3), R_world_pelvis (..., 3, 3) -> (..., 24, 3).
    """
    rel = p_world - p_world[..., :1, :]
    return rel @ R_world_pelvis  # row vectors: (R^T v)^T = v^T R


def find_edit_pairs(p_pelvis: Tensor, fps: float, cfg: EditPairConfig = EditPairConfig(), *,
                    clip: int = 0) -> list[EditPair]:
    """The single-limb edits of one clip (see the module docstring).

    Scanning ``t0`` forward, a frame with valid partners takes the partner where the limb end moved
    farthest; the scan resumes :attr:`EditPairConfig.min_gap` seconds later (at least one frame).

    Args:
        p_pelvis: (T, 24, 3) joint positions relative to the pelvis (:func:`pelvis_relative`), metres.
        fps: the clip's frame rate.
        clip: stored in each pair.
    """
    if p_pelvis.ndim != 3 or p_pelvis.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"p_pelvis must have shape (T, {NUM_JOINTS}, 3), got {tuple(p_pelvis.shape)}.")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}.")
    T = p_pelvis.shape[0]
    lo, hi = math.ceil(cfg.min_dt * fps - 1e-9), math.floor(cfg.max_dt * fps + 1e-9)
    watched = p_pelvis[:, [JOINT_INDEX[n] for n in STILL_JOINTS]].double()  # (T, 5, 3); ends first, head last
    n_ends = len(LIMB_ENDS)
    best_move = torch.full((T,), -1.0, dtype=torch.float64)
    best_dt = torch.zeros(T, dtype=torch.long)
    best_end = torch.zeros(T, dtype=torch.long)
    for dt in range(max(lo, 1), min(hi, T - 1) + 1):
        move = (watched[dt:] - watched[:-dt]).norm(dim=-1)  # (T - dt, 5)
        big = move[:, :n_ends] >= cfg.min_move
        still = move < cfg.max_still
        # exactly one end moved far, and all other watched joints (other ends + head) stayed
        ok = (big.sum(-1) == 1) & ((still | torch.cat([big, torch.zeros_like(big[:, :1])], -1)).all(-1))
        moved = torch.where(ok, (move[:, :n_ends] * big).amax(-1), torch.full_like(move[:, 0], -1.0))
        better = moved > best_move[:T - dt]
        best_move[:T - dt] = torch.where(better, moved, best_move[:T - dt])
        best_dt[:T - dt] = torch.where(better, dt, best_dt[:T - dt])
        best_end[:T - dt] = torch.where(better, big.float().argmax(-1), best_end[:T - dt])
    gap = max(1, round(cfg.min_gap * fps))
    pairs: list[EditPair] = []
    t = 0
    while t < T:
        if best_move[t] >= 0:
            pairs.append(EditPair(clip, t, t + int(best_dt[t]), LIMB_ENDS[int(best_end[t])], float(best_move[t])))
            t += gap
        else:
            t += 1
    return pairs


def align_to_pelvis(R_world: Tensor, p_world: Tensor, R_world_pelvis_ref: Tensor,
                    p_pelvis_ref: Tensor) -> tuple[Tensor, Tensor]:
    """A posed skeleton moved rigidly so that its pelvis has the reference pelvis's position and rotation.

    R_world (..., 24, 3, 3), p_world (..., 24, 3), R_world_pelvis_ref (..., 3, 3), p_pelvis_ref (..., 3)
    -> (R_world', p_world') of the same shapes.
    """
    R_align = R_world_pelvis_ref @ R_world[..., 0, :, :].transpose(-1, -2)  # (..., 3, 3)
    p = (p_world - p_world[..., :1, :]) @ R_align.transpose(-1, -2) + p_pelvis_ref[..., None, :]
    return R_align[..., None, :, :] @ R_world, p


@dataclass(frozen=True)
class JointRanges:
    """Per joint and rotation-vector component, the range of local rotations seen in a motion set.

    lo, hi: (24, 3) radians (joint 0, the global orientation, is never checked).
    """

    lo: Tensor
    hi: Tensor

    @classmethod
    def fit(cls, pose_axis_angle: Tensor) -> JointRanges:
        """From local rotations (M, 24, 3) axis-angle (e.g. a train split's ``pose``)."""
        if pose_axis_angle.ndim != 3 or pose_axis_angle.shape[1:] != (NUM_JOINTS, 3) or not len(pose_axis_angle):
            raise ValueError(f"pose must have shape (M > 0, {NUM_JOINTS}, 3), got {tuple(pose_axis_angle.shape)}.")
        x = pose_axis_angle.double()
        return cls(x.amin(0), x.amax(0))

    def outside(self, pose_axis_angle: Tensor, margin_deg: float = RANGE_MARGIN_DEG) -> Tensor:
        """(..., 24) bool: the joint's rotation vector leaves the range widened by ``margin_deg``.

        pose_axis_angle (..., 24, 3). Joint 0 is always False.
        """
        m = math.radians(margin_deg)
        x = pose_axis_angle.double()
        out = ((x < self.lo - m) | (x > self.hi + m)).any(-1)
        out[..., 0] = False
        return out

    def to_dict(self) -> dict[str, list]:
        return {"lo": self.lo.tolist(), "hi": self.hi.tolist()}


@dataclass(frozen=True)
class EditMetrics:
    """Per-pair errors of one method (P pairs); see the module docstring. All tensors (P,)."""

    mpjpe_mm: Tensor
    collateral_mm: Tensor
    limb_mm: Tensor
    reach_mm: Tensor
    out_of_range: Tensor
    """Joints the edit took outside the training range: outside where the real frame ``t1`` and the pose
    the edit started from are inside (long)."""
    torso_turned: Tensor
    """Torso joints turned more than :data:`TORSO_TURN_DEG` beyond the real motion (long)."""
    torso_excess_deg: Tensor
    """The largest extra turn of a torso joint over the real motion (degrees; negative: less than real)."""

    @property
    def contortions(self) -> Tensor:
        """(P,) long: contorted joints of each pair."""
        return self.out_of_range + self.torso_turned


def limb_mask(ends: list[str]) -> Tensor:
    """(P, 24) bool: the joints of each dragged end's limb (:data:`~smplik.conventions.LIMB_CHAINS`)."""
    mask = torch.zeros(len(ends), NUM_JOINTS, dtype=torch.bool)
    for i, end in enumerate(ends):
        mask[i, [JOINT_INDEX[n] for n in LIMB_CHAINS[LIMB_OF_END[end]]]] = True
    return mask


def edit_metrics(*, p_pred: Tensor, R_world_pred: Tensor, aa_local_pred: Tensor, p_true: Tensor,
                 R_world_true: Tensor, aa_local_true: Tensor, R_world_before: Tensor, aa_local_before: Tensor,
                 R_world_start: Tensor, ends: list[str], targets: Tensor, ranges: JointRanges) -> EditMetrics:
    """Errors of edited poses against the real frames (P pairs).

    Args:
        p_pred, p_true: (P, 24, 3) joints (metres) of the method's pose and of the aligned real frame ``t1``.
        R_world_pred, R_world_true: (P, 24, 3, 3) their global rotations.
        aa_local_pred, aa_local_true: (P, 24, 3) their local rotations (axis-angle).
        R_world_before, aa_local_before: (P, 24, 3, 3), (P, 24, 3) global and local rotations of the pose the
            edit started from (the scene's);
        R_world_start: (P, 24, 3, 3) those of the real frame ``t0`` (the real turn is measured from there).
        ends: the dragged joint of each pair (:data:`LIMB_ENDS`); targets: (P, 3) where it was dragged.
        ranges: the training motion's :class:`JointRanges`.
    """
    err = (p_pred - p_true).norm(dim=-1).double() * 1000.0  # (P, 24)
    limb = limb_mask(ends)
    rows = torch.arange(len(ends))
    end_idx = torch.tensor([JOINT_INDEX[e] for e in ends], dtype=torch.long)
    reach = (p_pred[rows, end_idx] - targets).norm(dim=-1).double() * 1000.0
    out_of_range = (ranges.outside(aa_local_pred) & ~ranges.outside(aa_local_true)
                    & ~ranges.outside(aa_local_before)).sum(-1)
    torso = [JOINT_INDEX[n] for n in TORSO_JOINTS]
    turn_pred = geodesic_distance(R_world_pred[:, torso].double(), R_world_before[:, torso].double())
    turn_real = geodesic_distance(R_world_true[:, torso].double(), R_world_start[:, torso].double())
    excess = torch.rad2deg(turn_pred - turn_real)
    return EditMetrics(
        mpjpe_mm=err.mean(-1),
        collateral_mm=(err * ~limb).sum(-1) / (~limb).sum(-1),
        limb_mm=(err * limb).sum(-1) / limb.sum(-1),
        reach_mm=reach,
        out_of_range=out_of_range.long(),
        torso_turned=(excess > TORSO_TURN_DEG).sum(-1).long(),
        torso_excess_deg=excess.amax(-1),
    )


def summarize(metrics: EditMetrics, reachable: Tensor) -> dict[str, float | int]:
    """Pooled figures of one method: means, the reach within 1 cm where ``reachable`` (P,) bool, contortions."""
    reach = metrics.reach_mm
    n_reach = int(reachable.sum())
    return {
        "pairs": int(reach.shape[0]),
        "mpjpe_mm": float(metrics.mpjpe_mm.mean()),
        "collateral_mm": float(metrics.collateral_mm.mean()),
        "limb_mm": float(metrics.limb_mm.mean()),
        "reach_mm_median": float(reach.median()),
        "reach_mm_mean": float(reach.mean()),
        "reachable_pairs": n_reach,
        "reach_within_1cm": float((reach[reachable] <= 10.0).double().mean()) if n_reach else float("nan"),
        "contorted_pairs": int((metrics.contortions > 0).sum()),
        "out_of_range_joints": int(metrics.out_of_range.sum()),
        "torso_turned_pairs": int((metrics.torso_turned > 0).sum()),
        "torso_excess_deg_max": float(metrics.torso_excess_deg.max()),
    }
