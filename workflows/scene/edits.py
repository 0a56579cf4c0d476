"""Edits that do not fight the user: stale effectors on a dragged chain, and the conflict report.

Effectors recovered from an estimate (:mod:`workflows.scene.recovery`) are exact and several may sit on one limb
(a wrist position plus the elbow's and shoulder's rotations). Once the user drags one of them, the others
contradict it: the elbow rotation still asks for the old forearm direction, so the solver meets all of
them as well as it can by bending everything else (the torso tips, the head drops).

**Relaxing the dragged chain.** When an effector is moved, the effectors that its move makes stale
(:func:`stale_effectors`) get the tolerance :data:`RELAXED_TOLERANCE`: they stay in the scene as loose
hints (the network still reads them, the refinement weighs them about 1 %), so the limb keeps its style
while the dragged effector is met. The rule follows the kinematic chain within the moved joint's limb
(:data:`~smplik.conventions.LIMB_CHAINS`; the spine-neck-head chain for torso joints):

* a moved **position** on joint ``j`` makes stale every other effector of the chain: the other position
  effectors (the elbow's, the hand's, an older one of ``j`` itself), the rotation and look-at effectors of
  ``j``'s ancestors (the collar's, shoulder's and elbow's rotations fix where ``j`` can be) and those of ``j``
  and its descendants
  (in real reaches the hand turns with the forearm: keeping the old hand orientation exact made the edit
  benchmark's validation edits worse, docs/editing.md);
* a moved **rotation** or **look-at** on ``j`` makes stale the position effectors of ``j``'s descendants
  in the chain (they move with it) and ``j``'s own effector of the other orientation type.

Effectors outside the chain are kept: they hold the rest of the body. The benchmark behind these choices is
``benchmarks/edit_benchmark.py`` (``docs/editing.md``).

**Solving a drag** (:func:`solve_edit`): a dragged wrist or ankle is posed by the analytic two-bone IK of its
limb on the pose the drag started from, its elbow or knee swivel turned most of the way to the learned
prior's; everything outside the limb stays put unless an exact effector needs it. A dragged elbow, knee, head,
neck, spine joint or pelvis is the local chain solve of :mod:`smplik.chain_drag` (:func:`solve_chain_drag`).

**Scripted edits** (:func:`solve_scripted`): a script that changes effectors (in ``scene.json``, an animation's
keyframe) gets the same drag. The effectors the stored pose does not meet (beyond their :func:`allowance`) are
the moved ones; each relaxes its chain's stale effectors and they are solved one after the other by
:func:`solve_edit` from the stored pose (``smplik scene solve``: :func:`solve_scene_edits`; Python:
:func:`drag_scene_effector`, ``Scene.drag``; ``smplik scene edit-keyframe``:
:func:`workflows.animation.keyframe_edit.keyframe_edit`).

**Conflict report** (:func:`conflict_report`): per effector, its residual after the solve, what its tolerance
allows, and the effectors it contradicts: those whose removal (one batched leave-one-out solve) brings its
residual within the allowance or halves it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, JOINT_NAMES, LIMB_CHAINS, PARENTS, EffectorType
from smplik.effectors import Effector
from smplik.pose import Pose

RELAXED_TOLERANCE = 1.0
"""Tolerance given to the effectors an edit makes stale (1: a loose hint; see the module docstring)."""
HOLD_PRIOR = 100.0
"""How much harder than the solver's own prior the refinement of a drag holds the joints outside the dragged
chain at their previous rotations (:func:`solve_edit`)."""
TORSO_CHAIN: tuple[str, ...] = ("spine1", "spine2", "spine3", "neck", "head")
"""The chain of torso joints (the pelvis, the root, is in no chain)."""
POSITION_ALLOWANCE_MM = 10.0
"""Residual of an exact position effector that counts as met."""
ANGLE_ALLOWANCE_DEG = 5.0
"""Residual of an exact rotation or look-at effector that counts as met."""
STRAIN_MM = 100.0
"""An exact position effector the network alone misses by more than this is *forced* (see :func:`strain_limit`)."""
STRAIN_DEG = 30.0
"""The same for rotation and look-at effectors (degrees)."""
_SIGMA_MAX, _ETA = 0.1, 13.0  # the training sampler's noise at tolerance t: sigma_M t^eta (m or rad)


def chain_of(joint: int) -> tuple[int, ...]:
    """The joints of ``joint``'s limb chain (:data:`~smplik.conventions.LIMB_CHAINS`, or :data:`TORSO_CHAIN`);
    empty for the pelvis."""
    name = JOINT_NAMES[joint]
    for chain in (*LIMB_CHAINS.values(), TORSO_CHAIN):
        if name in chain:
            return tuple(JOINT_INDEX[n] for n in chain)
    return ()


@cache
def _ancestors(j: int) -> frozenset[int]:
    """The strict ancestors of joint ``j``."""
    return frozenset() if PARENTS[j] < 0 else _ancestors(PARENTS[j]) | {PARENTS[j]}


def _is_ancestor(a: int, j: int) -> bool:
    """``a`` is a strict ancestor of ``j``."""
    return a in _ancestors(j)


def stale_effectors(effectors: Sequence[Effector], moved: int) -> tuple[int, ...]:
    """Indices of the effectors that moving ``effectors[moved]`` makes stale (module docstring rule)."""
    if not 0 <= moved < len(effectors):
        raise IndexError(f"No effector {moved}: there are {len(effectors)}.")
    m = effectors[moved]
    chain = set(chain_of(m.joint))
    out = []
    for i, e in enumerate(effectors):
        if i == moved or e.joint not in chain:
            continue
        if m.type == EffectorType.POSITION:
            stale = True  # every other effector of the chain (another position of the same joint included)
        else:
            stale = (e.type == EffectorType.POSITION and _is_ancestor(m.joint, e.joint)) or (
                e.joint == m.joint and e.type not in (EffectorType.POSITION, m.type))
        if stale:
            out.append(i)
    return tuple(out)


def relax_stale(effectors: Sequence[Effector], moved: int, *,
                tolerance: float | None = RELAXED_TOLERANCE) -> tuple[tuple[Effector, ...], tuple[int, ...]]:
    """The effectors with those made stale by moving ``effectors[moved]`` relaxed, and their indices.

    ``tolerance``: the relaxed effectors' tolerance (never lowered); None drops them instead (the returned
    indices are then those of the input list).
    """
    stale = stale_effectors(effectors, moved)
    if tolerance is None:
        return tuple(e for i, e in enumerate(effectors) if i not in stale), stale
    changed = tuple(i for i in stale if effectors[i].tolerance < tolerance)
    out = tuple(dataclasses.replace(e, tolerance=float(tolerance)) if i in changed else e
                for i, e in enumerate(effectors))
    return out, changed


def drag_effector(effectors: Sequence[Effector], new: Effector, *,
                  tolerance: float | None = RELAXED_TOLERANCE) -> tuple[tuple[Effector, ...], int, tuple[int, ...]]:
    """A user's drag of ``new``'s joint: replace the effector of the same joint and type (else append ``new``)
    and relax the effectors it makes stale.

    Returns: (effectors, index of ``new``, relaxed indices); with ``tolerance=None`` stale effectors are
    dropped and the indices refer to the returned list for ``new`` and to the input list for the dropped.
    """
    effectors = tuple(effectors)
    k = next((i for i, e in enumerate(effectors) if e.joint == new.joint and e.type == new.type), None)
    if k is None:
        effectors, k = effectors + (new,), len(effectors)
    else:
        effectors = effectors[:k] + (new,) + effectors[k + 1:]
    out, relaxed = relax_stale(effectors, k, tolerance=tolerance)
    if tolerance is None:
        k -= sum(1 for i in relaxed if i < k)
    return out, k, relaxed


# ----------------------------------------------------------------------------- solving a drag


HINGE_JOINTS: tuple[str, ...] = ("left_knee", "right_knee", "left_elbow", "right_elbow")
"""Joints that take no twist about their parent's bone: the training motion never turns a knee about the
thigh or an elbow about the upper arm (CMU: under 4 degrees); that turn belongs to the hip or shoulder."""


def hinge_twist_to_parent(R_local: Tensor, J_rest: Tensor, joints: Sequence[int]) -> Tensor:
    """Move each listed joint's rotation about its parent's bone axis into the parent.

    ``R_local[j] = T R'`` with ``T`` the twist about the bone ``a = J_rest[j] - J_rest[parent]`` (swing-twist
    decomposition by projecting the quaternion onto ``a``); the result has ``R_local[j] = R'`` and
    ``R_local[parent] = R_local[parent] T``. World rotations of ``j`` and its subtree and every joint position
    are unchanged (``T`` keeps the bone ``a``); only the parent's turn about its own bone changes.

    R_local (B, 24, 3, 3), J_rest (B, 24, 3) -> (B, 24, 3, 3). Joints whose parent is also listed are not
    supported (not needed for knees and elbows).
    """
    from smplik.rotations import matrix_to_quaternion, quaternion_to_matrix

    R_local = R_local.clone()
    for j in joints:
        par = PARENTS[j]
        a = J_rest[:, j] - J_rest[:, par]
        a = a / a.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # (B, 3)
        q = matrix_to_quaternion(R_local[:, j])  # (B, 4) w, x, y, z
        twist = torch.cat([q[:, :1], (q[:, 1:] * a).sum(-1, keepdim=True) * a], -1)
        norm = twist.norm(dim=-1, keepdim=True)
        twist = torch.where(norm > 1e-9, twist / norm.clamp_min(1e-12), torch.tensor([1.0, 0.0, 0.0, 0.0],
                                                                                     dtype=q.dtype))
        T = quaternion_to_matrix(twist)
        R_local[:, j] = T.transpose(-1, -2) @ R_local[:, j]
        R_local[:, par] = R_local[:, par] @ T
    return R_local


SWIVEL_SHARE = 0.75
"""Share of the turn from the scene's elbow/knee swivel to the prior's that an analytic drag takes
(:func:`solve_edit`; chosen on the validation split and unseen CMU dance, docs/editing.md)."""
TWO_BONE_ENDS: tuple[str, ...] = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")
"""Dragged joints whose limb :func:`solve_edit` poses analytically (shoulder-elbow-wrist, hip-knee-ankle)."""
NETWORK_SWIVEL_ENDS: tuple[str, ...] = ("left_wrist", "right_wrist")
"""Ends whose prior swivel is the network's alone (an arm's elbow); a leg's knee comes from the refined chain,
whose hip the refinement has placed (validation: knee off by less)."""


def _refine_held(solver: Any, eff: Any, chain: Tensor, start: Any, J_rest: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Refine B starting poses towards their effectors, the joints outside each row's ``chain`` (B, 24) bool held
    :data:`HOLD_PRIOR` times harder; knee/elbow twist then handed to the parent (:func:`hinge_twist_to_parent`).

    Returns float64 (B, 24, 3, 3) local rotations, (B, 3) translations and (B, 24, 3) joints.
    """
    from smplik.network import IKOutput
    from smplik.refine import refine_output

    B = chain.shape[0]
    R_out = torch.zeros(B, len(PARENTS), 3, 3, dtype=torch.float64)
    transl_out = torch.zeros(B, 3, dtype=torch.float64)
    joints_out = torch.zeros(B, len(PARENTS), 3, dtype=torch.float64)
    base = solver.refine.joint_prior_array(len(PARENTS))
    for key in torch.unique(chain, dim=0):  # one refinement per chain: its own per-joint prior
        rows = torch.nonzero((chain == key).all(-1))[:, 0]
        prior = np.where(key.numpy(), base, base * HOLD_PRIOR)
        cfg = dataclasses.replace(solver.refine, joint_prior=tuple(prior.tolist()))
        out = refine_output(IKOutput(*(t[rows] for t in start)), J_rest[rows], _rows(eff, rows), cfg)
        hinges = [j for j in (JOINT_INDEX[n] for n in HINGE_JOINTS) if bool(key[j])]
        R_out[rows] = hinge_twist_to_parent(out.R_local.double(), J_rest[rows].double(), hinges)
        transl_out[rows] = out.transl.double()
        joints_out[rows] = out.p_world.double()
    return R_out, transl_out, joints_out


