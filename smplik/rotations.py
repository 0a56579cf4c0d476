"""Pure, batched rotation conversions and the geodesic distance: the one home of every conversion.

Conventions, fixed here once:

* Rotation matrices act on column vectors: ``v_world = R @ v_local``.
* Axis-angle ``(..., 3)`` (scipy's "rotation vector"): unit axis times angle in radians.
* 6D ``(..., 6)``: the first two **columns** of the matrix, ``[R[..., :, 0], R[..., :, 1]]``
  (Zhou et al. 2019, ProtoRes eq. 14); decoding re-orthonormalises by Gram-Schmidt.
* Quaternions ``(..., 4)`` are scalar-first ``(w, x, y, z)`` unless a name says ``xyzw`` (scipy's, glTF's
  and OpenVR's order); torch conversions return ``w >= 0``.

Two twins of every conversion:

* **torch** (``axis_angle_to_matrix``, ``quaternion_to_matrix``, ...): differentiable, keep dtype and device.
  torch is imported inside them, so the numpy functions below load without it.
* **numpy**, float64: through :class:`scipy.spatial.transform.Rotation` (``quat_wxyz_to_matrix``,
  ``matrix_to_quat_wxyz``, ``axis_angle_to_matrix_np``, ``matrix_to_axis_angle_scipy``), or hand-written where
  speed or the exact float32 formula of a torch twin matters (``*_np``: ``quaternion_to_matrix_np``,
  ``rot6d_to_matrix_np``, ``matrix_to_axis_angle_np``, ``axis_rotation_np``); BVH's Euler channels in degrees
  (``euler_deg_to_matrix_np``, ``matrix_to_euler_deg_np``, any axis order, unlike :func:`euler_to_matrix`).

Every function accepts arbitrary leading batch dimensions. The numba kernels (:mod:`smplik.tracking.kernels`,
:mod:`smplik.tracking.fit`, :mod:`smplik.refine_fast`) keep their own jit-compiled scalar copies, tested against
these.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
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
    "quat_wxyz_to_xyzw",
    "quat_xyzw_to_wxyz",
    "quat_wxyz_to_matrix",
    "matrix_to_quat_wxyz",
    "axis_angle_to_matrix_np",
    "matrix_to_axis_angle_scipy",
    "matrix_to_axis_angle_np",
    "matrix_to_axis_angle_acos_np",
    "quaternion_to_matrix_np",
    "rot6d_to_matrix_np",
    "axis_rotation_np",
    "euler_deg_to_matrix_np",
    "matrix_to_euler_deg_np",
]


def _check_last(x: Tensor, dims: tuple[int, ...], name: str) -> None:
    if tuple(x.shape[-len(dims):]) != dims:
        raise ValueError(f"Invalid {name} shape {tuple(x.shape)}; expected (..., {', '.join(map(str, dims))}).")


def skew_matrix(v: Tensor) -> Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrix: ``skew_matrix(v) @ x = v x x``."""
    import torch

    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*v.shape[:-1], 3, 3)


def axis_angle_to_matrix(axis_angle: Tensor) -> Tensor:
    """Rodrigues' formula, stable at zero angle. (..., 3) -> (..., 3, 3)."""
    import torch

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
    import torch

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
    import torch

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
    import torch

    _check_last(axis_angle, (3,), "axis-angle")
    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True)
    small = theta2 < 1e-8
    theta = torch.where(small, torch.ones_like(theta2), theta2).sqrt()
    half_sinc = torch.where(small, 0.5 - theta2 / 48, torch.sin(theta / 2) / theta)
    w = torch.where(small, 1 - theta2 / 8, torch.cos(theta / 2))
    return torch.cat([w, axis_angle * half_sinc], dim=-1)


def quaternion_to_axis_angle(quaternion: Tensor) -> Tensor:
    """(..., 4) (w, x, y, z) -> (..., 3) axis-angle with angle in [0, pi]."""
    import torch

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
    import torch

    _check_last(matrix, (3, 3), "rotation matrix")
    return torch.cat([matrix[..., :, 0], matrix[..., :, 1]], dim=-1)


def rot6d_to_matrix(rot6d: Tensor) -> Tensor:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt on the two columns (ProtoRes eq. 14)."""
    import torch

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
    import torch

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
    import torch

    _check_last(R_a, (3, 3), "rotation matrix")
    _check_last(R_b, (3, 3), "rotation matrix")
    rel = R_a.transpose(-1, -2) @ R_b
    cos = (rel[..., 0, 0] + rel[..., 1, 1] + rel[..., 2, 2] - 1) / 2
    skew = torch.stack(
        [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], dim=-1
    )
    sin = ((skew * skew).sum(-1) + 1e-30).sqrt() / 2
    return torch.atan2(sin, cos)


# ----------------------------------------------------------------------------- numpy twins (float64 unless noted)


def quat_wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """(..., 4) scalar-first ``(w, x, y, z)`` -> scalar-last ``(x, y, z, w)`` (a copy)."""
    q = np.asarray(q)
    return np.concatenate([q[..., 1:], q[..., :1]], -1)


def quat_xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    """(..., 4) scalar-last ``(x, y, z, w)`` -> scalar-first ``(w, x, y, z)`` (a copy)."""
    q = np.asarray(q)
    return np.concatenate([q[..., 3:], q[..., :3]], -1)


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) ``(w, x, y, z)`` quaternions, any non-zero norm -> (..., 3, 3) rotation matrices (scipy)."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(quat_wxyz_to_xyzw(q).reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit ``(w, x, y, z)`` quaternions (scipy's sign, ``w >= 0``)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    return quat_xyzw_to_wxyz(Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(*R.shape[:-2], 4))


def axis_angle_to_matrix_np(aa: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle -> (..., 3, 3) rotation matrices (scipy)."""
    from scipy.spatial.transform import Rotation

    aa = np.asarray(aa, dtype=np.float64)
    return Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(*aa.shape[:-1], 3, 3)


