"""Pure, batched skeleton kinematics over ``(..., J, ·)`` tensors.

Frames: ``R_parent_joint`` is a joint's rotation relative to its parent (SMPL's local pose),
``R_world_joint``/``p_world_joint`` its global rotation and position. Rest joints ``J_rest
(..., J, 3)`` give the bone offsets ``J_rest[j] - J_rest[parent(j)]`` of a T-pose skeleton whose
local rotations are all identity (SMPL's convention). The root rotates about its rest position
and ``transl`` is added afterwards (smplx's convention).

Joints are processed one tree-depth level at a time (8 levels for SMPL instead of 23 joint
steps), which keeps small batches fast.
"""

from __future__ import annotations

from functools import lru_cache

import torch
from torch import Tensor

from smplik.conventions import PARENTS, tree_depth


@lru_cache(maxsize=16)
def _levels(parents: tuple[int, ...]) -> tuple[list[Tensor], list[Tensor], Tensor]:
    """Joint indices per depth level, each joint's parent position within the previous level
    (a parent is always exactly one level up), and the inverse of the level order.

    Built outside inference mode: cached tensors made under ``torch.inference_mode()`` could not
    be saved for backward by later autograd users of FK.
    """
    with torch.inference_mode(False):
        return _build_levels(parents)


def _build_levels(parents: tuple[int, ...]) -> tuple[list[Tensor], list[Tensor], Tensor]:
    depth = tree_depth(parents)
    order: list[int] = []
    joints_per_level: list[Tensor] = []
    parent_pos_per_level: list[Tensor] = []
    previous: list[int] = []
    for d in range(max(depth) + 1):
        joints = [j for j in range(len(parents)) if depth[j] == d]
        position = {j: i for i, j in enumerate(previous)}
        parent_pos_per_level.append(torch.tensor([position.get(parents[j], -1) for j in joints]))
        joints_per_level.append(torch.tensor(joints))
        order.extend(joints)
        previous = joints
    inverse = torch.empty(len(order), dtype=torch.long)
    inverse[torch.tensor(order)] = torch.arange(len(order))
    return joints_per_level, parent_pos_per_level, inverse


def forward_kinematics(
    R_parent_joint: Tensor,
    J_rest: Tensor,
    transl: Tensor | None = None,
    parents: tuple[int, ...] = PARENTS,
) -> tuple[Tensor, Tensor]:
    """Global joint rotations and positions from local rotations and a rest skeleton.

    Args:
        R_parent_joint: (..., J, 3, 3) local rotations (joint 0: the root's global rotation).
        J_rest: (..., J, 3) rest joint positions; broadcast against ``R_parent_joint``'s batch.
        transl: (..., 3) or None; added to every joint (smplx ``transl``).
        parents: parent index per joint, parents before children.

    Returns:
        ``(R_world_joint (..., J, 3, 3), p_world_joint (..., J, 3))``.
    """
    J = len(parents)
    if R_parent_joint.shape[-3:] != (J, 3, 3):
        raise ValueError(f"Invalid local rotations shape {tuple(R_parent_joint.shape)}; expected (..., {J}, 3, 3).")
    if J_rest.shape[-2:] != (J, 3):
        raise ValueError(f"Invalid rest joints shape {tuple(J_rest.shape)}; expected (..., {J}, 3).")
    batch = torch.broadcast_shapes(R_parent_joint.shape[:-3], J_rest.shape[:-2])
    R_local = R_parent_joint.expand(*batch, J, 3, 3)
    J_rest = J_rest.expand(*batch, J, 3)
    parent_idx = torch.tensor([max(p, 0) for p in parents], device=J_rest.device)
    offsets = J_rest - J_rest[..., parent_idx, :]
    offsets[..., 0, :] = J_rest[..., 0, :]

    joints_per_level, parent_pos_per_level, inverse = _levels(tuple(parents))
    R_levels: list[Tensor] = [R_local[..., joints_per_level[0].to(R_local.device), :, :]]
    p_levels: list[Tensor] = [offsets[..., joints_per_level[0].to(R_local.device), :]]
    for joints, parent_pos in zip(joints_per_level[1:], parent_pos_per_level[1:], strict=True):
        joints, parent_pos = joints.to(R_local.device), parent_pos.to(R_local.device)
        R_par = R_levels[-1][..., parent_pos, :, :]
        p_par = p_levels[-1][..., parent_pos, :]
        R_levels.append(R_par @ R_local[..., joints, :, :])
        p_levels.append(p_par + (R_par @ offsets[..., joints, :, None])[..., 0])
    inverse = inverse.to(R_local.device)
    R_world_joint = torch.cat(R_levels, dim=-3)[..., inverse, :, :]
    p_world_joint = torch.cat(p_levels, dim=-2)[..., inverse, :]
    if transl is not None:
        p_world_joint = p_world_joint + transl[..., None, :]
    return R_world_joint, p_world_joint


def global_to_local(R_world_joint: Tensor, parents: tuple[int, ...] = PARENTS) -> Tensor:
    """``R_parent_joint = R_world_parent^T R_world_joint``. (..., J, 3, 3) -> (..., J, 3, 3)."""
    parent_idx = torch.tensor([max(p, 0) for p in parents], device=R_world_joint.device)
    R_world_parent = R_world_joint[..., parent_idx, :, :]
    R_local = R_world_parent.transpose(-1, -2) @ R_world_joint
    return torch.cat([R_world_joint[..., :1, :, :], R_local[..., 1:, :, :]], dim=-3)


def local_to_global(R_parent_joint: Tensor, parents: tuple[int, ...] = PARENTS) -> Tensor:
    """Global rotations from local ones (the rotation half of :func:`forward_kinematics`)."""
    J = len(parents)
    zeros = torch.zeros(R_parent_joint.shape[:-2] + (3,), dtype=R_parent_joint.dtype, device=R_parent_joint.device)
    return forward_kinematics(R_parent_joint, zeros.expand(*R_parent_joint.shape[:-3], J, 3), None, parents)[0]
