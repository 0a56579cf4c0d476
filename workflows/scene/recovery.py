"""Effector recovery (smpl-ik.txt section 5, App. D): a few effectors that reproduce a full pose.

Greedy: start from no effector; at each step try every remaining candidate ``(joint, type)`` added
to the current set, all candidates in **one** batched solve (row ``b`` = current set + candidate
``b``); keep the candidate whose solved pose has the lowest mean per-joint L2 error to the target
in character space; stop at ``max_effectors`` or once the error is below ``threshold``.

The search never gives up above the threshold while effectors remain. A learned solver can sit in a
local minimum where every single extra effector makes the pose worse (on a real GVHMR squat, spine1 and
neck positions at 96 mm, every third effector above 100 mm, while the 6-point set reaches 20 mm), so:

1. **pairs**: when no single candidate lowers the error, every pair of remaining candidates is tried
   (one batched solve) and the best pair is kept if it lowers the error (its first member's error is
   the one it had as a single);
2. **force**: if no pair helps either, the least harmful single is added and the search goes on.

A full path (``max_effectors``) still above the threshold **and** above ``polish_above`` (3 cm: a hard pose;
most poses end below it and cost no more than the greedy search) is escalated. On hard poses the cheap
solve that scores candidates (one refinement step) ranks them differently from the full refinement that
gives the final pose (an AIST++ dance frame: 44 mm scored, 41 mm final, where the same search scored with
the full refinement ends at 24 mm), so every later stage is scored with the solver's own refinement:

3. **search again**: the path is set aside and the greedy search (pairs and forced steps included) runs
   again from no effector;
4. **restart**: if that path is still above ``polish_above`` (and ``max_effectors`` >= 6), it is set aside
   too and the search starts again from the dense :data:`RESTART_SET` (all its prefixes scored in one
   round), continuing by the same rules;
5. **swaps**: the closest of the escalated paths is polished by up to :data:`SWAP_ROUNDS` swaps, each the
   best replacement of one effector by another candidate (all in one batched solve) when it lowers the
   error; the new one goes last and the path's per-count errors are scored again.

Of the full paths (the cheap one, the escalated ones, before and after swaps), the result is the one whose
re-solved pose (the final solve below) is closest. So the result holds ``max_effectors`` effectors unless
the threshold was reached. ``errors`` decrease strictly along a path except after a forced step, along the
restart set's prefixes and after swaps. On every frame of four real GVHMR tracks and an AIST++ dance
(``benchmarks/estimator_recovery.py``) the plain greedy search left squat frames at 72-96 mm with 2
effectors; with these steps no frame is above 40 mm with 8 (docs/estimators.md has the figures).

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
from dataclasses import dataclass, field, replace
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

RESTART_SET = ("pelvis", "neck", "left_wrist", "right_wrist", "left_ankle", "right_ankle")
"""Where a stuck search restarts (position effectors, this order): the 6-point set of the IK benchmark
(DESIGN.md section 5), a dense set that pins every limb; truncated to ``max_effectors``."""

SWAP_ROUNDS = 3
"""At most this many swaps (one effector replaced by another candidate) polish a full path above the threshold."""


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
    polish: bool = True
    """Escalate a full path still above ``polish_above`` and the threshold (steps 3-5 of the module docstring);
    off keeps the plain greedy search (pairs and forced steps still run)."""
    polish_above: float = 0.03
    """Escalate only a full path whose search error (metres, character space) is above this: most poses end
    below it after the cheap greedy search and cost no more than it (0: escalate every path above the
    threshold)."""
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


SearchMode = Literal["single", "pair", "seed", "force", "swap", "rescore"]


@dataclass
class _Search:
    """One target's search state inside :func:`recover_many` (candidate indices into ``cand``)."""

    target: TargetPose
    scale: float
    cand: tuple[Tensor, Tensor, Tensor]
    chosen: list[int] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    mode: SearchMode = "single"
    singles: dict[int, tuple[float, float]] = field(default_factory=dict)
    """The last single step's (error, score) per candidate: a kept pair's first member reports its own."""
    stage: Literal["greedy", "research", "restart", "swap"] = "greedy"
    """Where the search is: the cheap greedy path, then (escalated) the greedy search again scored with the full
    refinement, the restart from :data:`RESTART_SET`, the swaps."""
    paths: list[tuple[list[int], list[float], list[float]]] = field(default_factory=list)
    """Full paths set aside (the cheap one, the re-search's, the restart's, the one before swaps):
    :func:`_finish` keeps the path whose re-solved pose is closest."""
    swaps_left: int = 0
    swapped: bool = False
    done: bool = False

    @property
    def full_refine(self) -> bool:
        """Scored with the solver's own (full) refinement: every stage after the cheap greedy path."""
        return self.stage != "greedy"


