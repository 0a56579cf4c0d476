"""The effector refinement of :mod:`smplik.refine` as numba kernels (the ``"fast"`` backend).

Same algorithm as :func:`smplik.refine.refine_output_reference` (same residuals, weights, prior,
Levenberg-Marquardt accept/reject rule and lambda schedule, same failure handling), per pose in
float64 scalar code, with the normal equations solved through the tree sparsity instead of a dense
``(3J + 3)`` Cholesky factorisation:

``A = D + J^T W J`` with ``D = (prior_j + lambda) I`` on joint j's 3 rotation parameters and ``lambda I`` on the
translation, and ``J`` only 3N rows (N effectors). With ``U = S J_rot`` (``S = W^(1/2)``, so zero-weight
padded rows are harmless), ``V = S J_transl`` and ``K = I + U D^-1 U^T`` (3N x 3N, eigenvalues >= 1, so
its Cholesky factorisation fails only on non-finite numbers), block elimination of the translation
with the Woodbury identity gives

* with ``K = L L^T``: ``y = L^-1 U D^-1 g_rot``, ``Z = L^-1 V``;
* translation: ``(lambda I + Z^T Z) x_t = g_t - Z^T y`` (3 x 3; positive definite when lambda > 0);
* rotations: ``x_rot = D^-1 (g_rot - U^T L^-T (y + Z x_t))``; the step is ``delta = -x``.

Effector ``i``'s rows of ``J_rot`` are non-zero only on the ancestor chain of its joint (at most 9
joints for SMPL), so ``U U^T`` block ``(a, b)`` sums over the common ancestors of the two joints only
(a prefix of both chains, from the root).

Kernels are ``nogil``: :func:`refine_arrays` splits large batches over ``torch.get_num_threads()``
threads (each pose is independent, so the result equals one chunk's bit for bit). ``cache=True`` keeps
the compiled code next to this module (or in numba's user cache directory when that is read-only).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np
import torch

from smplik.conventions import tree_depth
from smplik.threads import run_spread

CHUNK_MIN = 64
"""Batches of at least this many poses per thread are split over ``torch.get_num_threads()`` threads."""

_POS, _ROT, _LOOK = 0, 1, 2  # smplik.conventions.EffectorType values


@lru_cache(maxsize=16)
def skeleton_tables(parents: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-skeleton constants of the kernel, cached per parent tuple.

    Returns ``(parent (J,), order (J,), chain (J, L), chain_len (J,), common (J, J))``: ``parent`` with the
    root its own (0), ``order`` the joints parents first, ``chain[k, :chain_len[k]]`` joint ``k``'s inclusive
    ancestors from the root, and ``common[a, b]`` how many leading entries the chains of ``a`` and ``b`` share.
    """
    J = len(parents)
    depth = tree_depth(parents)
    chains = []
    for k in range(J):
        chain = [k]
        while parents[chain[-1]] >= 0:
            chain.append(parents[chain[-1]])
        chains.append(chain[::-1])
    L = max(len(c) for c in chains)
    chain_arr = np.zeros((J, L), np.int64)
    for k, c in enumerate(chains):
        chain_arr[k, :len(c)] = c
    common = np.zeros((J, J), np.int64)
    for a in range(J):
        for b in range(J):
            n = 0
            while n < min(len(chains[a]), len(chains[b])) and chains[a][n] == chains[b][n]:
                n += 1
            common[a, b] = n
    order = np.array(sorted(range(J), key=lambda j: depth[j]), np.int64)
    parent = np.array([max(p, 0) for p in parents], np.int64)
    return parent, order, chain_arr, np.array([len(c) for c in chains], np.int64), common


def _jit(fn):
    """``numba.njit`` (nogil, strict IEEE arithmetic) with an on-disk cache; without one where numba finds no
    writable cache directory (a read-only install with an unwritable home: it then compiles once per process)."""
    try:
        return numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")(fn)
    except RuntimeError:  # numba: "cannot cache function ...: no locator available"
        return numba.njit(cache=False, nogil=True, fastmath=False, error_model="numpy")(fn)