def _meets(solver: Any, effectors: Sequence[Effector], pose: Pose) -> bool:
    """Every effector of tolerance below :data:`RELAXED_TOLERANCE` is within its :func:`allowance` on ``pose``."""
    from smplik.solver import effector_residuals

    return all(r.value <= allowance(r.effector) for r in effector_residuals(pose, effectors, solver.bodies)
               if r.effector.tolerance < RELAXED_TOLERANCE)


def chain_drag_target(effectors: Sequence[Effector], joint: int) -> np.ndarray | None:
    """The target of a chain drag (:mod:`smplik.chain_drag`): the exact position effector (tolerance below
    :data:`RELAXED_TOLERANCE`) of a dragged joint that :func:`smplik.chain_drag.drag_joint` solves (elbows, knees,
    head, neck, spine, pelvis), else None."""
    from smplik.chain_drag import DRAG_JOINTS

    if JOINT_NAMES[int(joint)] not in DRAG_JOINTS:
        return None
    pos = [e for e in effectors if e.joint == int(joint) and e.type == EffectorType.POSITION
           and e.tolerance < RELAXED_TOLERANCE]
    return np.asarray(pos[-1].value, np.float64) if pos else None


def held_positions(effectors: Sequence[Effector], joint: int) -> list[tuple[int, np.ndarray]]:
    """(joint, position) of the exact position effectors (tolerance below :data:`RELAXED_TOLERANCE`) on joints
    other than ``joint``: what a chain drag keeps."""
    return [(e.joint, np.asarray(e.value, np.float64)) for e in effectors
            if e.type == EffectorType.POSITION and e.tolerance < RELAXED_TOLERANCE and e.joint != int(joint)]


