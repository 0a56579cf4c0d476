"""Pure functions: tracker signals -> heading-invariant network inputs, and network outputs -> SMPL pose.

Conventions: y up, metres; rotations are (..., 3, 3) world matrices; the *heading frame* of frame t is the
world rotated by the yaw of the reference tracker (the first one, the head by default) and moved so that
the reference's x and z are 0 (its y, the height above the floor, is kept: the floor stays at y = 0). The
yaw is the angle of the reference's local +z axis (SMPL's forward) projected on the floor.

Inputs per frame (:func:`tracker_features`), per tracker k: position in the heading frame (3), velocity
(frame difference, m/s, expressed in the current heading frame) (3), rotation in the heading frame as 6D
(6, zeros when the tracker has no rotation), a rotation-present flag (1); then the sine and cosine of the
heading change since the previous frame (2). Outputs per frame: 24 local 6D rotations (the root's
relative to the heading frame), the pelvis position in the heading frame (3), two foot-contact logits.
"""

from __future__ import annotations

import torch
from torch import Tensor

from smplik.rotations import matrix_to_rot6d, rot6d_to_matrix
from smplik.symmetry import rotation_about_y

NUM_OUT_ROT = 24 * 6
"""Output columns of the local 6D rotations."""
OUT_DIM = NUM_OUT_ROT + 3 + 2
"""Output columns: rotations, pelvis position in the heading frame, contact logits."""


def heading_yaw(R_world_ref: Tensor) -> Tensor:
    """Yaw (...,) of rotations (..., 3, 3): the angle about +y of the local +z axis projected on the floor."""
    f = R_world_ref[..., :, 2]
    return torch.atan2(f[..., 0], f[..., 2])


def tracker_features(p_world: Tensor, R_world: Tensor, has_rot: Tensor, fps: float) -> tuple[Tensor, Tensor, Tensor]:
    """Heading-invariant inputs for a sequence of tracker signals.

    Args:
        p_world: (..., T, K, 3) tracker positions; R_world: (..., T, K, 3, 3) tracker rotations (any value where
            ``has_rot`` is False); has_rot: (..., K) bool; fps: frames per second.

    Returns:
        ``(x (..., T, K * 13 + 2), yaw (..., T), origin (..., T, 3))``: the features, the heading per frame
        and the heading frame's origin (reference x, 0, reference z). The first frame's velocity is zero.
    """
    yaw = heading_yaw(R_world[..., 0, :, :])
    Y_inv = rotation_about_y(-yaw)  # (..., T, 3, 3)
    origin = p_world[..., 0, :] * p_world.new_tensor([1.0, 0.0, 1.0])
    pos = torch.einsum("...tij,...tkj->...tki", Y_inv, p_world - origin[..., None, :])
    d = torch.zeros_like(p_world)
    d[..., 1:, :, :] = (p_world[..., 1:, :, :] - p_world[..., :-1, :, :]) * fps
    vel = torch.einsum("...tij,...tkj->...tki", Y_inv, d)
    mask = has_rot[..., None, :].expand(*p_world.shape[:-1]).to(p_world.dtype)  # (..., T, K)
    R_h = Y_inv[..., None, :, :] @ R_world
    rot = matrix_to_rot6d(R_h) * mask[..., None]
    dyaw = torch.zeros_like(yaw)
    dyaw[..., 1:] = yaw[..., 1:] - yaw[..., :-1]
    per = torch.cat([pos, vel * 0.1, rot, mask[..., None]], dim=-1)  # (..., T, K, 13)
    x = torch.cat([per.flatten(-2), torch.sin(dyaw)[..., None], torch.cos(dyaw)[..., None]], dim=-1)
    return x, yaw, origin


def pose_targets(R_local: Tensor, p_pelvis: Tensor, yaw: Tensor, origin: Tensor) -> Tensor:
    """Training targets (..., 147) of a pose: local 6D (root in the heading frame) and the pelvis position in the
    heading frame. R_local (..., 24, 3, 3), p_pelvis (..., 3), yaw (...), origin (..., 3)."""
    Y_inv = rotation_about_y(-yaw)
    R = R_local.clone()
    R[..., 0, :, :] = Y_inv @ R_local[..., 0, :, :]
    pel = (Y_inv @ (p_pelvis - origin)[..., None])[..., 0]
    return torch.cat([matrix_to_rot6d(R).flatten(-2), pel], dim=-1)


def decode_pose(out: Tensor, yaw: Tensor, origin: Tensor, J_rest: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Network outputs -> world pose.

    Args:
        out: (..., OUT_DIM) network outputs; yaw: (...) heading; origin: (..., 3) heading-frame origin;
        J_rest: (..., 24, 3) rest joints (broadcast).

    Returns:
        ``(R_local (..., 24, 3, 3) with the root in world, transl (..., 3) smplx translation,
        contact_prob (..., 2) left, right)``.
    """
    R = rot6d_to_matrix(out[..., :NUM_OUT_ROT].unflatten(-1, (24, 6)))
    Y = rotation_about_y(yaw)
    R_root = Y @ R[..., 0, :, :]
    R = torch.cat([R_root[..., None, :, :], R[..., 1:, :, :]], dim=-3)
    pel = (Y @ out[..., NUM_OUT_ROT:NUM_OUT_ROT + 3, None])[..., 0] + origin
    transl = pel - J_rest[..., 0, :]
    return R, transl, torch.sigmoid(out[..., NUM_OUT_ROT + 3:])
