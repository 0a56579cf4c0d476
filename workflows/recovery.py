"""Effector recovery (smpl-ik.txt section 5, App. D): a few effectors that reproduce a full pose.

Greedy: start from no effector; at each step try every remaining candidate ``(joint, type)`` added
to the current set, all candidates in **one** batched solve (row ``b`` = current set + candidate
``b``); keep the candidate whose solved pose has the lowest mean per-joint L2 error to the target
in character space; stop at ``max_effectors``, once the error is below ``threshold``, or when no
remaining candidate lowers the error (with a learned solver an extra effector can make the pose
slightly worse; such an effector is not kept), so the errors strictly decrease.

Candidates: the 24 joints x {position, rotation}, plus (``include_look_at``) a look-at on the head
whose target is ``look_at_distance`` metres along the head's forward axis (+z in its frame).
Effector values are the target pose's exact joint positions / global rotations (tolerance
``tolerance``).

Spaces: the solver works in SMPL space (the body ``J(betas)`` at unit scale); a character of
``scale`` s is the SMPL body scaled by s about the world origin (see :mod:`workflows.scene`), so
the character-space error is ``s`` times the SMPL-space error and recovered effectors are
returned in character space (positions and look-at targets times s).

Candidates are scored with a cheap solve (the network plus ``search_refine_steps`` refinement
steps); the chosen set is then solved once more with the solver's full refinement for the final
pose. That pose is the result even in the rare case where it is farther from the target than the
search's cheap solve: it is the pose that the
recovered effectors re-solve to, so a scene built from it does not jump at its first edit or
``smplik scene solve``.

Speed: candidate effector data are precomputed once as tensors; each step builds the packed
``(B, k + 1)`` batch by concatenation, with no per-candidate Python objects.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, NUM_BETAS, NUM_JOINTS, EffectorType, Gender
from smplik.effectors import Effector, EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.pose import Pose
from smplik.refine import DEFAULT_REFINEMENT, RefineConfig
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_rot6d

HEAD_FORWARD = (0.0, 0.0, 1.0)
"""The head's forward axis in its own frame (SMPL faces +z at rest)."""

LIMB_ZONES: dict[str, tuple[str, ...]] = {
    "torso_head": ("pelvis", "spine1", "spine2", "spine3", "neck", "head"),
    "left_arm": ("left_collar", "left_shoulder", "left_elbow", "left_wrist", "left_hand"),
    "right_arm": ("right_collar", "right_shoulder", "right_elbow", "right_wrist", "right_hand"),
    "left_leg": ("left_hip", "left_knee", "left_ankle", "left_foot"),
    "right_leg": ("right_hip", "right_knee", "right_ankle", "right_foot"),
}
"""The body's limbs, for the ``"joints+worst_limb"`` criterion and the benchmark's per-limb errors."""

Criterion = Literal["joints", "joints+worst_limb"]


def limb_errors(joint_err: Tensor) -> Tensor:
    """Per-limb mean joint error. joint_err (..., 24) -> (..., 5) in :data:`LIMB_ZONES` order."""
    return torch.stack([joint_err[..., [JOINT_INDEX[n] for n in names]].mean(-1) for names in LIMB_ZONES.values()],
                       -1)


def recovery_score(joint_err: Tensor, criterion: Criterion) -> Tensor:
    """What the greedy search minimises. joint_err (..., 24) per-joint L2 errors (m) -> (...,).

    ``"joints"``: the mean per-joint error. ``"joints+worst_limb"``: the mean of that and the worst
    limb's mean error, so a limb far off (a raised arm) costs more than many small errors elsewhere.
    """
    mean = joint_err.mean(-1)
    if criterion == "joints":
        return mean
    return 0.5 * (mean + limb_errors(joint_err).max(-1).values)