def solve_chain_drag(solver: Any, effectors: Sequence[Effector], previous: Pose, joint: int, *,
                     keep_held: bool = True) -> Pose:
    """A drag of an elbow, knee, the head, neck, a spine joint or the pelvis (SMPL space): the local solve of
    :func:`smplik.chain_drag.drag_joint` from ``previous`` (no network), keeping the exact position effectors of
    other joints (``keep_held=False``: ignoring them, to see which ones pull against the target)."""
    from scipy.spatial.transform import Rotation

    from smplik.chain_drag import drag_joint

    target = chain_drag_target(effectors, joint)
    if target is None:
        raise ValueError(f"No exact position effector on {JOINT_NAMES[int(joint)]} to drag.")
    betas = torch.as_tensor(np.asarray(previous.betas, np.float64))
    J_rest = solver.bodies[previous.gender].rest_joints(betas).double().numpy()
    aa = np.concatenate([np.asarray(previous.global_orient)[None], np.asarray(previous.body_pose)])
    held = held_positions(effectors, joint) if keep_held else []
    result = drag_joint(Rotation.from_rotvec(aa).as_matrix(), np.asarray(previous.transl, np.float64), J_rest,
                        int(joint), target, held_positions=held)
    out = Rotation.from_matrix(result.R_local).as_rotvec()
    return Pose(out[0], out[1:], result.transl, np.asarray(previous.betas, np.float64), previous.gender,
                result.p_world)


def solve_edit(solver: Any, effector_lists: Sequence[Sequence[Effector]], previous: Sequence[Pose],
               moved_joints: Sequence[int], *, analytic: bool = True) -> list[Pose]:
    """Solve B drags (SMPL space) so that only the dragged chain changes (see :func:`solve_limb_edit`); with
    ``analytic``, a position drag of an elbow, knee, the head, neck, a spine joint or the pelvis is the local
    chain solve :func:`solve_chain_drag` instead (:mod:`smplik.chain_drag`)."""
    B = len(effector_lists)
    if not len(previous) == len(moved_joints) == B:
        raise ValueError(f"{B} effector lists, {len(previous)} previous poses, {len(moved_joints)} moved joints.")
    chain_rows = [b for b in range(B) if analytic and chain_drag_target(effector_lists[b], moved_joints[b])
                  is not None]
    out: list[Pose | None] = [None] * B
    for b in chain_rows:
        out[b] = solve_chain_drag(solver, effector_lists[b], previous[b], int(moved_joints[b]))
    rest = [b for b in range(B) if b not in chain_rows]
    if rest:
        solved = solve_limb_edit(solver, [effector_lists[b] for b in rest], [previous[b] for b in rest],
                                 [moved_joints[b] for b in rest], analytic=analytic)
        for b, pose in zip(rest, solved, strict=True):
            out[b] = pose
    return [p for p in out if p is not None]


