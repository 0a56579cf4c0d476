"""The per-frame geometry of :class:`smplik.tracking.runtime.Tracker` as numba kernels (``pip install
'smplik[fast]'``): tracker features, 6D -> matrices + FK, the anomaly score and the two-bone leg IK of the foot
locks, in float64 scalar code. A frame is a few hundred numpy calls on 3-vectors otherwise, each a microsecond or
more of overhead; here each step is one call.

Each kernel is the same arithmetic as its numpy reference, which stays the fallback when numba is absent and which
``tests/test_tracking.py`` compares against: :func:`frame_features` (:func:`smplik.tracking.runtime.frame_features`
with :func:`smplik.rotations.quaternion_to_matrix_np`), :func:`decode_fk` (:func:`smplik.tracking.fast.decode_np`
then :func:`smplik.tracking.fast.fk_np`), :func:`anomaly_scores` (:func:`smplik.tracking.runtime.anomaly_scores`)
and :func:`two_bone_ik` (the animation pipeline's :func:`smplik.limb_ik.two_bone_ik`). ``cache=True``
keeps the compiled code next to this module (or in numba's user cache directory when that is read-only).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True)


@_jit
def _yaw_apply(c: float, s: float, v0: float, v1: float, v2: float) -> tuple[float, float, float]:
    """Rotation about +y by the angle with cosine c, sine s applied to (v0, v1, v2)."""
    return c * v0 + s * v2, v1, -s * v0 + c * v2


@_jit
def frame_features(p: np.ndarray, q: np.ndarray, p_prev: np.ndarray, yaw_prev: float, has_rot: np.ndarray,
                   fps: float, first: bool, x: np.ndarray, R: np.ndarray) -> tuple[float, float, float]:
    """One frame's features into ``x`` (K * 13 + 2,) and the tracker rotations into ``R`` (K, 3, 3).

    p (K, 3), q (K, 4) (w, x, y, z) any non-zero norm, p_prev (K, 3), has_rot (K,) bool. ``first``: no previous
    frame (zero velocity, no heading change). Returns ``(yaw, origin x, origin z)``.
    """
    K = p.shape[0]
    for k in range(K):
        n = math.sqrt(q[k, 0] ** 2 + q[k, 1] ** 2 + q[k, 2] ** 2 + q[k, 3] ** 2)
        w, a, b, c = q[k, 0] / n, q[k, 1] / n, q[k, 2] / n, q[k, 3] / n
        R[k, 0, 0] = 1 - 2 * (b * b + c * c)
        R[k, 0, 1] = 2 * (a * b - c * w)
        R[k, 0, 2] = 2 * (a * c + b * w)
        R[k, 1, 0] = 2 * (a * b + c * w)
        R[k, 1, 1] = 1 - 2 * (a * a + c * c)
        R[k, 1, 2] = 2 * (b * c - a * w)
        R[k, 2, 0] = 2 * (a * c - b * w)
        R[k, 2, 1] = 2 * (b * c + a * w)
        R[k, 2, 2] = 1 - 2 * (a * a + b * b)
    yaw = math.atan2(R[0, 0, 2], R[0, 2, 2])
    c, s = math.cos(-yaw), math.sin(-yaw)
    ox, oz = p[0, 0], p[0, 2]
    for k in range(K):
        o = 13 * k
        x[o], x[o + 1], x[o + 2] = _yaw_apply(c, s, p[k, 0] - ox, p[k, 1], p[k, 2] - oz)
        if first:
            x[o + 3], x[o + 4], x[o + 5] = 0.0, 0.0, 0.0
        else:
            v0, v1, v2 = _yaw_apply(c, s, (p[k, 0] - p_prev[k, 0]) * fps, (p[k, 1] - p_prev[k, 1]) * fps,
                                    (p[k, 2] - p_prev[k, 2]) * fps)
            x[o + 3], x[o + 4], x[o + 5] = 0.1 * v0, 0.1 * v1, 0.1 * v2
        m = 1.0 if has_rot[k] else 0.0
        for col in range(2):
            r0, r1, r2 = _yaw_apply(c, s, R[k, 0, col], R[k, 1, col], R[k, 2, col])
            x[o + 6 + 3 * col], x[o + 7 + 3 * col], x[o + 8 + 3 * col] = m * r0, m * r1, m * r2
        x[o + 12] = m
    d = 0.0 if first else yaw - yaw_prev
    x[13 * K] = math.sin(d)
    x[13 * K + 1] = math.cos(d)
    return yaw, ox, oz


@_jit
def decode_fk(out: np.ndarray, yaw: float, origin: np.ndarray, J: np.ndarray, parents: np.ndarray,
              R: np.ndarray, transl: np.ndarray, prob: np.ndarray, G: np.ndarray, p: np.ndarray) -> None:
    """Network outputs (N, OUT_DIM) of one frame -> ``R`` (N, 24, 3, 3) local rotations (root in world),
    ``transl`` (N, 3), ``prob`` (N, 2) contact probabilities, and their FK on rest joints ``J`` (24, 3):
    ``G`` (N, 24, 3, 3) world rotations, ``p`` (N, 24, 3) joints. ``parents`` (24,) with the root's -1 (parents
    before children)."""
    N, nj = out.shape[0], J.shape[0]
    c, s = math.cos(yaw), math.sin(yaw)
    for n in range(N):
        for j in range(nj):
            o = 6 * j
            a0, a1, a2 = out[n, o], out[n, o + 1], out[n, o + 2]
            na = max(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2), 1e-8)
            b0, b1, b2 = a0 / na, a1 / na, a2 / na
            e0, e1, e2 = out[n, o + 3], out[n, o + 4], out[n, o + 5]
            d = b0 * e0 + b1 * e1 + b2 * e2
            e0, e1, e2 = e0 - d * b0, e1 - d * b1, e2 - d * b2
            ne = max(math.sqrt(e0 * e0 + e1 * e1 + e2 * e2), 1e-8)
            e0, e1, e2 = e0 / ne, e1 / ne, e2 / ne
            f0, f1, f2 = b1 * e2 - b2 * e1, b2 * e0 - b0 * e2, b0 * e1 - b1 * e0
            if j == 0:  # the root: from the heading frame to the world
                b0, b1, b2 = _yaw_apply(c, s, b0, b1, b2)
                e0, e1, e2 = _yaw_apply(c, s, e0, e1, e2)
                f0, f1, f2 = _yaw_apply(c, s, f0, f1, f2)
            R[n, j, 0, 0], R[n, j, 1, 0], R[n, j, 2, 0] = b0, b1, b2
            R[n, j, 0, 1], R[n, j, 1, 1], R[n, j, 2, 1] = e0, e1, e2
            R[n, j, 0, 2], R[n, j, 1, 2], R[n, j, 2, 2] = f0, f1, f2
        q0, q1, q2 = _yaw_apply(c, s, out[n, 6 * nj], out[n, 6 * nj + 1], out[n, 6 * nj + 2])
        p[n, 0, 0], p[n, 0, 1], p[n, 0, 2] = q0 + origin[0], q1 + origin[1], q2 + origin[2]
        for i in range(3):
            transl[n, i] = p[n, 0, i] - J[0, i]
        for i in range(2):
            prob[n, i] = 1.0 / (1.0 + math.exp(-out[n, 6 * nj + 3 + i]))
        G[n, 0] = R[n, 0]
        for j in range(1, nj):
            a = parents[j]
            for r in range(3):
                for col in range(3):
                    G[n, j, r, col] = (G[n, a, r, 0] * R[n, j, 0, col] + G[n, a, r, 1] * R[n, j, 1, col]
                                       + G[n, a, r, 2] * R[n, j, 2, col])
                p[n, j, r] = p[n, a, r] + (G[n, a, r, 0] * (J[j, 0] - J[a, 0]) + G[n, a, r, 1] * (J[j, 1] - J[a, 1])
                                           + G[n, a, r, 2] * (J[j, 2] - J[a, 2]))


@_jit
def anomaly_scores(R: np.ndarray, p: np.ndarray, lo: np.ndarray, hi: np.ndarray, floor_y: float, below_m: float,
                   cross_min: float, cross_pairs: np.ndarray, margin: float) -> np.ndarray:
    """As :func:`smplik.tracking.runtime.anomaly_scores`: R (N, 24, 3, 3), p (N, 24, 3), lo/hi (24, 3), cross_pairs
    (P, 2) -> (N,)."""
    N, nj = R.shape[0], R.shape[1]
    out = np.zeros(N)
    for n in range(N):
        below = 0.0
        for j in range(nj):
            below += max(floor_y - below_m - p[n, j, 1], 0.0)
        cross = 0.0
        for i in range(cross_pairs.shape[0]):
            a, b = cross_pairs[i, 0], cross_pairs[i, 1]
            d = math.sqrt((p[n, a, 0] - p[n, b, 0]) ** 2 + (p[n, a, 1] - p[n, b, 1]) ** 2
                          + (p[n, a, 2] - p[n, b, 2]) ** 2)
            cross += max(cross_min - d, 0.0)
        rng = 0.0
        for j in range(1, nj):
            cos = min(max((R[n, j, 0, 0] + R[n, j, 1, 1] + R[n, j, 2, 2] - 1.0) / 2.0, -1.0), 1.0)
            angle = math.acos(cos)
            sn = math.sin(angle)
            scale = angle / (2.0 * max(sn, 1e-6)) if sn > 1e-6 else 0.5
            v = ((R[n, j, 2, 1] - R[n, j, 1, 2]) * scale, (R[n, j, 0, 2] - R[n, j, 2, 0]) * scale,
                 (R[n, j, 1, 0] - R[n, j, 0, 1]) * scale)
            for i in range(3):
                rng += max(lo[j, i] - margin - v[i], 0.0) + max(v[i] - hi[j, i] - margin, 0.0)
        out[n] = below + cross + 0.1 * rng
    return out


@_jit
def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


@_jit
def _norm(v: np.ndarray) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


@_jit
def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis[0], axis[1], axis[2]
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


@_jit
def two_bone_ik(p_a: np.ndarray, p_b: np.ndarray, p_c: np.ndarray, target: np.ndarray, bend_axis: np.ndarray,
                eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """:func:`smplik.limb_ik.two_bone_ik` for (n, 3) float64 rows -> ``(R_a, R_b)`` (n, 3, 3)."""
    n = p_a.shape[0]
    R_a, R_b = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    for i in range(n):
        a, b, c, t = p_a[i], p_b[i], p_c[i], target[i]
        l_ab, l_bc = _norm(b - a), _norm(c - b)
        l_at = min(max(_norm(t - a), abs(l_ab - l_bc) + eps), l_ab + l_bc - eps)
        u, v = a - b, c - b
        cr = _cross(u, v)
        n_len = _norm(cr)
        if n_len > 1e-9 * max(l_ab * l_bc, 1e-12):
            normal = cr / max(n_len, 1e-12)
        else:
            normal = bend_axis[i] / max(_norm(bend_axis[i]), 1e-12)
        theta0 = math.atan2(n_len, u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
        cos1 = min(max((l_ab ** 2 + l_bc ** 2 - l_at ** 2) / (2.0 * l_ab * l_bc), -1.0), 1.0)
        R_b[i] = _rodrigues(normal, math.acos(cos1) - theta0)
        c1 = b + R_b[i] @ v
        f = c1 - a
        f = f / max(_norm(f), 1e-12)
        to = t - a
        to = to / max(_norm(to), 1e-12)
        sa = _cross(f, to)
        s_len = _norm(sa)
        swing = math.atan2(s_len, f[0] * to[0] + f[1] * to[1] + f[2] * to[2])
        if s_len > 1e-12:
            axis, angle = sa / s_len, swing
        else:  # parallel or antiparallel: any axis perpendicular to f
            ref = np.array([1.0, 0.0, 0.0]) if abs(f[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            axis = _cross(f, ref)
            axis = axis / max(_norm(axis), 1e-12)
            angle = swing if swing > 1.0 else 0.0
        R_a[i] = _rodrigues(axis, angle)
    return R_a, R_b