def _trial_sets(st: _Search, cfg: RecoveryConfig) -> list[Tensor]:
    """The candidate sets to score for ``st`` this round: a list of (B, width) long tensors of candidate indices."""
    n = st.cand[0].shape[0]
    chosen = torch.tensor(st.chosen, dtype=torch.long)
    taken = torch.zeros(n, dtype=torch.bool)
    taken[chosen] = True
    rest = torch.nonzero(~taken)[:, 0]
    if st.mode in ("seed", "rescore"):  # every prefix, one set per width
        seed = chosen if st.mode == "rescore" else torch.tensor(
            [JOINT_INDEX[name] for name in RESTART_SET[:cfg.max_effectors]])  # position rows
        return [seed[:m][None] for m in range(1, seed.shape[0] + 1)]
    if st.mode == "swap":  # every effector replaced by every remaining candidate (appended last)
        k = len(st.chosen)
        return [torch.cat([torch.cat([torch.cat([chosen[:i], chosen[i + 1:]]).expand(rest.shape[0], k - 1),
                                      rest[:, None]], 1) for i in range(k)])]
    if st.mode == "pair":
        pairs = torch.combinations(rest, 2)
        return [torch.cat([chosen.expand(pairs.shape[0], len(st.chosen)), pairs], 1)]
    return [torch.cat([chosen.expand(rest.shape[0], len(st.chosen)), rest[:, None]], 1)]


def _score_sets(solver: TensorSolver, states: Sequence[_Search], sets: Sequence[Tensor], cfg: RecoveryConfig,
                refine: RefineConfig | None) -> list[tuple[Tensor, Tensor]]:
    """Solve every trial set (``sets[i]`` belongs to ``states[i]``), one batched call per set width
    (``refine``: the search's cheap refinement, None for the solver's own).

    Returns per entry ``(score (B,), mean joint error (B,))`` in character space.
    """
    out: list[tuple[Tensor, Tensor] | None] = [None] * len(sets)
    widths = sorted({int(s.shape[1]) for s in sets})
    for width in widths:
        group = [i for i, s in enumerate(sets) if s.shape[1] == width]
        parts = [[states[i].cand[f][sets[i]] for f in range(3)] for i in group]
        joint, kind, data = (torch.cat([p[f] for p in parts]) for f in range(3))
        sizes = [sets[i].shape[0] for i in group]
        betas = torch.cat([states[i].target.betas.float().reshape(1, NUM_BETAS).expand(n, NUM_BETAS)
                           for i, n in zip(group, sizes, strict=True)])
        gender = torch.cat([torch.full((n,), states[i].target.gender.index) for i, n in zip(group, sizes, strict=True)])
        eff = EffectorBatch(joint, kind, data, torch.full(joint.shape, float(cfg.tolerance)),
                            torch.ones(joint.shape, dtype=torch.bool))
        solved = solver.solve_tensors(eff, betas, gender, refine=refine)
        start = 0
        for i, n in zip(group, sizes, strict=True):
            st = states[i]
            joint_err = (solved.p_world[start:start + n].float() - st.target.p_world.float()).norm(dim=-1)
            start += n
            out[i] = (recovery_score(joint_err, cfg.criterion) * st.scale, joint_err.mean(-1) * st.scale)
    return out  # type: ignore[return-value]


def _set_aside(st: _Search) -> None:
    """Keep the current full path for :func:`_finish` and start the next stage from no effector."""
    st.paths.append((list(st.chosen), list(st.errors), list(st.scores)))
    st.chosen, st.errors, st.scores, st.singles = [], [], [], {}