def solve_limb_edit(solver: Any, effector_lists: Sequence[Sequence[Effector]], previous: Sequence[Pose],
                    moved_joints: Sequence[int], *, analytic: bool = True) -> list[Pose]:
    """Solve B drags (SMPL space) so that only the dragged chain changes, posed the way the prior finds natural.

    Per row, first the *prior's chain*: the network solves the (relaxed) effectors; its local rotations of the
    moved joint's chain (:func:`chain_of`) above the moved joint are put on the ``previous`` pose (every other
    local rotation, the moved joint's own and its subtree's included, and the translation kept), and the
    solver's refinement (:mod:`smplik.refine`, anchored to that pose, the joints outside the chain held
    :data:`HOLD_PRIOR` times harder) meets the effectors; a knee's or elbow's turn about its parent bone then
    moves to the hip or shoulder (:func:`hinge_twist_to_parent`).

    A dragged wrist or ankle position (:data:`TWO_BONE_ENDS`) is then posed analytically on the ``previous``
    pose: the two-bone IK of shoulder-elbow-wrist or hip-knee-ankle
    (:func:`smplik.limb_ik.two_bone_ik_pose`) reaches the target exactly with the fewest joints changed,
    and its swivel (the elbow or knee pole) turns :data:`SWIVEL_SHARE` of the way to the prior's (the network's
    elbow, :data:`NETWORK_SWIVEL_ENDS`, or the prior chain's knee). Every joint outside the limb, the collar
    included, stays exactly where the user left it. Only when that pose misses an effector the user still
    holds exactly (the target out of reach, a kept wrist rotation) does the held refinement start from it,
    so the collar, spine or root take a share only when the edit needs them. A moved joint in no chain
    (the pelvis) solves as :meth:`~smplik.solver.IKSolver.solve_batch` does (:func:`solve_edit` solves a
    pelvis position drag with :mod:`smplik.chain_drag` instead).

    Args:
        solver: an :class:`smplik.solver.IKSolver`.
        effector_lists: B effector lists (SMPL space, after the drag).
        previous: B poses before the drag (same betas and gender as the rows are solved with).
        moved_joints: B joint indices, the dragged effectors' joints.
        analytic: False: the prior's chain only (the previous release's drag; the edit benchmark compares).
    """
    from smplik.effectors import pack_effectors
    from smplik.kinematics import forward_kinematics
    from smplik.limb_ik import swivel_angle, turn_swivel, two_bone_ik_pose
    from smplik.refine import NO_REFINEMENT
    from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle

    B = len(effector_lists)
    if not len(previous) == len(moved_joints) == B:
        raise ValueError(f"{B} effector lists, {len(previous)} previous poses, {len(moved_joints)} moved joints.")
    eff = pack_effectors([list(e) for e in effector_lists])
    betas = torch.from_numpy(np.stack([np.asarray(p.betas, np.float32) for p in previous]))
    gender = torch.tensor([p.gender.index for p in previous])
    with torch.inference_mode():
        net = solver.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT)
        aa_prev = torch.from_numpy(np.stack([np.concatenate([p.global_orient[None], p.body_pose])
                                             for p in previous])).float()
        transl_prev = torch.from_numpy(np.stack([np.asarray(p.transl) for p in previous])).float()
        chain = torch.zeros(B, len(PARENTS), dtype=torch.bool)
        for b, j in enumerate(moved_joints):
            joints = chain_of(int(j))
            chain[b, list(joints) if joints else slice(None)] = True
        keep_all = chain.all(-1)
        take = chain.clone()  # the network's rotations: the chain above the moved joint
        for b, j in enumerate(moved_joints):
            if not keep_all[b]:  # the moved joint and its subtree keep their local rotations (a hand its wrist's)
                take[b, [k for k in range(len(PARENTS)) if k == j or _is_ancestor(int(j), k)]] = False
        R_local = torch.where(take[..., None, None], net.R_local.float(), axis_angle_to_matrix(aa_prev))
        transl = torch.where(keep_all[:, None], net.transl.float(), transl_prev)
        J_rest = solver.model.rest_joints(betas, gender)
        R_world, p_world = forward_kinematics(R_local, J_rest, transl)
        R_out, transl_out, joints_out = _refine_held(solver, eff, chain, (R_local, R_world, p_world, net.draft,
                                                                          transl), J_rest)
        # the analytic limb: rows whose dragged wrist/ankle holds an exact position
        targets = torch.zeros(B, 3, dtype=torch.float64)
        two_bone = torch.zeros(B, dtype=torch.bool)
        for b, (effs, j) in enumerate(zip(effector_lists, moved_joints, strict=True)):
            pos = [e for e in effs if e.joint == int(j) and e.type == EffectorType.POSITION
                   and e.tolerance < RELAXED_TOLERANCE]
            if JOINT_NAMES[int(j)] in TWO_BONE_ENDS and pos:
                two_bone[b], targets[b] = True, torch.as_tensor(np.asarray(pos[0].value, np.float64))
        if analytic and two_bone.any():
            rows = torch.nonzero(two_bone)[:, 0]
            tip = torch.tensor([int(moved_joints[b]) for b in rows.tolist()])
            par = torch.tensor(PARENTS)
            mid, root = par[tip], par[par[tip]]
            J64, R_prev = J_rest[rows].double(), axis_angle_to_matrix(aa_prev[rows].double())
            t_prev = transl_prev[rows].double()
            R_seed = two_bone_ik_pose(R_prev, t_prev, J64, tip, targets[rows])
            _, p_seed = forward_kinematics(R_seed, J64, t_prev)
            arm = torch.tensor([JOINT_NAMES[int(t)] in NETWORK_SWIVEL_ENDS for t in tip.tolist()])
            p_ref = torch.where(arm[:, None, None], net.p_world[rows].double(), joints_out[rows])
            k = torch.arange(len(rows))
            angle = swivel_angle(p_seed[k, root], p_seed[k, mid], targets[rows], p_ref[k, root], p_ref[k, mid])
            R_seed = turn_swivel(R_seed, t_prev, J64, tip, targets[rows], SWIVEL_SHARE * angle)
            # an orientation the user holds on the end or below it (a hand's, a foot's): the end keeps its world
            # rotation instead of following the forearm or shin
            Rw_prev, _ = forward_kinematics(R_prev, J64, t_prev)
            Rw_seed, _ = forward_kinematics(R_seed, J64, t_prev)
            for i, b in enumerate(rows.tolist()):
                t = int(tip[i])
                if any(e.type != EffectorType.POSITION and e.tolerance < RELAXED_TOLERANCE
                       and (e.joint == t or _is_ancestor(t, e.joint)) for e in effector_lists[b]):
                    R_seed[i, t] = Rw_seed[i, int(mid[i])].transpose(-1, -2) @ Rw_prev[i, t]
            # the analytic bend turns the elbow/knee about the chain's plane, which can twist it about the
            # upper arm or thigh: that twist goes to the shoulder or hip (positions and world rotations kept)
            for m in torch.unique(mid).tolist():
                sel = mid == m
                R_seed[sel] = hinge_twist_to_parent(R_seed[sel], J64[sel], [m])
            Rw_seed, p_seed = forward_kinematics(R_seed, J64, t_prev)
            aa_seed = matrix_to_axis_angle(R_seed).numpy()
            ok = torch.tensor([_meets(solver, effector_lists[b], Pose(
                aa_seed[i, 0], aa_seed[i, 1:], t_prev[i].numpy(), np.asarray(previous[b].betas, np.float64),
                previous[b].gender)) for i, b in enumerate(rows.tolist())])
            if (~ok).any():  # out of reach or a kept effector missed: the held refinement from the analytic pose
                bad = rows[~ok]
                start = (R_seed[~ok].float(), Rw_seed[~ok].float(), p_seed[~ok].float(), net.draft[bad],
                         t_prev[~ok].float())
                R_fix, t_fix, p_fix = _refine_held(solver, _rows(eff, bad), chain[bad], start, J_rest[bad])
                R_seed[~ok], t_prev[~ok], p_seed[~ok] = R_fix, t_fix, p_fix
            R_out[rows], transl_out[rows], joints_out[rows] = R_seed, t_prev, p_seed
        aa = matrix_to_axis_angle(R_out).numpy()
    transl_np, joints_np = transl_out.numpy(), joints_out.numpy()
    return [Pose(aa[b, 0], aa[b, 1:], transl_np[b], np.asarray(p.betas, np.float64), p.gender, joints_np[b])
            for b, p in enumerate(previous)]