class TensorSolver(Protocol):
    """What recovery needs from a solver: ``IKSolver.solve_tensors`` (no validation, batched; ``refine``
    overrides the solver's effector refinement, None keeps it)."""

    def solve_tensors(self, eff: EffectorBatch, betas: Tensor, gender: Tensor, *,
                      refine: RefineConfig | None = None) -> IKOutput: ...


@dataclass(frozen=True)
class TargetPose:
    """A pose to recover, in SMPL space (unit scale). p_world (24, 3), R_world (24, 3, 3) float32 tensors."""

    p_world: Tensor
    R_world: Tensor
    betas: Tensor
    gender: Gender

    @classmethod
    def from_pose(cls, pose: Pose) -> TargetPose:
        """FK of a :class:`~smplik.pose.Pose` with the body model of its gender."""
        from smplik.body_model import load_body_model

        model = load_body_model(pose.gender)
        betas = torch.as_tensor(pose.betas, dtype=torch.float32)
        aa = torch.as_tensor(np.concatenate([pose.global_orient[None], pose.body_pose]), dtype=torch.float32)
        R_world, p_world = forward_kinematics(axis_angle_to_matrix(aa), model.rest_joints(betas),
                                              torch.as_tensor(pose.transl, dtype=torch.float32))
        return cls(p_world, R_world, betas, pose.gender)


@dataclass(frozen=True)
class RecoveryConfig:
    """Settings of :func:`recover_effectors`."""

    max_effectors: int = 8
    """Stop after this many effectors."""
    threshold: float = 0.02
    """Stop once the mean per-joint error (metres, character space) is below this."""
    include_look_at: bool = True
    """Also try a look-at effector on the head."""
    look_at_distance: float = 1.0
    """Distance (metres, SMPL space) of the head's look-at target along its forward axis."""
    tolerance: float = 0.0
    """Tolerance given to every recovered effector."""
    search_refine_steps: int = 1
    """Refinement steps (:mod:`smplik.refine`) while scoring candidates; the final pose gets the
    solver's own refinement. One step keeps 8 effectors under 100 ms on one CPU thread."""
    criterion: Criterion = "joints"
    """What each step minimises (:func:`recovery_score`); ``errors`` always report the mean joint error."""


@dataclass(frozen=True)
class RecoveryResult:
    """Recovered effectors (character space), the error after each step and the final solved pose.

    Attributes:
        effectors: in the order they were chosen.
        errors: (K,) mean per-joint L2 error (metres, character space) after 1..K effectors, as
            scored during the search.
        pose: the pose solved from all recovered effectors (SMPL space) with the solver's refinement.
        scale: the character scale used.
        final_error: mean per-joint L2 error of ``pose`` (metres, character space).
    """

    effectors: tuple[Effector, ...]
    errors: tuple[float, ...]
    pose: Pose
    scale: float
    final_error: float


def candidate_table(target: TargetPose, cfg: RecoveryConfig) -> tuple[Tensor, Tensor, Tensor]:
    """All candidates as tensors: joint (C,) long, type (C,) long, data (C, 6) (SMPL space)."""
    J = NUM_JOINTS
    joints = [torch.arange(J), torch.arange(J)]
    types = [torch.full((J,), int(EffectorType.POSITION)), torch.full((J,), int(EffectorType.ROTATION))]
    data = [torch.cat([target.p_world, torch.zeros(J, 3)], -1), matrix_to_rot6d(target.R_world)]
    if cfg.include_look_at:
        h = JOINT_INDEX["head"]
        d = torch.tensor(HEAD_FORWARD)
        aim = target.p_world[h] + cfg.look_at_distance * (target.R_world[h] @ d)
        joints.append(torch.tensor([h]))
        types.append(torch.tensor([int(EffectorType.LOOK_AT)]))
        data.append(torch.cat([aim, d])[None])
    return torch.cat(joints), torch.cat(types), torch.cat(data).float()


