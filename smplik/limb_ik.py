"""Analytic two-bone IK on world positions (numpy): hip, knee, ankle or shoulder, elbow, wrist.

Used where joint positions are edited directly: foot locking (:func:`workflows.animation.clean.lock_feet`) and
the tracker runtime's limb fix-up (:mod:`smplik.tracking.runtime`). The torch version that works on a
local-rotation pose, :func:`two_bone_ik_pose` (with :func:`swivel_angle` and :func:`turn_swivel`), is the editor's
limb drag and the edit benchmark's ``two_bone`` method.

The algorithm of Unity Animation Rigging's ``TwoBoneIK`` (``AnimationRuntimeUtils.SolveTwoBoneIK`` without a
hint) and of a Blender IK constraint of chain length 2: for the chain root ``a`` (shoulder / hip), middle
``b`` (elbow / knee) and tip ``c`` (wrist / ankle) and a target ``t``,

1. bend the middle joint about the chain's current bend axis ``(b - a) x (c - b)`` until the distance
   ``|c - a|`` equals ``|t - a|`` (law of cosines; clamped to the straight or fully folded limb);
2. turn the root joint by the shortest rotation taking ``c - a`` onto ``t - a``.

Every other local rotation is kept, so the tip's local rotation (the hand's orientation relative to the
forearm) follows the forearm. Targets beyond reach give the straight limb pointing at them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from smplik.conventions import PARENTS
from smplik.rotations import axis_angle_to_matrix, axis_rotation_np

if TYPE_CHECKING:
    from torch import Tensor

__all__ = ["shortest_rotation", "swivel_angle", "turn_swivel", "two_bone_ik", "two_bone_ik_pose"]


def _unit(v: np.ndarray, eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, eps), n[..., 0]


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), (u * v).sum(-1))


def two_bone_ik(p_a: np.ndarray, p_b: np.ndarray, p_c: np.ndarray, target: np.ndarray, bend_axis: np.ndarray,
                eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone IK (root a, middle b, end c), batched.

    Args:
        p_a, p_b, p_c, target: (..., 3) world positions.
        bend_axis: (..., 3) world axis about which a *negative* rotation at b bends the chain (for
            SMPL's knee: minus its x axis); used only when the chain is straight.

    Returns:
        ``(R_a, R_b)`` (..., 3, 3) world-frame rotations: R_b about b (applied to the lower bone first),
        then R_a about a (applied to both bones). New positions ``b' = a + R_a (b - a)``,
        ``c' = a + R_a (b - a + R_b (c - b))``; new world rotations ``R_a G_a`` and ``R_a R_b G_b``.
        ``c'`` equals the target when it is within reach, else it points at it from ``a``.
    """
    l_ab = np.linalg.norm(p_b - p_a, axis=-1)
    l_bc = np.linalg.norm(p_c - p_b, axis=-1)
    l_at = np.clip(np.linalg.norm(target - p_a, axis=-1), np.abs(l_ab - l_bc) + eps, l_ab + l_bc - eps)
    u, v = p_a - p_b, p_c - p_b
    normal, n_len = _unit(np.cross(u, v))
    fallback, _ = _unit(bend_axis)
    normal = np.where((n_len > 1e-9 * np.maximum(l_ab * l_bc, 1e-12))[..., None], normal, fallback)
    theta0 = _angle(u, v)
    cos1 = np.clip((l_ab ** 2 + l_bc ** 2 - l_at ** 2) / (2.0 * l_ab * l_bc), -1.0, 1.0)
    R_b = axis_rotation_np(normal, np.arccos(cos1) - theta0)
    c1 = p_b + (R_b @ v[..., None])[..., 0]
    from_dir, _ = _unit(c1 - p_a)
    to_dir, _ = _unit(target - p_a)
    swing_axis, s_len = _unit(np.cross(from_dir, to_dir))
    swing = _angle(from_dir, to_dir)
    # antiparallel: any axis perpendicular to from_dir
    perp, _ = _unit(np.cross(from_dir, np.where(np.abs(from_dir[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0])))
    swing_axis = np.where((s_len > 1e-12)[..., None], swing_axis, perp)
    R_a = axis_rotation_np(swing_axis, np.where(s_len > 1e-12, swing, np.where(swing > 1.0, swing, 0.0)))
    return R_a, R_b


# ----------------------------------------------------------------------------- torch, on a local-rotation pose

_POSE_EPS = 1e-9


def _rotate_about(axis: Tensor, angle: Tensor) -> Tensor:
    """Rotation matrices (B, 3, 3) of ``angle`` (B,) about unit ``axis`` (B, 3)."""
    return axis_angle_to_matrix(axis * angle[:, None])


def shortest_rotation(u: Tensor, v: Tensor) -> Tensor:
    """The rotation (B, 3, 3) of least angle taking direction ``u`` (B, 3) onto ``v`` (B, 3).

    Opposite directions turn by pi about an axis perpendicular to ``u``.
    """
    import torch

    u = u / u.norm(dim=-1, keepdim=True).clamp_min(_POSE_EPS)
    v = v / v.norm(dim=-1, keepdim=True).clamp_min(_POSE_EPS)
    axis = torch.cross(u, v, dim=-1)
    sin = axis.norm(dim=-1)
    cos = (u * v).sum(-1)
    # perpendicular fallback axis for (anti)parallel vectors
    other = torch.where(u[:, :1].abs() < 0.9, torch.tensor([1.0, 0.0, 0.0], dtype=u.dtype),
                        torch.tensor([0.0, 1.0, 0.0], dtype=u.dtype))
    fallback = torch.cross(u, other, dim=-1)
    axis = torch.where(sin[:, None] > 1e-9, axis / sin.clamp_min(_POSE_EPS)[:, None],
                       fallback / fallback.norm(dim=-1, keepdim=True))
    return _rotate_about(axis, torch.atan2(sin, cos))


def _triangle_angle(opposite: Tensor, side1: Tensor, side2: Tensor) -> Tensor:
    """Interior angle between sides 1 and 2 of a triangle whose third side is ``opposite`` (clamped)."""
    import torch

    cos = (side1.square() + side2.square() - opposite.square()) / (2 * side1 * side2).clamp_min(_POSE_EPS)
    return torch.acos(cos.clamp(-1.0, 1.0))


def two_bone_ik_pose(R_local: Tensor, transl: Tensor, J_rest: Tensor, tip: Tensor, target: Tensor,
                     parents: tuple[int, ...] = PARENTS) -> Tensor:
    """Pose each tip's two-bone chain (grandparent, parent, tip) so that the tip reaches its target.

    Args:
        R_local: (B, J, 3, 3) local rotations of the starting poses; transl: (B, 3); J_rest: (B, J, 3).
        tip: (B,) long, the dragged joint (its parent and grandparent are the chain).
        target: (B, 3) world targets.

    Returns: (B, J, 3, 3) local rotations (only the chain's middle and root joints change).
    """
    import torch

    from smplik.kinematics import forward_kinematics

    B = R_local.shape[0]
    rows = torch.arange(B)
    par = torch.tensor(parents)
    mid = par[tip]
    root = par[mid]
    R_local = R_local.clone()
    R_world, p = forward_kinematics(R_local, J_rest, transl, parents)
    a, b, c = p[rows, root], p[rows, mid], p[rows, tip]
    ab, bc = (b - a).norm(dim=-1), (c - b).norm(dim=-1)
    bend_old = _triangle_angle((c - a).norm(dim=-1), ab, bc)
    reach = (target - a).norm(dim=-1).clamp(max=ab + bc)
    bend_new = _triangle_angle(reach, ab, bc)
    axis = torch.cross(b - a, c - b, dim=-1)
    straight = axis.norm(dim=-1) < 1e-6 * (ab * bc).clamp_min(_POSE_EPS)
    if straight.any():  # a straight limb bends about an axis perpendicular to it and to the target
        alt = torch.cross(b - a, target - a, dim=-1)
        alt = torch.where(alt.norm(dim=-1, keepdim=True) > 1e-9, alt,
                          torch.cross(b - a, torch.tensor([0.0, 0.0, 1.0], dtype=a.dtype).expand_as(a), dim=-1))
        axis = torch.where(straight[:, None], alt, axis)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(_POSE_EPS)
    # a positive turn about (b - a) x (c - b) folds the limb further: the interior angle shrinks by it
    delta_mid = _rotate_about(axis, bend_old - bend_new)
    R_par_mid = R_world[rows, root]  # the middle joint's parent is the chain root
    R_local[rows, mid] = R_par_mid.transpose(-1, -2) @ delta_mid @ R_world[rows, mid]
    R_world, p = forward_kinematics(R_local, J_rest, transl, parents)
    delta_root = shortest_rotation(p[rows, tip] - a, target - a)
    grand = par[root]
    R_local[rows, root] = R_world[rows, grand].transpose(-1, -2) @ delta_root @ R_world[rows, root]
    return R_local


def swivel_angle(root: Tensor, mid: Tensor, target: Tensor, root_ref: Tensor, mid_ref: Tensor) -> Tensor:
    """Signed turn (B,) about the reach axis ``target - root`` that takes the middle joint's direction
    ``mid - root`` onto ``mid_ref - root_ref`` (both projected off the axis): the swivel (elbow or knee pole)
    change from one limb pose to another. 0 where either projection is degenerate (a straight limb).

    All arguments (B, 3) world positions.
    """
    import torch

    n = target - root
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(_POSE_EPS)
    u = mid - root
    u = u - (u * n).sum(-1, keepdim=True) * n
    v = mid_ref - root_ref
    v = v - (v * n).sum(-1, keepdim=True) * n
    angle = torch.atan2((torch.cross(u, v, dim=-1) * n).sum(-1), (u * v).sum(-1))
    ok = (u.norm(dim=-1) > 1e-3) & (v.norm(dim=-1) > 1e-3)
    return torch.where(ok, angle, torch.zeros_like(angle))


def turn_swivel(R_local: Tensor, transl: Tensor, J_rest: Tensor, tip: Tensor, target: Tensor, angle: Tensor,
                parents: tuple[int, ...] = PARENTS) -> Tensor:
    """Turn each tip's two-bone chain by ``angle`` (B,) about its reach axis ``target - root``: the chain
    root's world rotation is pre-multiplied by that turn, so the root stays, the tip stays on the axis (on the
    target when the chain reaches it) and only the middle joint's swivel changes (what a pole or hint
    target sets in Unity's TwoBoneIK or a Blender IK constraint).

    R_local (B, J, 3, 3), transl (B, 3), J_rest (B, J, 3), tip (B,) long, target (B, 3) -> (B, J, 3, 3).
    """
    import torch

    from smplik.kinematics import forward_kinematics

    rows = torch.arange(R_local.shape[0])
    par = torch.tensor(parents)
    root = par[par[tip]]
    R_world, p = forward_kinematics(R_local, J_rest, transl, parents)
    n = target - p[rows, root]
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(_POSE_EPS)
    R_local = R_local.clone()
    turned = _rotate_about(n, angle) @ R_world[rows, root]
    R_local[rows, root] = R_world[rows, par[root]].transpose(-1, -2) @ turned
    return R_local