def _rows(eff: Any, rows: Tensor) -> Any:
    """The ``rows`` of an :class:`~smplik.effectors.EffectorBatch`."""
    from smplik.effectors import EffectorBatch

    return EffectorBatch(*(getattr(eff, f)[rows] for f in ("joint", "type", "data", "tolerance", "mask")))


def solve_drag(character: Any, solver: Any, moved: int, previous: Pose | None = None) -> Any:
    """Re-solve a scene character after a drag of its effector ``moved`` (:func:`solve_edit`, character
    space handled as :func:`workflows.scene.solve_character` does); ``previous``: the pose before the drag
    (default: the character's stored pose; without one, a plain :func:`~workflows.scene.solve_character`)."""
    from workflows.scene.characters import scale_effector, solve_character

    previous = character.pose if previous is None else previous
    if previous is None or not character.effectors:
        return solve_character(character, solver)
    previous = dataclasses.replace(previous, betas=np.asarray(character.betas, np.float64), gender=character.gender,
                                   joints=None)
    effectors = [scale_effector(e, 1.0 / character.scale) for e in character.effectors]
    pose = solve_edit(solver, [effectors], [previous], [character.effectors[moved].joint])[0]
    return dataclasses.replace(character, pose=pose)


# ----------------------------------------------------------------------------- scripted edits


@dataclass(frozen=True)
class ScriptedEdit:
    """What a scripted edit of one character did (:func:`solve_scripted`), for one printed line.

    Attributes:
        character: the character's (or track's) name.
        effectors: the effectors after the edit (character space; the relaxed ones with tolerance raised).
        moved: indices (into ``effectors``) of the effectors solved as drags, in the order they were solved.
        distances: per moved effector, how far the pose before the edit was from it (mm or degrees, character
            space).
        relaxed: indices of the effectors whose tolerance the drags raised (:func:`relax_stale`).
        mode: ``"drag"`` (the moved effectors solved as drags from the previous pose), ``"kept"`` (every effector
            met by the previous pose: the pose is kept), ``"exact"`` (every effector re-solved exactly: asked for,
            or no previous pose).
    """

    character: str
    effectors: tuple[Effector, ...]
    moved: tuple[int, ...] = ()
    distances: tuple[float, ...] = ()
    relaxed: tuple[int, ...] = ()
    mode: str = "drag"

    def _names(self, indices: Sequence[int]) -> str:
        return ", ".join(f"{self.effectors[i].joint_name} {self.effectors[i].type.name.lower()}" for i in indices)

    def line(self) -> str:
        """One line: what was moved (and how far), what it relaxed, or why nothing was dragged."""
        if self.mode == "exact":
            return f"{self.character}: re-solved exactly from its {len(self.effectors)} effectors"
        if self.mode == "kept":
            return (f"{self.character}: every effector is met by the stored pose (within {POSITION_ALLOWANCE_MM:g} "
                    f"mm / {ANGLE_ALLOWANCE_DEG:g} deg); pose kept")
        units = ["mm" if self.effectors[i].type == EffectorType.POSITION else "deg" for i in self.moved]
        moved = ", ".join(f"{self._names([i])} ({d:.0f} {u} from the stored pose)"
                          for i, d, u in zip(self.moved, self.distances, units, strict=True))
        relaxed = self._names(self.relaxed) or "nothing"
        return (f"{self.character}: moved {moved}, solved as a drag; relaxed (tolerance {RELAXED_TOLERANCE:g}): "
                f"{relaxed}")