def _to_effector(joint: int, kind: int, data: np.ndarray, scale: float, tolerance: float) -> Effector:
    if kind == EffectorType.POSITION:
        return Effector.position(joint, data[:3] * scale, tolerance)
    if kind == EffectorType.ROTATION:
        a, b = data[:3], data[3:]
        R = np.stack([a, b, np.cross(a, b)], axis=1)
        return Effector.rotation(joint, R, tolerance)
    return Effector.look_at(joint, data[:3] * scale, data[3:], tolerance)


def output_to_pose(out: IKOutput, row: int, betas: Tensor, gender: Gender) -> Pose:
    """Row ``row`` of a solver output as a :class:`~smplik.pose.Pose` (joints included)."""
    aa = matrix_to_axis_angle(out.R_local[row].double()).numpy()
    return Pose(aa[0], aa[1:], out.transl[row].double().numpy(), betas.double().numpy(), gender,
                out.p_world[row].double().numpy())


def recover_effectors(solver: TensorSolver, target: TargetPose, cfg: RecoveryConfig = RecoveryConfig(), *,
                      scale: float = 1.0) -> RecoveryResult:
    """Greedy effector recovery of one pose (see the module docstring; :func:`recover_many` for several).

    Args:
        solver: anything with ``solve_tensors`` (e.g. :class:`smplik.solver.IKSolver`).
        target: the pose to reproduce (SMPL space).
        cfg: limits and candidate set.
        scale: character scale (errors and effectors are reported in character space).

    Returns: :class:`RecoveryResult` with at least one effector.
    """
    return recover_many(solver, [target], cfg, scales=[scale])[0]


@dataclass
class _Search:
    """One target's greedy state inside :func:`recover_many`."""

    target: TargetPose
    scale: float
    cand: tuple[Tensor, Tensor, Tensor]
    remaining: Tensor
    chosen: list[int]
    errors: list[float]
    scores: list[float]
    best_eff: EffectorBatch | None = None
    done: bool = False