def _advance(st: _Search, sets: list[Tensor], scored: list[tuple[Tensor, Tensor]], cfg: RecoveryConfig) -> None:
    """Apply one round's scores to ``st`` (see the module docstring for the rules)."""
    if st.mode in ("seed", "rescore"):  # every prefix of the restart set / of the swapped path was scored
        st.chosen = [int(c) for c in sets[-1][0]]
        st.errors = [float(err[0]) for _, err in scored]
        st.scores = [float(score[0]) for score, _ in scored]
        if st.mode == "rescore":
            st.done = True
            return
        st.mode = "single"
    elif st.mode == "swap":
        (score, err), = scored
        best = int(torch.argmin(score))
        if float(score[best]) < st.scores[-1]:
            st.chosen = [int(c) for c in sets[0][best]]
            st.errors[-1], st.scores[-1] = float(err[best]), float(score[best])
            st.swapped, st.swaps_left = True, st.swaps_left - 1
            if st.swaps_left > 0 and st.errors[-1] >= cfg.threshold:
                return
        st.mode = "rescore"
        st.done = not st.swapped
        return
    else:
        (score, err), = scored
        best = int(torch.argmin(score))
        improves = not st.scores or float(score[best]) < st.scores[-1]
        row = sets[0][best]
        if st.mode == "pair":
            if not improves:
                st.mode = "force"  # neither a single nor a pair helps: add the least harmful single
                return
            a, b = (int(c) for c in row[-2:])
            if st.singles.get(b, (0.0, np.inf))[1] < st.singles.get(a, (0.0, np.inf))[1]:
                a, b = b, a  # the better single first
            st.chosen += [a, b]
            st.errors += [st.singles[a][0] if a in st.singles else float(err[best]), float(err[best])]
            st.scores += [st.singles[a][1] if a in st.singles else float(score[best]), float(score[best])]
            st.mode = "single"
        elif improves or st.mode == "force":
            st.chosen.append(int(row[-1]))
            st.errors.append(float(err[best]))
            st.scores.append(float(score[best]))
            st.mode = "single"
        else:  # no single candidate lowers the error
            st.singles = {int(r[-1]): (float(e), float(s)) for r, e, s in zip(sets[0], err, score, strict=True)}
            st.mode = "pair" if len(st.chosen) + 2 <= cfg.max_effectors else "force"
            return
    if st.errors[-1] < cfg.threshold:
        st.done = True
    elif len(st.chosen) >= cfg.max_effectors:
        _full(st, cfg)


def _full(st: _Search, cfg: RecoveryConfig) -> None:
    """A path holds ``max_effectors`` but is above the threshold: escalate (module docstring, steps 3-5) while
    it is above ``polish_above``; the next stage starts, or the search ends."""
    if not cfg.polish or st.errors[-1] < cfg.polish_above:
        st.done = True
        return
    if st.stage == "greedy":
        _set_aside(st)
        st.stage, st.mode = "research", "single"
        return
    if st.stage == "research" and len(st.chosen) >= len(RESTART_SET):
        _set_aside(st)
        st.stage, st.mode = "restart", "seed"
        return
    # swaps polish the closest of the paths scored with the full refinement (the cheap path's scores differ)
    st.paths.append((list(st.chosen), list(st.errors), list(st.scores)))
    comparable = st.paths[1:] if len(st.paths) > 1 else st.paths
    st.chosen, st.errors, st.scores = (list(x) for x in min(comparable, key=lambda p: p[2][-1]))
    st.stage, st.mode, st.swaps_left = "swap", "swap", SWAP_ROUNDS