def character_residuals(effectors: Sequence[Effector], pose: Pose, scale: float, bodies: Any) -> list[float]:
    """Each effector's residual (character space: mm or degrees) on ``pose`` (SMPL space) of a character
    scaled by ``scale``."""
    from smplik.solver import effector_residuals
    from workflows.scene.characters import scale_effector

    smpl = [scale_effector(e, 1.0 / scale) for e in effectors]
    return [r.value * (scale if r.effector.type == EffectorType.POSITION else 1.0)
            for r in effector_residuals(dataclasses.replace(pose, joints=None), smpl, bodies)]


def unmet_effectors(effectors: Sequence[Effector], pose: Pose, scale: float, bodies: Any, *,
                    among: Sequence[int] | None = None) -> list[tuple[int, float]]:
    """The effectors a stored pose does not meet: those (of ``among``, default all) held more tightly than a
    relaxed hint (tolerance below :data:`RELAXED_TOLERANCE`) whose residual on ``pose`` exceeds their
    :func:`allowance` (10 mm / 5 degrees for exact ones); as (index, residual) pairs in index order.

    The effectors a script changed since the pose was solved are among these; so is one the pose never met
    (a conflict the previous solve could not resolve)."""
    residuals = character_residuals(effectors, pose, scale, bodies)
    pick = range(len(effectors)) if among is None else sorted(set(among))
    return [(i, residuals[i]) for i in pick
            if effectors[i].tolerance < RELAXED_TOLERANCE and residuals[i] > allowance(effectors[i])]


def drag_order(effectors: Sequence[Effector], moved: Sequence[int]) -> list[int]:
    """The order in which several moved effectors are solved as drags: those on no chain (the pelvis: it
    carries the whole upper body) first, then the others as given."""
    return sorted(moved, key=lambda i: bool(chain_of(effectors[i].joint)))


def solve_scripted(solver: Any, name: str, effectors: Sequence[Effector], previous: Pose | None, *, scale: float,
                   betas: Any, gender: Any, moved: Sequence[int] | None = None, among: Sequence[int] | None = None,
                   exact: bool = False) -> tuple[Pose, ScriptedEdit]:
    """Solve a character whose effectors a script changed as the editor solves drags of them.

    ``moved`` (indices into ``effectors``): the effectors the script changed; default: those ``previous`` does
    not meet (:func:`unmet_effectors`, among the indices ``among``). Each moved effector relaxes the stale
    effectors of its chain (:func:`stale_effectors`; a moved effector is never relaxed), then the moved ones
    are solved one after the other as drags (:func:`solve_edit`, in :func:`drag_order`; the moved effectors not
    yet solved are left out of each step), starting from ``previous``. Nothing moved: ``previous`` is kept.
    ``exact`` or no ``previous``: every effector re-solved exactly (``solver.solve``), nothing relaxed.

    Args:
        solver: an :class:`smplik.solver.IKSolver`.
        name: the character's name (for the report line).
        effectors: character space (positions and look-at targets are divided by ``scale`` to solve).
        previous: the pose before the edit (SMPL space) or None.
        scale, betas, gender: the character's.

    Returns: (the solved pose, SMPL space; what was done, :class:`ScriptedEdit`).
    """
    from workflows.scene.characters import scale_effector

    effectors = tuple(effectors)
    if not effectors:
        raise ValueError(f"{name}: no effectors to solve.")
    betas = np.asarray(betas, np.float64)
    if exact or previous is None:
        smpl = [scale_effector(e, 1.0 / scale) for e in effectors]
        return solver.solve(smpl, betas=betas, gender=gender), ScriptedEdit(name, effectors, mode="exact")
    stored, previous = previous, dataclasses.replace(previous, betas=betas, gender=gender, joints=None)
    if moved is None:
        unmet = unmet_effectors(effectors, previous, scale, solver.bodies, among=among)
    else:
        residuals = character_residuals(effectors, previous, scale, solver.bodies)
        unmet = [(int(i), residuals[int(i)]) for i in moved]
    if not unmet:
        return stored, ScriptedEdit(name, effectors, mode="kept")
    distance = dict(unmet)
    order = drag_order(effectors, list(distance))
    relaxed: set[int] = set()
    current = effectors
    for k in order:
        stale = [i for i in stale_effectors(current, k)
                 if i not in distance and current[i].tolerance < RELAXED_TOLERANCE]
        current = tuple(dataclasses.replace(e, tolerance=RELAXED_TOLERANCE) if i in stale else e
                        for i, e in enumerate(current))
        relaxed.update(stale)
    pose = previous
    for step, k in enumerate(order):
        pending = set(order[step + 1:])
        keep = [i for i in range(len(current)) if i not in pending]
        smpl = [scale_effector(current[i], 1.0 / scale) for i in keep]
        pose = solve_edit(solver, [smpl], [pose], [current[k].joint])[0]
        pose = dataclasses.replace(pose, joints=None) if step + 1 < len(order) else pose
    report = ScriptedEdit(name, current, tuple(order), tuple(distance[k] for k in order), tuple(sorted(relaxed)))
    return pose, report


def solve_scene_edits(scene: Any, solver: Any, *, exact: bool = False, only: Sequence[str] | None = None
                      ) -> tuple[Any, list[ScriptedEdit]]:
    """``smplik scene solve``: every character (or those named in ``only``) with effectors solved by
    :func:`solve_scripted` (the effectors its stored pose does not meet, solved as drags; ``exact``: today's
    exact re-solve of all of them). Returns the new :class:`~workflows.scene.Scene` and one
    :class:`ScriptedEdit` per character solved."""
    chars, reports = [], []
    for c in scene.characters:
        if not c.effectors or (only is not None and c.name not in only):
            chars.append(c)
            continue
        pose, report = solve_scripted(solver, c.name, c.effectors, c.pose, scale=c.scale, betas=c.betas,
                                      gender=c.gender, exact=exact)
        chars.append(dataclasses.replace(c, effectors=report.effectors, pose=pose))
        reports.append(report)
    return dataclasses.replace(scene, characters=tuple(chars)), reports