@torch.inference_mode()
def recover_many(solver: TensorSolver, targets: Sequence[TargetPose], cfg: RecoveryConfig = RecoveryConfig(), *,
                 scales: Sequence[float] | None = None,
                 progress: Callable[[int, int], None] | None = None) -> list[RecoveryResult]:
    """Greedy effector recovery of several poses at once (many people / frames): each step solves the
    candidates of every unfinished pose in ONE batched call; the final solves are batched per count.

    Args:
        targets: poses to reproduce (SMPL space); scales: their character scales (default 1).
        progress: ``progress(step, max_steps)`` after each greedy step.

    Returns: one :class:`RecoveryResult` per target, the same as :func:`recover_effectors` on each.
    """
    if cfg.max_effectors < 1:
        raise ValueError(f"max_effectors must be >= 1, got {cfg.max_effectors}.")
    if cfg.search_refine_steps < 0:
        raise ValueError(f"search_refine_steps must be >= 0, got {cfg.search_refine_steps}.")
    scales = [1.0] * len(targets) if scales is None else list(scales)
    if len(scales) != len(targets):
        raise ValueError(f"{len(targets)} targets but {len(scales)} scales.")
    for scale in scales:
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}.")
    states = []
    for t, scale in zip(targets, scales, strict=True):
        cand = candidate_table(t, cfg)
        states.append(_Search(t, float(scale), cand, torch.ones(cand[0].shape[0], dtype=torch.bool), [], [], []))
    search = replace(getattr(solver, "refine", DEFAULT_REFINEMENT), iterations=cfg.search_refine_steps)
    steps = min(cfg.max_effectors, min((s.cand[0].shape[0] for s in states), default=0))
    for k in range(steps):
        active = [s for s in states if not s.done]
        if not active:
            break
        parts, rows_of = [], []
        for st in active:
            cand_joint, cand_type, cand_data = st.cand
            rows = torch.nonzero(st.remaining)[:, 0]
            B = rows.shape[0]
            sel = torch.tensor(st.chosen, dtype=torch.long)
            parts.append((torch.cat([cand_joint[sel].expand(B, k), cand_joint[rows, None]], 1),
                          torch.cat([cand_type[sel].expand(B, k), cand_type[rows, None]], 1),
                          torch.cat([cand_data[sel].expand(B, k, 6), cand_data[rows, None]], 1)))
            rows_of.append(rows)
        joint, kind, data = (torch.cat([p[i] for p in parts]) for i in range(3))
        sizes = [r.shape[0] for r in rows_of]
        betas = torch.cat([st.target.betas.float().reshape(1, NUM_BETAS).expand(n, NUM_BETAS)
                           for st, n in zip(active, sizes, strict=True)])
        gender = torch.cat([torch.full((n,), st.target.gender.index) for st, n in zip(active, sizes, strict=True)])
        eff = EffectorBatch(joint, kind, data, torch.full(joint.shape, float(cfg.tolerance)),
                            torch.ones(joint.shape, dtype=torch.bool))
        out = solver.solve_tensors(eff, betas, gender, refine=search)
        start = 0
        for st, rows, n in zip(active, rows_of, sizes, strict=True):
            sl = slice(start, start + n)
            start += n
            joint_err = (out.p_world[sl].float() - st.target.p_world.float()).norm(dim=-1)  # (n, 24), SMPL space
            score = recovery_score(joint_err, cfg.criterion) * st.scale
            err = joint_err.mean(-1) * st.scale
            best = int(torch.argmin(score))
            if st.scores and float(score[best]) >= st.scores[-1]:
                st.done = True  # no candidate improves on the current set
                continue
            st.chosen.append(int(rows[best]))
            st.remaining[rows[best]] = False
            st.errors.append(float(err[best]))
            st.scores.append(float(score[best]))
            b = sl.start + best
            st.best_eff = EffectorBatch(joint[b:b + 1], kind[b:b + 1], data[b:b + 1], eff.tolerance[b:b + 1],
                                        eff.mask[b:b + 1])
            st.done = st.errors[-1] < cfg.threshold
        if progress is not None:
            progress(k + 1, steps)
    return _finish(solver, states, cfg)


def _finish(solver: TensorSolver, states: list[_Search], cfg: RecoveryConfig) -> list[RecoveryResult]:
    """Final solves with the solver's full refinement, batched per effector count: the pose that re-solving
    the recovered effectors gives (a scene's stored pose is what ``smplik scene solve`` reproduces)."""
    results: list[RecoveryResult | None] = [None] * len(states)
    by_count: dict[int, list[int]] = {}
    for i, st in enumerate(states):
        assert st.best_eff is not None
        by_count.setdefault(len(st.chosen), []).append(i)
    for group in by_count.values():
        effs = [states[i].best_eff for i in group]
        eff = EffectorBatch(*(torch.cat([getattr(e, f) for e in effs]) for f in  # type: ignore[union-attr]
                              ("joint", "type", "data", "tolerance", "mask")))
        betas = torch.stack([states[i].target.betas.float().reshape(NUM_BETAS) for i in group])
        gender = torch.tensor([states[i].target.gender.index for i in group])
        final = solver.solve_tensors(eff, betas, gender)
        for row, i in enumerate(group):
            st = states[i]
            cand_joint, cand_type, cand_data = st.cand
            effectors = tuple(_to_effector(int(cand_joint[c]), int(cand_type[c]), cand_data[c].double().numpy(),
                                           st.scale, cfg.tolerance) for c in st.chosen)
            joint_err = (final.p_world[row].float() - st.target.p_world.float()).norm(dim=-1)
            final_error = float(joint_err.mean()) * st.scale
            pose = output_to_pose(final, row, st.target.betas, st.target.gender)
            results[i] = RecoveryResult(effectors, tuple(st.errors), pose, st.scale, final_error)  # type: ignore[arg-type]
    return results  # type: ignore[return-value]
