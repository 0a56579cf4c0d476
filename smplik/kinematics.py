"""Pure, batched skeleton kinematics over ``(..., J, ·)`` tensors.

Frames: ``R_parent_joint`` is a joint's rotation relative to its parent (SMPL's local pose),
``R_world_joint``/``p_world_joint`` its global rotation and position. Rest joints ``J_rest
(..., J, 3)`` give the bone offsets ``J_rest[j] - J_rest[parent(j)]`` of a T-pose skeleton whose
local rotations are all identity (SMPL's convention). The root rotates about its rest position
and ``transl`` is added afterwards (smplx's convention).

Joints are processed one tree-depth level at a time (8 levels for SMPL instead of 23 joint
steps), which keeps small batches fast. :func:`compose_to_root` composes the same chains by
pointer jumping (4 rounds for SMPL's 9 levels), batch last: the form the ONNX graph uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import torch
from torch import Tensor

from smplik.conventions import PARENTS, tree_depth


@dataclass(frozen=True)
class _Levels:
    """The skeleton in depth-level order: ``order`` (J,) joints sorted by depth, ``parent_of_order``
    (J,) each one's parent (the root its own), ``bounds`` the [start, end) of each level in that
    order, ``parent_pos`` per level (from 1) the parent's position within the previous level (a
    parent is always exactly one level up), and ``inverse`` (J,) the inverse permutation."""

    order: Tensor
    parent_of_order: Tensor
    bounds: tuple[tuple[int, int], ...]
    parent_pos: tuple[Tensor, ...]
    inverse: Tensor


@lru_cache(maxsize=16)
def _levels(parents: tuple[int, ...]) -> _Levels:
    """Cached :class:`_Levels` of a parent list.

    Built outside inference mode: cached tensors made under ``torch.inference_mode()`` could not
    be saved for backward by later autograd users of FK.
    """
    with torch.inference_mode(False):
        depth = tree_depth(parents)
        order: list[int] = []
        bounds: list[tuple[int, int]] = []
        parent_pos: list[Tensor] = []
        previous: list[int] = []
        for d in range(max(depth) + 1):
            joints = [j for j in range(len(parents)) if depth[j] == d]
            position = {j: i for i, j in enumerate(previous)}
            parent_pos.append(torch.tensor([position.get(parents[j], 0) for j in joints]))
            bounds.append((len(order), len(order) + len(joints)))
            order.extend(joints)
            previous = joints
        inverse = torch.empty(len(order), dtype=torch.long)
        inverse[torch.tensor(order)] = torch.arange(len(order))
        return _Levels(torch.tensor(order), torch.tensor([max(parents[j], 0) for j in order]), tuple(bounds),
                       tuple(parent_pos), inverse)


def broadcast_shapes(a: tuple[int, ...], b: tuple[int, ...]) -> tuple[int, ...]:
    """The broadcast of two shapes, as ``torch.broadcast_shapes`` (whose first call imports sympy through
    ``torch._refs``: 0.7 CPU s of every command's start). Raises RuntimeError when they do not broadcast."""
    if torch.jit.is_tracing():
        return tuple(torch.broadcast_shapes(a, b))
    n = max(len(a), len(b))
    a, b = (1,) * (n - len(a)) + tuple(a), (1,) * (n - len(b)) + tuple(b)
    out = []
    for x, y in zip(a, b, strict=True):
        if x != y and 1 not in (x, y):
            raise RuntimeError(f"shapes {a} and {b} do not broadcast.")
        out.append(x if y == 1 else y)
    return tuple(out)


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
    batch = broadcast_shapes(R_parent_joint.shape[:-3], J_rest.shape[:-2])
    lv = _levels(tuple(parents))
    dev = R_parent_joint.device
    order = lv.order.to(dev)
    # Everything in level order: one gather each, then each level is a contiguous slice.
    R_local = R_parent_joint[..., order, :, :].expand(*batch, J, 3, 3)
    J_ordered = J_rest[..., order, :]
    offsets = (J_ordered - J_rest[..., lv.parent_of_order.to(dev), :]).expand(*batch, J, 3)
    R_levels: list[Tensor] = [R_local[..., :1, :, :]]
    p_levels: list[Tensor] = [J_ordered[..., :1, :].expand(*batch, 1, 3)]
    for (start, end), parent_pos in zip(lv.bounds[1:], lv.parent_pos[1:], strict=True):
        parent_pos = parent_pos.to(dev)
        R_par = R_levels[-1][..., parent_pos, :, :]
        R_levels.append(R_par @ R_local[..., start:end, :, :])
        p_levels.append(p_levels[-1][..., parent_pos, :] + (R_par @ offsets[..., start:end, :, None])[..., 0])
    inverse = lv.inverse.to(dev)
    R_world_joint = torch.cat(R_levels, dim=-3)[..., inverse, :, :]
    p_world_joint = torch.cat(p_levels, dim=-2)[..., inverse, :]
    if transl is not None:
        p_world_joint = p_world_joint + transl[..., None, :]
    return R_world_joint, p_world_joint


@lru_cache(maxsize=16)
def _jumps(parents: tuple[int, ...]) -> tuple[Tensor, ...]:
    """Pointer-jumping rounds of a parent list: per round, each joint's ancestor ``2^round`` levels up,
    ``J`` (a sentinel standing for the identity) where there is none; indices over ``J + 1`` entries.

    Built outside inference mode (see :func:`_levels`).
    """
    with torch.inference_mode(False):
        J = len(parents)
        up = [p if p >= 0 else J for p in parents] + [J]
        rounds = []
        while any(a != J for a in up[:J]):
            rounds.append(torch.tensor(up))
            up = [up[a] for a in up]
        return tuple(rounds)


@lru_cache(maxsize=16)
def _homogeneous(J: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """(4, 4, J + 1, 1): 1 at [3, 3] of every joint, the identity for the sentinel J (outside inference mode)."""
    with torch.inference_mode(False):
        out = torch.zeros(4, 4, J + 1, 1, dtype=dtype, device=device)
        out[3, 3] = 1.0
        out[:, :, J, 0] = torch.eye(4, dtype=dtype, device=device)
        return out


def compose_to_root(T_parent_joint: Tensor, parents: tuple[int, ...] = PARENTS) -> Tensor:
    """World transforms from local ones by pointer jumping: ``log2(depth + 1)`` rounds over all joints at once
    (4 rounds for SMPL), instead of one step per tree level.

    Layout: **batch last**, ``(3, 4, J, B)``: ``T[:, :, j, b] = [R | t]``, the affine map ``x -> R x + t`` of
    joint j in batch row b. This is the ONNX graph's layout: every product is then an elementwise operation
    over contiguous rows of J B values (onnxruntime would run a matmul of B x J 4x4 matrices as that many small
    GEMMs, and broadcasts over short inner axes slowly). For FK, ``T_parent_joint[..., j, :] = [R_parent_joint[j]
    | J_rest[j] - J_rest[parent(j)]]`` and, for the root, ``[R_world_root | J_rest[0] + transl]``; the result is
    ``[R_world_joint | p_world_joint]`` (:func:`forward_kinematics`' outputs, up to float rounding of the
    different product order).

    Args:
        T_parent_joint: (3, 4, J, B) local transforms (joint 0: the root's world transform).
        parents: parent index per joint, parents before children.

    Returns:
        ``T_world_joint`` (3, 4, J, B).
    """
    J = len(parents)
    if T_parent_joint.dim() != 4 or T_parent_joint.shape[:3] != (3, 4, J):
        raise ValueError(f"Invalid local transforms shape {tuple(T_parent_joint.shape)}; expected (3, 4, {J}, B).")
    # Homogeneous (4, 4, J + 1, B): a zero last row and an all-zero sentinel entry J, then the constant part
    # (1 at [3, 3]; the sentinel the identity) added in one operation.
    T = torch.nn.functional.pad(T_parent_joint, (0, 0, 0, 1, 0, 0, 0, 1)) + _homogeneous(J, T_parent_joint.dtype,
                                                                                       T_parent_joint.device)
    for up in _jumps(tuple(parents)):
        # T_world = T_world_parent @ T_local: T[r, c] = sum_m T_up[r, m] T[m, c]; (4, 4, 1, ...) * (4, 4, ...)
        T = (T[:, :, up.to(T.device)][:, :, None] * T).sum(1)
    return T[:3, :, :J]


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