@_jit
def _rodrigues(v0, v1, v2, out):
    """``smplik.rotations.axis_angle_to_matrix`` of one vector (same small-angle Taylor branch) into out (3, 3)."""
    theta2 = v0 * v0 + v1 * v1 + v2 * v2
    if theta2 < 1e-8:
        a = 1.0 - theta2 / 6.0
        b = 0.5 - theta2 / 24.0
    else:
        theta = math.sqrt(theta2)
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta2
    # K = skew(v); K @ K = v v^T - theta2 I
    out[0, 0] = 1.0 + b * (v0 * v0 - theta2)
    out[1, 1] = 1.0 + b * (v1 * v1 - theta2)
    out[2, 2] = 1.0 + b * (v2 * v2 - theta2)
    out[0, 1] = -a * v2 + b * v0 * v1
    out[1, 0] = a * v2 + b * v0 * v1
    out[0, 2] = a * v1 + b * v0 * v2
    out[2, 0] = -a * v1 + b * v0 * v2
    out[1, 2] = -a * v0 + b * v1 * v2
    out[2, 1] = a * v0 + b * v1 * v2


@_jit
def _rot6d_T(d, out):
    """``rot6d_to_matrix(d)^T`` (Gram-Schmidt with eps 1e-8, like torch's normalize) into out (3, 3)."""
    n1 = max(math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), 1e-8)
    b10, b11, b12 = d[0] / n1, d[1] / n1, d[2] / n1
    dot = b10 * d[3] + b11 * d[4] + b12 * d[5]
    c0, c1, c2 = d[3] - dot * b10, d[4] - dot * b11, d[5] - dot * b12
    n2 = max(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), 1e-8)
    b20, b21, b22 = c0 / n2, c1 / n2, c2 / n2
    out[0, 0], out[0, 1], out[0, 2] = b10, b11, b12
    out[1, 0], out[1, 1], out[1, 2] = b20, b21, b22
    out[2, 0] = b11 * b22 - b12 * b21
    out[2, 1] = b12 * b20 - b10 * b22
    out[2, 2] = b10 * b21 - b11 * b20


@_jit
def _fk(R_local, J_rest, transl, parent, order, R_world, p_world):
    """``smplik.kinematics.forward_kinematics`` of one pose into R_world (J, 3, 3), p_world (J, 3)."""
    r = order[0]
    for i in range(3):
        for c in range(3):
            R_world[r, i, c] = R_local[r, i, c]
        p_world[r, i] = J_rest[r, i]
    for n in range(1, order.shape[0]):
        j = order[n]
        q = parent[j]
        for i in range(3):
            for c in range(3):
                R_world[j, i, c] = (R_world[q, i, 0] * R_local[j, 0, c] + R_world[q, i, 1] * R_local[j, 1, c]
                                    + R_world[q, i, 2] * R_local[j, 2, c])
        o0, o1, o2 = J_rest[j, 0] - J_rest[q, 0], J_rest[j, 1] - J_rest[q, 1], J_rest[j, 2] - J_rest[q, 2]
        for i in range(3):
            p_world[j, i] = p_world[q, i] + (R_world[q, i, 0] * o0 + R_world[q, i, 1] * o1 + R_world[q, i, 2] * o2)
    for j in range(order.shape[0]):
        for i in range(3):
            p_world[j, i] += transl[i]


@_jit
def _vee_product(A, B):
    """``vee(skew(A @ B))`` of two (3, 3) matrices: ``sin(angle) * axis`` when ``A @ B`` is a rotation."""
    m21 = A[2, 0] * B[0, 1] + A[2, 1] * B[1, 1] + A[2, 2] * B[2, 1]
    m12 = A[1, 0] * B[0, 2] + A[1, 1] * B[1, 2] + A[1, 2] * B[2, 2]
    m02 = A[0, 0] * B[0, 2] + A[0, 1] * B[1, 2] + A[0, 2] * B[2, 2]
    m20 = A[2, 0] * B[0, 0] + A[2, 1] * B[1, 0] + A[2, 2] * B[2, 0]
    m10 = A[1, 0] * B[0, 0] + A[1, 1] * B[1, 0] + A[1, 2] * B[2, 0]
    m01 = A[0, 0] * B[0, 1] + A[0, 1] * B[1, 1] + A[0, 2] * B[2, 1]
    return 0.5 * (m21 - m12), 0.5 * (m02 - m20), 0.5 * (m10 - m01)


