"""Pure, batched rotation conversions and the geodesic distance (torch).

Conventions, fixed here once:

* Rotation matrices act on column vectors: ``v_world = R @ v_local``.
* Axis-angle ``(..., 3)``: unit axis times angle in radians.
* 6D ``(..., 6)``: the first two **columns** of the matrix, ``[R[..., :, 0], R[..., :, 1]]``
  (Zhou et al. 2019, ProtoRes eq. 14); decoding re-orthonormalises by Gram-Schmidt.
* Quaternions ``(..., 4)`` are scalar-first ``(w, x, y, z)``; conversions return ``w >= 0``.

Every function accepts arbitrary leading batch dimensions and keeps dtype and device.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "matrix_to_rot6d",
    "rot6d_to_matrix",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "axis_angle_to_quaternion",
    "quaternion_to_axis_angle",
    "geodesic_distance",
    "euler_to_matrix",
]


def _check_last(x: Tensor, dims: tuple[int, ...], name: str) -> None:
    if tuple(x.shape[-len(dims):]) != dims:
        raise ValueError(f"Invalid {name} shape {tuple(x.shape)}; expected (..., {', '.join(map(str, dims))}).")


def skew_matrix(v: Tensor) -> Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrix: ``skew_matrix(v) @ x = v x x``."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(axis_angle: Tensor) -> Tensor:
    """Rodrigues' formula, stable at zero angle. (..., 3) -> (..., 3, 3)."""
    _check_last(axis_angle, (3,), "axis-angle")
    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-8
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = theta2_safe.sqrt()
    # sin(t)/t and (1-cos t)/t^2 with Taylor fallbacks near zero.
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2_safe)
    K = skew_matrix(axis_angle)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def quaternion_to_matrix(quaternion: Tensor) -> Tensor:
    """(w, x, y, z) quaternion (normalised here) -> rotation matrix. (..., 4) -> (..., 3, 3)."""
    _check_last(quaternion, (4,), "quaternion")
    q = quaternion / quaternion.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    m = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return m.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quaternion(matrix: Tensor) -> Tensor:
    """Rotation matrix -> unit (w, x, y, z) quaternion with w >= 0. (..., 3, 3) -> (..., 4).

    Uses the numerically best of the four candidate formulas per element (Shepperd's method).
    """
    _check_last(matrix, (3, 3), "rotation matrix")
    m = matrix
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # 4 * q_i^2 for i in (w, x, y, z)
    q_abs2 = torch.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], dim=-1
    )
    q_abs = q_abs2.clamp_min(0).sqrt()  # 2|q_i|
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s21, s02, s10 = m[..., 2, 1] + m[..., 1, 2], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1]
    # Candidate (unnormalised) quaternions, each scaled by 4 q_i.
    cands = torch.stack(
        [
            torch.stack([q_abs2[..., 0], d21, d02, d10], -1),
            torch.stack([d21, q_abs2[..., 1], s10, s02], -1),
            torch.stack([d02, s10, q_abs2[..., 2], s21], -1),
            torch.stack([d10, s02, s21, q_abs2[..., 3]], -1),
        ],
        dim=-2,
    )  # (..., 4, 4)
    best = q_abs.argmax(dim=-1)  # (...)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def axis_angle_to_quaternion(axis_angle: Tensor) -> Tensor:
    """(..., 3) -> (..., 4) scalar-first unit quaternion (w >= 0 for angles <= pi)."""
    _check_last(axis_angle, (3,), "axis-angle")
    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True)
    small = theta2 < 1e-8
    theta = torch.where(small, torch.ones_like(theta2), theta2).sqrt()
    half_sinc = torch.where(small, 0.5 - theta2 / 48, torch.sin(theta / 2) / theta)
    w = torch.where(small, 1 - theta2 / 8, torch.cos(theta / 2))
    return torch.cat([w, axis_angle * half_sinc], dim=-1)


def quaternion_to_axis_angle(quaternion: Tensor) -> Tensor:
    """(..., 4) (w, x, y, z) -> (..., 3) axis-angle with angle in [0, pi]."""
    _check_last(quaternion, (4,), "quaternion")
    q = quaternion / quaternion.norm(dim=-1, keepdim=True)
    q = torch.where(q[..., :1] < 0, -q, q)
    xyz = q[..., 1:]
    sin_half = xyz.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(sin_half, q[..., :1])
    small = sin_half < 1e-6
    safe_sin = torch.where(small, torch.ones_like(sin_half), sin_half)
    scale = torch.where(small, 2 / q[..., :1].clamp_min(1e-12), angle / safe_sin)
    return xyz * scale


def matrix_to_axis_angle(matrix: Tensor) -> Tensor:
    """(..., 3, 3) -> (..., 3), angle in [0, pi]; stable near 0 and pi (via quaternions)."""
    return quaternion_to_axis_angle(matrix_to_quaternion(matrix))


def matrix_to_rot6d(matrix: Tensor) -> Tensor:
    """(..., 3, 3) -> (..., 6): first column then second column."""
    _check_last(matrix, (3, 3), "rotation matrix")
    return torch.cat([matrix[..., :, 0], matrix[..., :, 1]], dim=-1)


def rot6d_to_matrix(rot6d: Tensor) -> Tensor:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt on the two columns (ProtoRes eq. 14)."""
    _check_last(rot6d, (6,), "6D rotation")
    a1, a2 = rot6d[..., :3], rot6d[..., 3:]
    b1 = torch.nn.functional.normalize(a1, dim=-1, eps=1e-8)
    b2 = torch.nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1, eps=1e-8)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def euler_to_matrix(angles: Tensor) -> Tensor:
    """Intrinsic Z-Y-X Euler angles ``(a, b, c)`` -> ``Rz(a) @ Ry(b) @ Rx(c)``. (..., 3) -> (..., 3, 3).

    This is ProtoRes eq. (13), used for its rotation-effector noise model.
    """
    _check_last(angles, (3,), "Euler angles")
    unit = torch.eye(3, dtype=angles.dtype, device=angles.device)
    rz = axis_angle_to_matrix(angles[..., 0:1] * unit[2])
    ry = axis_angle_to_matrix(angles[..., 1:2] * unit[1])
    rx = axis_angle_to_matrix(angles[..., 2:3] * unit[0])
    return rz @ ry @ rx


def geodesic_distance(R_a: Tensor, R_b: Tensor) -> Tensor:
    """Angle in radians of ``R_a^T R_b``, in [0, pi]. (..., 3, 3), (..., 3, 3) -> (...).

    Computed as ``atan2(|skew part|, (trace - 1) / 2)``, which is accurate near 0 and near pi
    (unlike ``arccos``) and has finite gradients there.
    """
    _check_last(R_a, (3, 3), "rotation matrix")
    _check_last(R_b, (3, 3), "rotation matrix")
    rel = R_a.transpose(-1, -2) @ R_b
    cos = (rel[..., 0, 0] + rel[..., 1, 1] + rel[..., 2, 2] - 1) / 2
    skew = torch.stack(
        [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], dim=-1
    )
    sin = ((skew * skew).sum(-1) + 1e-30).sqrt() / 2
    return torch.atan2(sin, cos)