@torch.inference_mode()
def recover_many(solver: TensorSolver, targets: Sequence[TargetPose], cfg: RecoveryConfig = RecoveryConfig(), *,
                 scales: Sequence[float] | None = None,
                 progress: Callable[[int, int], None] | None = None) -> list[RecoveryResult]:
    """Effector recovery of several poses at once (many people / frames): each round solves the trial
    sets of every unfinished pose in one batched call per set width; the final solves are batched per count.

    Args:
        targets: poses to reproduce (SMPL space); scales: their character scales (default 1).
        progress: ``progress(round, max_effectors)`` after each search round (capped at ``max_effectors``).

    Returns: one :class:`RecoveryResult` per target, the same as :func:`recover_effectors` on each.
    """
    if cfg.max_effectors < 1:
        raise ValueError(f"max_effectors must be >= 1, got {cfg.max_effectors}.")
    if cfg.search_refine_steps < 0:
        raise ValueError(f"search_refine_steps must be >= 0, got {cfg.search_refine_steps}.")
    if not cfg.polish_above >= 0:
        raise ValueError(f"polish_above must be >= 0 metres, got {cfg.polish_above}.")
    scales = [1.0] * len(targets) if scales is None else list(scales)
    if len(scales) != len(targets):
        raise ValueError(f"{len(targets)} targets but {len(scales)} scales.")
    for scale in scales:
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}.")
    states = [_Search(t, float(s), candidate_table(t, cfg)) for t, s in zip(targets, scales, strict=True)]
    limit = min(cfg.max_effectors, min((s.cand[0].shape[0] for s in states), default=0))
    cfg = replace(cfg, max_effectors=limit)
    search = replace(getattr(solver, "refine", DEFAULT_REFINEMENT), iterations=cfg.search_refine_steps)
    for round_ in range(24 * limit + 2 * SWAP_ROUNDS + 16):  # a round adds effectors or moves to another mode
        active = [s for s in states if not s.done]
        if not active:
            break
        for full in (False, True):  # the cheap greedy paths, then the escalated ones (the solver's refinement)
            group = [st for st in active if st.full_refine == full]
            if not group:
                continue
            trials = [_trial_sets(st, cfg) for st in group]
            flat_states = [st for st, sets in zip(group, trials, strict=True) for _ in sets]
            scored = _score_sets(solver, flat_states, [s for sets in trials for s in sets], cfg,
                                 None if full else search)
            start = 0
            for st, sets in zip(group, trials, strict=True):
                _advance(st, sets, scored[start:start + len(sets)], cfg)
                start += len(sets)
        if progress is not None:
            progress(min(round_ + 1, limit), limit)
    return _finish(solver, states, cfg)


def _finish(solver: TensorSolver, states: list[_Search], cfg: RecoveryConfig) -> list[RecoveryResult]:
    """Final solves with the solver's full refinement, batched per effector count: the pose that re-solving
    the recovered effectors gives (a scene's stored pose is what ``smplik scene solve`` reproduces).

    A target with several full paths (the first, the restart's, the swapped one) keeps the one whose
    re-solved pose is closest (the search scored them with its cheap solve, which can rank them otherwise).
    """
    entries: list[tuple[int, tuple[list[int], list[float], list[float]]]] = []
    for i, st in enumerate(states):
        if not st.chosen:  # cut off right after a path was set aside (the round cap): keep the paths
            st.chosen, st.errors, st.scores = (list(x) for x in st.paths[-1])
        current = (st.chosen, st.errors, st.scores)
        seen = {tuple(st.chosen)}
        entries.append((i, current))  # first: it wins ties
        for path in st.paths:
            if tuple(path[0]) not in seen:
                seen.add(tuple(path[0]))
                entries.append((i, path))
    by_count: dict[int, list[int]] = {}
    for e, (_, path) in enumerate(entries):
        by_count.setdefault(len(path[0]), []).append(e)
    best: dict[int, tuple[float, IKOutput, int, tuple[list[int], list[float], list[float]]]] = {}
    for group in by_count.values():
        joint, kind, data = (torch.stack([states[entries[e][0]].cand[f][torch.tensor(entries[e][1][0])]
                                          for e in group]) for f in range(3))
        eff = EffectorBatch(joint, kind, data, torch.full(joint.shape, float(cfg.tolerance)),
                            torch.ones(joint.shape, dtype=torch.bool))
        betas = torch.stack([states[entries[e][0]].target.betas.float().reshape(NUM_BETAS) for e in group])
        gender = torch.tensor([states[entries[e][0]].target.gender.index for e in group])
        final = solver.solve_tensors(eff, betas, gender)
        for row, e in enumerate(group):
            i, path = entries[e]
            joint_err = (final.p_world[row].float() - states[i].target.p_world.float()).norm(dim=-1)
            score = float(recovery_score(joint_err, cfg.criterion))
            if i not in best or score < best[i][0]:
                best[i] = (score, final, row, path)
    results = []
    for i, st in enumerate(states):
        _, final, row, (chosen, errors, _) = best[i]
        cand_joint, cand_type, cand_data = st.cand
        effectors = tuple(_to_effector(int(cand_joint[c]), int(cand_type[c]), cand_data[c].double().numpy(),
                                       st.scale, cfg.tolerance) for c in chosen)
        joint_err = (final.p_world[row].float() - st.target.p_world.float()).norm(dim=-1)
        pose = output_to_pose(final, row, st.target.betas, st.target.gender)
        results.append(RecoveryResult(effectors, tuple(errors), pose, st.scale, float(joint_err.mean()) * st.scale))
    return results