@_jit
def _state_cost(R_local, R_net, R_world, p_world, joint, is_pos, is_rot, is_look, w, target, RtT, look_dir,
                prior, r, f, u, dist, dev):
    """Residuals r (N, 3), facing f, unit ray u, distance (N,), deviations dev (J, 3); returns the objective
    (``prior`` (J,): each joint's prior weight)."""
    N = joint.shape[0]
    total = 0.0
    for a in range(N):
        k = joint[a]
        for i in range(3):
            f[a, i] = R_world[k, i, 0] * look_dir[a, 0] + R_world[k, i, 1] * look_dir[a, 1] \
                + R_world[k, i, 2] * look_dir[a, 2]
        ray0, ray1, ray2 = target[a, 0] - p_world[k, 0], target[a, 1] - p_world[k, 1], target[a, 2] - p_world[k, 2]
        d = max(math.sqrt(ray0 * ray0 + ray1 * ray1 + ray2 * ray2), 1e-6)
        dist[a] = d
        u[a, 0], u[a, 1], u[a, 2] = ray0 / d, ray1 / d, ray2 / d
        v0, v1, v2 = _vee_product(R_world[k], RtT[a])  # vee(skew(R_k R_target^T))
        s = 0.0
        for i in range(3):
            vi = v0 if i == 0 else (v1 if i == 1 else v2)
            ri = is_pos[a] * (p_world[k, i] - target[a, i]) + is_rot[a] * vi + is_look[a] * (f[a, i] - u[a, i])
            r[a, i] = ri
            s += ri * ri
        total += w[a] * s
    for j in range(R_local.shape[0]):
        dev[j, 0], dev[j, 1], dev[j, 2] = _vee_product(R_local[j], R_net[j].T)
        total += prior[j] * (dev[j, 0] * dev[j, 0] + dev[j, 1] * dev[j, 1] + dev[j, 2] * dev[j, 2])
    return total


@_jit
def _cholesky(A, n):
    """In-place lower Cholesky factor of A[:n, :n]; False where a pivot is not positive (or not finite)."""
    for c in range(n):
        s = A[c, c]
        for m in range(c):
            s -= A[c, m] * A[c, m]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        A[c, c] = d
        for i in range(c + 1, n):
            t = A[i, c]
            for m in range(c):
                t -= A[i, m] * A[c, m]
            A[i, c] = t / d
    return True


@_jit
def _forward(L, n, x):
    """Solve L y = x in place for x (n,) (L lower triangular)."""
    for i in range(n):
        t = x[i]
        for m in range(i):
            t -= L[i, m] * x[m]
        x[i] = t / L[i, i]


@_jit
def _backward(L, n, x):
    """Solve L^T y = x in place for x (n,)."""
    for i in range(n - 1, -1, -1):
        t = x[i]
        for m in range(i + 1, n):
            t -= L[m, i] * x[m]
        x[i] = t / L[i, i]