def pulling_effectors(solver: Any, effectors: Sequence[Effector], previous: Pose, solved: Pose, moved: int, *,
                      scale: float = 1.0) -> tuple[int, ...]:
    """The effectors that actually pull against a drag of ``effectors[moved]`` (character space).

    Nothing when the drag met its target (within :func:`allowance`). Otherwise the drag is solved again from
    ``previous`` with the dragged effector alone (:func:`solve_chain_drag` without the held effectors, or
    :func:`solve_edit` of that one effector); the held effectors (tolerance below :data:`RELAXED_TOLERANCE`) whose
    residual then grows by more than their allowance over ``previous``'s are the ones that pull against it.
    ``solved``: the drag's pose; poses are SMPL space.
    """
    from workflows.scene.characters import scale_effector

    effectors = tuple(effectors)
    residual = character_residuals(effectors, solved, scale, solver.bodies)
    if residual[moved] <= allowance(effectors[moved]):
        return ()
    smpl = [scale_effector(e, 1.0 / scale) for e in effectors]
    joint = effectors[moved].joint
    previous = dataclasses.replace(previous, joints=None)
    if chain_drag_target(smpl, joint) is not None:
        alone = solve_chain_drag(solver, smpl, previous, joint, keep_held=False)
    else:
        alone = solve_edit(solver, [[smpl[moved]]], [previous], [joint])[0]
    before = character_residuals(effectors, previous, scale, solver.bodies)
    after = character_residuals(effectors, alone, scale, solver.bodies)
    return tuple(i for i, e in enumerate(effectors) if i != moved and e.tolerance < RELAXED_TOLERANCE
                 and after[i] - before[i] > allowance(e))


@cache
def _shipped_solver() -> Any:
    from smplik.solver import IKSolver

    return IKSolver.load()


def drag_scene_effector(scene: Any, character: str, joint: str | int, *, position: Any = None, offset: Any = None,
                        rotation: Any = None, tolerance: float = 0.0, solver: Any = None) -> tuple[Any, ScriptedEdit]:
    """A scripted drag: move (or add) one effector of a scene character and solve it as the editor's drag does.

    Exactly one of ``position`` (3,) (the joint's new place, character space), ``offset`` (3,) (added to where
    the stored pose has the joint) or ``rotation`` (3, 3) (the joint's new world rotation) is given. The
    effector of the same joint and type is replaced (else one is added, with ``tolerance``), the stale effectors
    of its chain are relaxed and its limb re-posed from the stored pose (:func:`solve_scripted`); the rest of the
    body stays where it was.

    Args:
        scene: a :class:`~workflows.scene.Scene` (``load_scene``); it is not changed.
        character: the character's name.
        solver: an :class:`smplik.solver.IKSolver` (default: the shipped model, loaded once).

    Returns: (the edited scene, what was moved and relaxed).
    Raises: :class:`~workflows.scene.SceneError` for an unknown character, a missing pose (``offset``) or not
    exactly one of position/offset/rotation; :class:`~smplik.effectors.EffectorError` for a bad joint or value.
    """
    from workflows.scene.characters import SceneError, character_joints

    names = [c.name for c in scene.characters]
    if character not in names:
        raise SceneError(f"no character {character!r} in the scene (characters: {', '.join(names)}).")
    n = names.index(character)
    c = scene.characters[n]
    given = [v is not None for v in (position, offset, rotation)]
    if sum(given) != 1:
        raise SceneError("a drag needs exactly one of position=, offset= or rotation=.")
    if rotation is not None:
        new = Effector.rotation(joint, rotation, tolerance)
    elif position is not None:
        new = Effector.position(joint, position, tolerance)
    else:
        if c.pose is None:
            raise SceneError(f"{character}: has no solved pose to move a joint from; give position= instead.")
        j = Effector.position(joint, (0.0, 0.0, 0.0)).joint
        new = Effector.position(joint, character_joints(c)[j] + np.asarray(offset, np.float64), tolerance)
    effectors = tuple(c.effectors)
    k = next((i for i, e in enumerate(effectors) if e.joint == new.joint and e.type == new.type), len(effectors))
    effectors = effectors[:k] + (new,) + effectors[k + 1:]
    pose, report = solve_scripted(solver or _shipped_solver(), c.name, effectors, c.pose, scale=c.scale,
                                  betas=c.betas, gender=c.gender, moved=[k])
    chars = list(scene.characters)
    chars[n] = dataclasses.replace(c, effectors=report.effectors, pose=pose)
    return dataclasses.replace(scene, characters=tuple(chars)), report


# ----------------------------------------------------------------------------- conflict report


def allowance(effector: Effector) -> float:
    """The residual (mm or degrees) that counts as meeting ``effector``: :data:`POSITION_ALLOWANCE_MM` /
    :data:`ANGLE_ALLOWANCE_DEG` plus three times the training sampler's noise at its tolerance."""
    noise = _SIGMA_MAX * float(effector.tolerance) ** _ETA
    if effector.type == EffectorType.POSITION:
        return POSITION_ALLOWANCE_MM + 3000.0 * noise
    return ANGLE_ALLOWANCE_DEG + 3.0 * float(np.degrees(noise))


def strain_limit(effector: Effector) -> float:
    """The network-alone residual (mm or degrees) beyond which an effector is *forced*: the refinement meets
    it only by bending the pose far from what the network makes of all the effectors together."""
    scale = 1.0 + 10.0 * float(effector.tolerance)
    return scale * (STRAIN_MM if effector.type == EffectorType.POSITION else STRAIN_DEG)