def matrix_to_axis_angle_scipy(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle, angle in [0, pi] (scipy; see
    :func:`matrix_to_axis_angle_np` for a faster one equal to it within 1e-12)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-2], 3)


def _axis_angle_shepperd(m: np.ndarray) -> np.ndarray:
    """Axis-angle via the quaternion of Shepperd's method (the branch with the largest pivot, stable
    everywhere, pi included). (..., 3, 3) float64 -> (..., 3)."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    cands = np.stack([  # (x, y, z, w) candidates, each proportional to the quaternion
        np.stack([1 + 2 * m00 - tr, m01 + m10, m02 + m20, m21 - m12], -1),
        np.stack([m01 + m10, 1 + 2 * m11 - tr, m12 + m21, m02 - m20], -1),
        np.stack([m02 + m20, m12 + m21, 1 + 2 * m22 - tr, m10 - m01], -1),
        np.stack([m21 - m12, m02 - m20, m10 - m01, 1 + tr], -1),
    ], -2)
    pick = np.stack([m00, m11, m22, tr], -1).argmax(-1)
    q = np.take_along_axis(cands, pick[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:] < 0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 3])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0 / np.maximum(q[..., 3], 1e-12))
    return q[..., :3] * scale[..., None]


_VEE_PLUS = ([2, 0, 1], [1, 2, 0])
_VEE_MINUS = ([1, 2, 0], [2, 0, 1])


def matrix_to_axis_angle_np(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angle (..., 3), angle in [0, pi] (numpy, float64).

    ``angle = atan2(|v|, (tr R - 1) / 2)`` along ``v = vee(R - R^T) / 2`` (``sin(angle) * axis``), which is
    exact to rounding up to 120 degrees; rotations beyond that (where ``v`` loses the axis's precision) go
    through Shepperd's quaternion method. About 5x faster than scipy's ``Rotation.from_matrix().as_rotvec()``
    for the 24 rotations of one pose, equal to it within 1e-12 (tested).
    """
    m = np.asarray(R, dtype=np.float64)
    v = 0.5 * (m[..., _VEE_PLUS[0], _VEE_PLUS[1]] - m[..., _VEE_MINUS[0], _VEE_MINUS[1]])
    cos = 0.5 * (np.trace(m, axis1=-2, axis2=-1) - 1.0)
    s = np.sqrt((v * v).sum(-1))
    scale = np.arctan2(s, cos) / np.where(s > 1e-300, s, 1.0)
    aa = v * np.where(s > 1e-300, scale, 1.0)[..., None]
    wide = cos < -0.5
    if wide.any():
        aa[wide] = _axis_angle_shepperd(m[wide])
    return aa


def matrix_to_axis_angle_acos_np(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) axis-angle by ``arccos`` (the log map in the input's dtype; adequate away from
    pi, as the tracker's anomaly score needs, and cheaper than :func:`matrix_to_axis_angle_np`)."""
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(angle)
    scale = np.where(s > 1e-6, angle / (2.0 * np.maximum(s, 1e-6)), 0.5)
    return v * scale[..., None]


def quaternion_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), any non-zero norm -> (..., 3, 3), in the input's dtype (the formula
    of :func:`quaternion_to_matrix`)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                  2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                  2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)
    return m.reshape(*q.shape[:-1], 3, 3)


def rot6d_to_matrix_np(r: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 3, 3), Gram-Schmidt on the two columns (as :func:`rot6d_to_matrix`), input dtype."""
    a1, a2 = r[..., :3], r[..., 3:]
    b1 = a1 / np.maximum(np.linalg.norm(a1, axis=-1, keepdims=True), 1e-8)
    a2 = a2 - (b1 * a2).sum(-1, keepdims=True) * b1
    b2 = a2 / np.maximum(np.linalg.norm(a2, axis=-1, keepdims=True), 1e-8)
    b3 = b1[..., [1, 2, 0]] * b2[..., [2, 0, 1]] - b1[..., [2, 0, 1]] * b2[..., [1, 2, 0]]
    return np.stack([b1, b2, b3], axis=-1)


def axis_rotation_np(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: unit axes (..., 3), angles (...) -> (..., 3, 3)."""
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def euler_deg_to_matrix_np(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in degrees (BVH channels) -> matrices (scipy).

    angles (..., len(order)), order e.g. ``"ZYX"`` (0 to 3 distinct axes) -> (..., 3, 3)."""
    shape = angles_deg.shape[:-1]
    if not order:
        return np.broadcast_to(np.eye(3), shape + (3, 3)).copy()
    from scipy.spatial.transform import Rotation

    flat = angles_deg.reshape(-1, len(order))
    return Rotation.from_euler(order.upper(), flat, degrees=True).as_matrix().reshape(shape + (3, 3))


def matrix_to_euler_deg_np(R: np.ndarray, order: str) -> np.ndarray:
    """Inverse of :func:`euler_deg_to_matrix_np` for a full 3-axis order. (..., 3, 3) -> (..., 3) degrees."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler(order.upper(), degrees=True).reshape(shape + (3,))