@_jit
def refine_kernel(R_net, R_world0, p_world0, transl0, J_rest, joint, kind, data, tolerance, mask,
                  parent, order, chain, chain_len, common,
                  iterations, sigma_pos, sigma_rot, sigma_lookat, sigma_prior, damping, eta, joint_prior,
                  R_local_out, R_world_out, p_world_out, transl_out):
    """Refine B poses (module docstring); writes the four ``*_out`` arrays (B, ...) float64.

    R_net, R_world0 (B, J, 3, 3), p_world0 (B, J, 3), transl0 (B, 3), J_rest (B, J, 3); joint, kind (B, N)
    int64, data (B, N, 6), tolerance (B, N), mask (B, N) bool; skeleton tables of :func:`skeleton_tables`;
    joint_prior (J,) each joint's relative prior weight (``RefineConfig.joint_prior``, ones when None).
    """
    B, N = joint.shape
    J = R_net.shape[1]
    L = chain.shape[1]
    n3 = 3 * N
    prior = 1.0 / (sigma_prior * sigma_prior)
    prior_j = joint_prior * prior
    dr = np.empty(J)  # the diagonal D on each joint's rotation parameters: prior_j + lambda
    # scratch, reused for every pose
    is_pos, is_rot, is_look = np.empty(N), np.empty(N), np.empty(N)
    w, s_w = np.empty(N), np.empty(N)
    target, look_dir = np.empty((N, 3)), np.empty((N, 3))
    RtT = np.empty((N, 3, 3))
    six = np.empty(6)
    r, f, u, dist = np.empty((N, 3)), np.empty((N, 3)), np.empty((N, 3)), np.empty(N)
    dev = np.empty((J, 3))
    r_n, f_n, u_n, dist_n, dev_n = np.empty((N, 3)), np.empty((N, 3)), np.empty((N, 3)), np.empty(N), np.empty((J, 3))
    R_local, R_world, p_world, transl = np.empty((J, 3, 3)), np.empty((J, 3, 3)), np.empty((J, 3)), np.empty(3)
    R_local_n, R_world_n, p_world_n, transl_n = np.empty((J, 3, 3)), np.empty((J, 3, 3)), np.empty((J, 3)), np.empty(3)
    Jc = np.zeros((N, L, 3, 3))  # effector a's rotation Jacobian blocks along its chain
    Jt = np.empty((N, 3, 3))  # translation Jacobian blocks
    proj, lev, nf = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    g = np.empty((J + 1, 3))  # gradient: rotations, then translation
    K = np.empty((n3, n3))
    y = np.empty(n3)
    Z = np.empty((3, n3))  # L^-1 V, column by column
    Sc = np.empty((3, 3))
    xt = np.empty(3)
    q = np.empty(n3)
    x = np.empty((J, 3))
    Rwp = np.empty((J, 3, 3))
    dR = np.empty((3, 3))
    one_six = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    for b in range(B):
        # ---- per-pose constants: effector flags, weights, targets
        for a in range(N):
            on = mask[b, a]
            is_pos[a] = 1.0 if (on and kind[b, a] == _POS) else 0.0
            is_rot[a] = 1.0 if (on and kind[b, a] == _ROT) else 0.0
            is_look[a] = 1.0 if (on and kind[b, a] == _LOOK) else 0.0
            sig = 0.1 * tolerance[b, a] ** eta
            tw = min(1.0 / max(sig, 1e-12), 1000.0) / 1000.0
            w[a] = tw * (is_pos[a] / sigma_pos ** 2 + is_rot[a] / sigma_rot ** 2 + is_look[a] / sigma_lookat ** 2)
            s_w[a] = math.sqrt(w[a])
            for i in range(3):
                target[a, i] = data[b, a, i]
                look_dir[a, i] = data[b, a, 3 + i]
            for i in range(6):
                six[i] = data[b, a, i] * is_rot[a] + one_six[i] * (1.0 - is_rot[a])
            _rot6d_T(six, RtT[a])
        R_local[:] = R_net[b]
        R_world[:] = R_world0[b]
        p_world[:] = p_world0[b]
        transl[:] = transl0[b]
        current = _state_cost(R_local, R_net[b], R_world, p_world, joint[b], is_pos, is_rot, is_look, w, target,
                              RtT, look_dir, prior_j, r, f, u, dist, dev)
        lam = prior * damping
        for _ in range(iterations):
            # ---- Jacobian blocks along each effector's chain
            for a in range(N):
                k = joint[b, a]
                cp, cr, cl = is_pos[a], is_rot[a], is_look[a]
                for i in range(3):
                    for c in range(3):
                        proj[i, c] = ((1.0 if i == c else 0.0) - u[a, i] * u[a, c]) / dist[a]
                        Jt[a, i, c] = cp * (1.0 if i == c else 0.0) + cl * proj[i, c]
                f0, f1, f2 = f[a, 0], f[a, 1], f[a, 2]
                nf[0, 0], nf[0, 1], nf[0, 2] = 0.0, f2, -f1
                nf[1, 0], nf[1, 1], nf[1, 2] = -f2, 0.0, f0
                nf[2, 0], nf[2, 1], nf[2, 2] = f1, -f0, 0.0
                for m in range(chain_len[k]):
                    j = chain[k, m]
                    strict = 1.0 if j != k else 0.0
                    d0 = (p_world[k, 0] - p_world[j, 0]) * strict
                    d1 = (p_world[k, 1] - p_world[j, 1]) * strict
                    d2 = (p_world[k, 2] - p_world[j, 2]) * strict
                    # lever = -skew(p_k - p_j) (strict ancestors); -skew(f) for look-at rows
                    lev[0, 0], lev[0, 1], lev[0, 2] = 0.0, d2, -d1
                    lev[1, 0], lev[1, 1], lev[1, 2] = -d2, 0.0, d0
                    lev[2, 0], lev[2, 1], lev[2, 2] = d1, -d0, 0.0
                    for i in range(3):
                        for c in range(3):
                            Jc[a, m, i, c] = lev[i, c] * cp + (cr * (1.0 if i == c else 0.0) + cl * nf[i, c])
                    if cl != 0.0:  # look-at rows also move with the joint's position: d u / d p_k = -proj
                        for i in range(3):
                            for c in range(3):
                                Jc[a, m, i, c] += (proj[i, 0] * lev[0, c] + proj[i, 1] * lev[1, c]
                                                   + proj[i, 2] * lev[2, c])
            # ---- gradient g = J^T W r + prior e (e: deviations as world-frame increments)
            for j in range(J):
                if j == order[0]:
                    for i in range(3):
                        for c in range(3):
                            Rwp[j, i, c] = 1.0 if i == c else 0.0
                else:
                    Rwp[j] = R_world[parent[j]]
                for i in range(3):
                    g[j, i] = prior_j[j] * (Rwp[j, i, 0] * dev[j, 0] + Rwp[j, i, 1] * dev[j, 1]
                                            + Rwp[j, i, 2] * dev[j, 2])
            g[J, 0] = g[J, 1] = g[J, 2] = 0.0
            for a in range(N):
                k = joint[b, a]
                for m in range(chain_len[k]):
                    j = chain[k, m]
                    for c in range(3):
                        g[j, c] += w[a] * (Jc[a, m, 0, c] * r[a, 0] + Jc[a, m, 1, c] * r[a, 1]
                                           + Jc[a, m, 2, c] * r[a, 2])
                for c in range(3):
                    g[J, c] += w[a] * (Jt[a, 0, c] * r[a, 0] + Jt[a, 1, c] * r[a, 1] + Jt[a, 2, c] * r[a, 2])
            # ---- K = I + U D^-1 U^T over common ancestors
            for j in range(J):
                dr[j] = prior_j[j] + lam
            for a in range(N):
                ka = joint[b, a]
                for bb in range(a + 1):
                    kb = joint[b, bb]
                    sab = s_w[a] * s_w[bb]
                    for i in range(3):
                        for c in range(3):
                            t = 0.0
                            for m in range(common[ka, kb]):
                                t += (Jc[a, m, i, 0] * Jc[bb, m, c, 0] + Jc[a, m, i, 1] * Jc[bb, m, c, 1]
                                      + Jc[a, m, i, 2] * Jc[bb, m, c, 2]) / dr[chain[ka, m]]
                            val = sab * t + (1.0 if (a == bb and i == c) else 0.0)
                            K[3 * a + i, 3 * bb + c] = val
                            K[3 * bb + c, 3 * a + i] = val
            finite = True
            for i in range(n3):
                for c in range(n3):
                    if not math.isfinite(K[i, c]):
                        finite = False
            for j in range(J + 1):
                for i in range(3):
                    if not math.isfinite(g[j, i]):
                        finite = False
            factored = finite and _cholesky(K, n3)
            if factored:
                # with K = L L^T: y = L^-1 U D^-1 g_rot, Z = L^-1 V
                for a in range(N):
                    k = joint[b, a]
                    for i in range(3):
                        t = 0.0
                        for m in range(chain_len[k]):
                            j = chain[k, m]
                            t += (Jc[a, m, i, 0] * g[j, 0] + Jc[a, m, i, 1] * g[j, 1]
                                  + Jc[a, m, i, 2] * g[j, 2]) / dr[j]
                        y[3 * a + i] = s_w[a] * t
                        for c in range(3):
                            Z[c, 3 * a + i] = s_w[a] * Jt[a, i, c]
                _forward(K, n3, y)
                for c in range(3):
                    _forward(K, n3, Z[c])
                # translation: (lam I + Z^T Z) x_t = g_t - Z^T y
                for c in range(3):
                    t = g[J, c]
                    for i in range(n3):
                        t -= Z[c, i] * y[i]
                    xt[c] = t
                    for c2 in range(3):
                        t = lam if c == c2 else 0.0
                        for i in range(n3):
                            t += Z[c, i] * Z[c2, i]
                        Sc[c, c2] = t
                factored = _cholesky(Sc, 3)
            if factored:
                _forward(Sc, 3, xt)
                _backward(Sc, 3, xt)
                # rotations: x_rot = D^-1 (g_rot - U^T L^-T (y + Z x_t))
                for i in range(n3):
                    q[i] = y[i] + Z[0, i] * xt[0] + Z[1, i] * xt[1] + Z[2, i] * xt[2]
                _backward(K, n3, q)
                for j in range(J):
                    for i in range(3):
                        x[j, i] = g[j, i]
                for a in range(N):
                    k = joint[b, a]
                    for m in range(chain_len[k]):
                        j = chain[k, m]
                        for c in range(3):
                            x[j, c] -= s_w[a] * (Jc[a, m, 0, c] * q[3 * a] + Jc[a, m, 1, c] * q[3 * a + 1]
                                                 + Jc[a, m, 2, c] * q[3 * a + 2])
                for j in range(J):
                    for i in range(3):
                        x[j, i] = x[j, i] / dr[j]
                        if not math.isfinite(x[j, i]):
                            factored = False
                for i in range(3):
                    if not math.isfinite(xt[i]):
                        factored = False
            ok = False
            new = 0.0
            if factored:
                # delta = -x; local increment R_world_parent^T delta_j, applied on the left
                for j in range(J):
                    l0 = -(Rwp[j, 0, 0] * x[j, 0] + Rwp[j, 1, 0] * x[j, 1] + Rwp[j, 2, 0] * x[j, 2])
                    l1 = -(Rwp[j, 0, 1] * x[j, 0] + Rwp[j, 1, 1] * x[j, 1] + Rwp[j, 2, 1] * x[j, 2])
                    l2 = -(Rwp[j, 0, 2] * x[j, 0] + Rwp[j, 1, 2] * x[j, 1] + Rwp[j, 2, 2] * x[j, 2])
                    _rodrigues(l0, l1, l2, dR)
                    for i in range(3):
                        for c in range(3):
                            R_local_n[j, i, c] = (dR[i, 0] * R_local[j, 0, c] + dR[i, 1] * R_local[j, 1, c]
                                                  + dR[i, 2] * R_local[j, 2, c])
                for i in range(3):
                    transl_n[i] = transl[i] - xt[i]
                _fk(R_local_n, J_rest[b], transl_n, parent, order, R_world_n, p_world_n)
                new = _state_cost(R_local_n, R_net[b], R_world_n, p_world_n, joint[b], is_pos, is_rot, is_look, w,
                                  target, RtT, look_dir, prior_j, r_n, f_n, u_n, dist_n, dev_n)
                ok = new < current and math.isfinite(new)
            if ok:
                R_local[:] = R_local_n
                R_world[:] = R_world_n
                p_world[:] = p_world_n
                transl[:] = transl_n
                r[:] = r_n
                f[:] = f_n
                u[:] = u_n
                dist[:] = dist_n
                dev[:] = dev_n
                current = new
                lam = lam * 0.3
            else:
                lam = lam * 10.0
        R_local_out[b] = R_local
        R_world_out[b] = R_world
        p_world_out[b] = p_world
        transl_out[b] = transl