@dataclass(frozen=True)
class EffectorConflict:
    """One effector's line of the conflict report.

    Attributes:
        index: the effector's index in its character's list.
        effector: the effector (character space).
        residual: how far the solved pose is from it (mm for positions, degrees otherwise).
        allowed: the residual its tolerance allows (:func:`allowance`).
        network_residual: how far the network's pose alone (no refinement) is from it.
        conflicts_with: indices of the effectors it contradicts: leaving one of them out brings it within
            its allowance or halves its residual (the network's residual for a forced effector).
    """

    index: int
    effector: Effector
    residual: float
    allowed: float
    network_residual: float
    conflicts_with: tuple[int, ...] = ()
    drag_solved: bool = False
    """The pose is a drag's local solve from the previous pose (:func:`pulling_effectors` found what contradicts
    it), not the network's: :attr:`forced` does not apply."""

    @property
    def unit(self) -> str:
        return "mm" if self.effector.type == EffectorType.POSITION else "deg"

    @property
    def met(self) -> bool:
        return self.residual <= self.allowed

    @property
    def forced(self) -> bool:
        """Met only by the refinement bending the pose far from the network's answer (:func:`strain_limit`)."""
        return self.met and not self.drag_solved and self.network_residual > strain_limit(self.effector)

    @property
    def in_conflict(self) -> bool:
        return not self.met or self.forced

    def label(self) -> str:
        return f"{self.index}: {self.effector.joint_name} {self.effector.type.name.lower()}"


@dataclass(frozen=True)
class ConflictReport:
    """Per effector of one character, its residual and the effectors it contradicts."""

    character: str
    entries: tuple[EffectorConflict, ...]

    @property
    def conflicts(self) -> tuple[EffectorConflict, ...]:
        """The entries not met or forced."""
        return tuple(e for e in self.entries if e.in_conflict)

    def lines(self) -> list[str]:
        """Human-readable lines: a summary, then one line per effector."""
        bad = self.conflicts
        head = (f"{self.character}: no conflicting effectors ({len(self.entries)} met)" if not bad else
                f"{self.character}: {len(bad)} of {len(self.entries)} effectors in conflict (not met, or met only "
                "by bending the pose far from the network's answer)")
        out = [head]
        for e in self.entries:
            line = (f"  {e.label()} (tolerance {e.effector.tolerance:g}): {e.residual:.1f} {e.unit} "
                    f"(allowed {e.allowed:.1f}; network alone {e.network_residual:.1f})")
            if e.in_conflict:
                others = ", ".join(self.entries[j].label() for j in e.conflicts_with)
                what = "NOT MET" if not e.met else "FORCED"
                line += f"  {what}, contradicts {others}" if others else f"  {what}"
            out.append(line)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"character": self.character, "effectors": [
            {"index": e.index, "joint": e.effector.joint_name, "type": e.effector.type.name.lower(),
             "tolerance": e.effector.tolerance, "residual": e.residual, "unit": e.unit, "allowed": e.allowed,
             "network_residual": e.network_residual, "met": e.met, "forced": e.forced,
             "conflicts_with": list(e.conflicts_with), "drag_solved": e.drag_solved} for e in self.entries]}


def conflict_report(character: Any, solver: Any) -> ConflictReport:
    """The conflict report of a solved scene character (:class:`workflows.scene.SceneCharacter` with a pose).

    Residuals are those of the character's stored pose, in character space (positions scaled by
    ``scale``); network residuals those of the network's pose alone for the same effectors. For every
    effector in conflict (not met, or forced: :attr:`EffectorConflict.forced`), batched solves of the effector
    lists that each leave one other effector out find the effectors it contradicts.

    Args:
        character: the solved character (``effectors``, ``pose``, ``betas``, ``gender``, ``scale``, ``name``).
        solver: an :class:`smplik.solver.IKSolver` (its ``solve_batch``, ``refine`` and ``bodies``).
    """
    from smplik.refine import NO_REFINEMENT
    from smplik.solver import effector_residuals
    from workflows.scene.characters import scale_effector

    effectors = list(character.effectors)
    if not effectors or character.pose is None:
        return ConflictReport(character.name, ())
    scale = float(character.scale)
    smpl = [scale_effector(e, 1.0 / scale) for e in effectors]
    network = dataclasses.replace(solver, refine=NO_REFINEMENT)

    def residuals(pose: Any) -> list[float]:
        return [r.value * (scale if r.effector.type == EffectorType.POSITION else 1.0)
                for r in effector_residuals(pose, smpl, solver.bodies)]

    def solve(which: Any, lists: list[list[Effector]]) -> list[list[float]]:
        return [residuals(p) for p in which.solve_batch(lists, betas=character.betas, gender=character.gender)]

    values = residuals(character.pose)
    net_values = solve(network, [smpl])[0]
    allowed = [allowance(e) for e in effectors]
    entries = [EffectorConflict(k, e, values[k], allowed[k], net_values[k]) for k, e in enumerate(effectors)]
    bad = [e for e in entries if e.in_conflict]
    if bad and len(effectors) > 1:
        lists = [smpl[:j] + smpl[j + 1:] for j in range(len(smpl))]
        full = solve(solver, lists) if any(not e.met for e in bad) else None
        net = solve(network, lists) if any(e.forced for e in bad) else None
        for e in bad:
            k = e.index
            if not e.met:
                assert full is not None
                partners = [j for j in range(len(effectors)) if j != k and (
                    full[j][k] <= allowed[k] or full[j][k] <= 0.5 * values[k])]
            else:
                assert net is not None
                partners = [j for j in range(len(effectors)) if j != k and net[j][k] <= 0.5 * net_values[k]]
            entries[k] = dataclasses.replace(e, conflicts_with=tuple(partners))
    return ConflictReport(character.name, tuple(entries))
