"""Analytic two-bone IK on world positions (numpy): hip, knee, ankle or shoulder, elbow, wrist.

Used where joint positions are edited directly: foot locking (:func:`workflows.animation.clean.lock_feet`) and
the tracker runtime's limb fix-up (:mod:`smplik.tracking.runtime`). The torch version that works on a
local-rotation pose is :func:`smplik.benchmark.two_bone.two_bone_ik`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["two_bone_ik"]


def _axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: unit axes (..., 3), angles (...) -> (..., 3, 3)."""
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


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
    R_b = _axis_angle_matrix(normal, np.arccos(cos1) - theta0)
    c1 = p_b + (R_b @ v[..., None])[..., 0]
    from_dir, _ = _unit(c1 - p_a)
    to_dir, _ = _unit(target - p_a)
    swing_axis, s_len = _unit(np.cross(from_dir, to_dir))
    swing = _angle(from_dir, to_dir)
    # antiparallel: any axis perpendicular to from_dir
    perp, _ = _unit(np.cross(from_dir, np.where(np.abs(from_dir[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0])))
    swing_axis = np.where((s_len > 1e-12)[..., None], swing_axis, perp)
    R_a = _axis_angle_matrix(swing_axis, np.where(s_len > 1e-12, swing, np.where(swing > 1.0, swing, 0.0)))
    return R_a, R_b