def refine_arrays(R_net: np.ndarray, R_world: np.ndarray, p_world: np.ndarray, transl: np.ndarray,
                  J_rest: np.ndarray, joint: np.ndarray, kind: np.ndarray, data: np.ndarray, tolerance: np.ndarray,
                  mask: np.ndarray, parents: tuple[int, ...], cfg, threads: int | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Run :func:`refine_kernel` on C-contiguous float64 / int64 / bool arrays (shapes in its docstring).

    ``cfg``: a :class:`smplik.refine.RefineConfig`. ``threads`` (default ``torch.get_num_threads()``):
    batches of at least ``CHUNK_MIN`` poses per thread run in that many chunks, one per thread.
    Returns ``(R_local, R_world, p_world, transl)``, new float64 arrays.
    """
    tables = skeleton_tables(tuple(parents))
    B = R_net.shape[0]
    outs = (np.empty_like(R_net), np.empty_like(R_world), np.empty_like(p_world), np.empty_like(transl))
    params = (int(cfg.iterations), float(cfg.sigma_pos), float(cfg.sigma_rot), float(cfg.sigma_lookat),
              float(cfg.sigma_prior), float(cfg.damping), float(cfg.tolerance_eta),
              cfg.joint_prior_array(len(parents)))
    ins = (R_net, R_world, p_world, transl, J_rest, joint, kind, data, tolerance, mask)

    def run(lo: int, hi: int) -> None:
        refine_kernel(*(a[lo:hi] for a in ins), *tables, *params, *(o[lo:hi] for o in outs))

    threads = torch.get_num_threads() if threads is None else threads
    chunks = max(1, min(threads, B // CHUNK_MIN))
    if chunks == 1:
        refine_kernel(*ins, *tables, *params, *outs)
    else:
        run_spread(run, np.linspace(0, B, chunks + 1).astype(int), chunks)
    return outs
