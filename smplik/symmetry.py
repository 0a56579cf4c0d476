"""Body symmetries of a posed SMPL body: left/right mirroring and turns about the vertical axis.

Pure batched functions over local rotations ``R_parent_joint`` (..., 24, 3, 3) and smplx ``transl``
(..., 3), used by the training sampler's augmentation (:mod:`smplik.data.sampler`) and the solver's
test-time ensemble (:mod:`smplik.ensemble`). Mirroring reflects across the x = 0 plane with
``M = diag(-1, 1, 1)``; the vertical axis is y (the world is y-up).
"""

from __future__ import annotations

import torch
from torch import Tensor

from smplik.conventions import LEFT_RIGHT, NUM_JOINTS

_LEFT_RIGHT = torch.tensor(LEFT_RIGHT)


def mirror_pose(rotations: Tensor, transl: Tensor, rest_pelvis: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Reflect a pose across the x = 0 plane (left <-> right).

    Args:
        rotations: local rotations (root first), either axis-angle (..., 24, 3) or matrices
            (..., 24, 3, 3); the result has the same form.
        transl: (..., 3) smplx translation.
        rest_pelvis: (..., 3) rest pelvis ``J0(beta)`` of the body (default zero; on a
            symmetric body its x is 0 and the result does not depend on it).

    Returns:
        ``(rotations', transl')`` with ``R'_j = M R_{LR[j]} M``, ``M = diag(-1, 1, 1)`` (axis-angle
        ``(x, y, z) -> (x, -y, -z)``), and ``transl' = M (J0 + transl) - J0``, so the posed pelvis
        ``J0 + transl`` reflects. Applying it twice gives the input back.
    """
    if transl.shape[-1:] != (3,):
        raise ValueError(f"Invalid transl shape {tuple(transl.shape)}; expected (..., 3).")
    lr = _LEFT_RIGHT.to(rotations.device)
    if rotations.shape[-3:] == (NUM_JOINTS, 3, 3):
        sign = torch.tensor([[1.0, -1.0, -1.0], [-1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]], dtype=rotations.dtype,
                            device=rotations.device)  # (M R M)_ik = m_i m_k R_ik
        rot_m = rotations[..., lr, :, :] * sign
    elif rotations.shape[-2:] == (NUM_JOINTS, 3):
        rot_m = rotations[..., lr, :] * torch.tensor([1.0, -1.0, -1.0], dtype=rotations.dtype, device=rotations.device)
    else:
        raise ValueError(f"Invalid pose shape {tuple(rotations.shape)}; expected (..., {NUM_JOINTS}, 3) axis-angle "
                         f"or (..., {NUM_JOINTS}, 3, 3) matrices.")
    flip_pos = torch.tensor([-1.0, 1.0, 1.0], dtype=transl.dtype, device=transl.device)
    if rest_pelvis is None:
        return rot_m, transl * flip_pos
    return rot_m, (rest_pelvis + transl) * flip_pos - rest_pelvis


def rotation_about_y(angle: Tensor) -> Tensor:
    """Rotation by ``angle`` (radians, right-handed) about the vertical y axis. (...) -> (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    zero, one = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([c, zero, s, zero, one, zero, -s, zero, c], dim=-1).reshape(*angle.shape, 3, 3)


def rotate_about_vertical(R_local: Tensor, transl: Tensor, angle: Tensor,
                          rest_pelvis: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Turn a whole posed body about the vertical (y) axis through the world origin.

    Args:
        R_local: (..., 24, 3, 3) local rotations (only the root, joint 0, changes).
        transl: (..., 3) smplx translation.
        angle: (...) radians.
        rest_pelvis: (..., 3) rest pelvis ``J0(beta)`` (default zero).

    Returns:
        ``(R_local' (..., 24, 3, 3), transl' (..., 3))`` with ``R'_0 = R_y R_0`` and
        ``transl' = R_y (J0 + transl) - J0``: every posed joint ``p`` moves to ``R_y p``, so the
        pelvis keeps its height.
    """
    if R_local.shape[-3:] != (NUM_JOINTS, 3, 3):
        raise ValueError(f"Invalid local rotations shape {tuple(R_local.shape)}; expected (..., {NUM_JOINTS}, 3, 3).")
    R_y = rotation_about_y(angle.to(R_local.dtype))
    root = R_y @ R_local[..., 0, :, :]
    R_out = torch.cat([root[..., None, :, :], R_local[..., 1:, :, :]], dim=-3)
    J0 = torch.zeros_like(transl) if rest_pelvis is None else rest_pelvis
    transl_out = (R_y @ (J0 + transl)[..., None])[..., 0] - J0
    return R_out, transl_out
