"""``ProtoResIK.forward`` as one numba kernel: the network for a few poses at a fraction of a graph call's cost.

A one-pose call through onnxruntime spends most of its ~0.2-0.4 ms in per-operator overhead (about 170 nodes
after its optimisations, :mod:`smplik.network_folded`); the arithmetic is ~2.5 MFLOP. This kernel runs the
same function (:mod:`smplik.network`, eq. numbers there) in one compiled call: every layer is one
``np.dot`` (BLAS ``sgemm``) on the ``(B N, C)`` token or ``(B, C)`` pose matrix, everything else (tokens,
prototype subtraction, masked means, Gram-Schmidt, J(beta, gender), FK) is loops. It is float32 like the
ONNX graph and agrees with the torch network within 1e-5 (tested). Batches of at least ``2 *``
:data:`CHUNK_ROWS` rows are split into chunks spread over threads (the kernel is ``nogil``).

:class:`NumbaNetwork` has :class:`~smplik.onnx_runtime.OnnxNetwork`'s interface (``__call__``,
``run_arrays``, ``threads``, ``with_threads``); the solver's onnxruntime network hands it the calls of at
most :data:`smplik.onnx_runtime.SMALL_TOKENS` effector tokens, one pose of up to 16 effectors, where it takes
about half the time of a session call (:func:`smplik.onnx_runtime.select_network`). Larger calls stay with
onnxruntime's graph, which is faster per pose from a few poses on. The first call in a new installation
compiles the kernel (cached on disk, as :mod:`smplik.refine_fast`'s).
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from torch import Tensor

from smplik.conventions import NUM_BETAS, PARENTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.network import NUM_GENDERS, FCRDecoder, IKOutput, ProtoResIK, ResidualBlock
from smplik.threads import run_spread

CHUNK_ROWS = 128
"""Batches of at least ``2 * CHUNK_ROWS`` rows run as chunks of this many rows spread over the threads."""
_POS, _ROT = int(EffectorType.POSITION), int(EffectorType.ROTATION)
_EPS = np.float32(1e-8)  # Gram-Schmidt's norm floor, as smplik.rotations.rot6d_to_matrix


@numba.njit(cache=True, nogil=True)
def _matmul(x, W):
    """x (R, in) @ W (in, out): BLAS ``sgemm`` (scipy's, through numba). At the sizes the solver calls this
    kernel for (:data:`smplik.onnx_runtime.SMALL_TOKENS` effector tokens or fewer: at most 65,536 x 4
    multiply-adds per product) OpenBLAS runs single-threaded, and 3x faster than a compiled loop."""
    return np.dot(x, W)


@numba.njit(cache=True, nogil=True)
def _linear(x, W, b, relu):
    """x (R, in) @ W (in, out) + b, optionally ReLU'd; a new (R, out) array."""
    y = _matmul(x, W)
    for i in range(y.shape[0]):
        for c in range(y.shape[1]):
            v = y[i, c] + b[c]
            y[i, c] = v if (not relu or v > 0) else np.float32(0.0)
    return y


@numba.njit(cache=True, nogil=True)
def _block(x, Ws, bs, prog):
    """A residual block (ProtoRes Fig. 4) on x (R, in): returns (b = relu(skip x + h) or x, h)."""
    h = x
    for k in range(prog[1]):
        h = _linear(h, Ws[prog[0] + k], bs[prog[0] + k], True)
    if prog[2] < 0:
        return x, h
    s = _linear(x, Ws[prog[2]], bs[prog[2]], False)
    for i in range(s.shape[0]):
        for c in range(s.shape[1]):
            v = s[i, c] + h[i, c]
            s[i, c] = v if v > 0 else np.float32(0.0)
    return s, h


@numba.njit(cache=True, nogil=True)
def _decode(x, Ws, bs, prog):
    """FCR decoder (eq. 6-7): outputs of every block's forward layer, summed. x (B, in) -> (B, out)."""
    out = np.zeros((x.shape[0], Ws[prog[0, 3]].shape[1]), np.float32)
    for r in range(prog.shape[0]):
        x, h = _block(x, Ws, bs, prog[r])
        out += _linear(h, Ws[prog[r, 3]], bs[prog[r, 3]], False)
    return out


@numba.njit(cache=True, nogil=True)
def forward_kernel(joint, kind, data, tolerance, mask, betas, gender, Ws, bs, enc_prog, gpd_prog, ikd_prog,
                   E_joint, E_type, J_template, J_dirs, parents, identity_6d,
                   R_local, R_world, p_world, draft_out, transl):
    """The network on B rows of N effectors; writes R_local/R_world (B, J, 3, 3), p_world/draft_out (B, J, 3),
    transl (B, 3).

    ``Ws``/``bs``: every layer's weight as (in, out) and bias; ``*_prog`` (blocks, 4) int rows
    ``[first hidden layer, hidden layers, skip layer or -1, forward layer]`` into them. ``E_joint`` (J, E),
    ``E_type`` (3, E), ``J_template`` (3, J, 3), ``J_dirs`` (3, J, 3, 10), ``identity_6d`` (6 J,).
    """
    B, N = joint.shape
    J = parents.shape[0]
    E = E_joint.shape[1]
    nb = betas.shape[1]
    ng = J_template.shape[0]
    cond = np.zeros((B, nb + ng), np.float32)
    centroid = np.zeros((B, 3), np.float32)
    weight = np.zeros((B, N), np.float32)  # masked mean weights
    x = np.zeros((B * N, 7 + 2 * E + nb + ng), np.float32)
    for i in range(B):
        count = np.float32(0.0)
        for n in range(N):
            if mask[i, n] and kind[i, n] == _POS:
                count += 1
                for c in range(3):
                    centroid[i, c] += data[i, n, c]
        for c in range(3):
            centroid[i, c] /= max(count, np.float32(1.0))
        for k in range(nb):
            cond[i, k] = betas[i, k]
        cond[i, nb + gender[i]] = 1.0
        real = np.float32(0.0)
        for n in range(N):
            real += np.float32(1.0) if mask[i, n] else np.float32(0.0)
        for n in range(N):
            row = i * N + n
            weight[i, n] = (np.float32(1.0) if mask[i, n] else np.float32(0.0)) / max(real, np.float32(1.0))
            shift = kind[i, n] != _ROT
            for c in range(6):
                x[row, c] = data[i, n, c] - (centroid[i, c] if shift and c < 3 else np.float32(0.0))
            x[row, 6] = tolerance[i, n]
            for e in range(E):
                x[row, 7 + e] = E_joint[joint[i, n], e]
                x[row, 7 + E + e] = E_type[kind[i, n], e]
            for k in range(nb + ng):
                x[row, 7 + 2 * E + k] = cond[i, k]
    # Encoder (eq. 2-5): prototypes subtracted and accumulated.
    w = Ws[enc_prog[0, 3]].shape[1]
    p = np.zeros((B, w), np.float32)
    for r in range(enc_prog.shape[0]):
        if r > 0:
            for i in range(B):
                for n in range(N):
                    for c in range(w):
                        v = x[i * N + n, c] - p[i, c] / np.float32(r)
                        x[i * N + n, c] = v if v > 0 else np.float32(0.0)
        x, h = _block(x, Ws, bs, enc_prog[r])
        mean = np.zeros((B, h.shape[1]), np.float32)
        for i in range(B):
            for n in range(N):
                if weight[i, n] != 0:
                    for c in range(h.shape[1]):
                        mean[i, c] += weight[i, n] * h[i * N + n, c]
        fwd = enc_prog[r, 3]
        proto = _matmul(mean, Ws[fwd])
        for i in range(B):
            has = np.float32(0.0)
            for n in range(N):
                has += weight[i, n]
            for c in range(w):
                p[i, c] += proto[i, c] + bs[fwd][c] * has  # masked mean of F h = F (mean h) (+ b if any)
    # Decoders: GPD on [p, cond]; IKD on [p, cond, root-relative draft].
    context = np.zeros((B, w + nb + ng + 3 * J), np.float32)
    context[:, :w] = p
    context[:, w:w + nb + ng] = cond
    draft = _decode(context[:, :w + nb + ng].copy(), Ws, bs, gpd_prog)  # (B, 3J), centroid-relative
    for i in range(B):
        for j in range(J):
            for c in range(3):
                context[i, w + nb + ng + 3 * j + c] = draft[i, 3 * j + c] - draft[i, c]
    rot6d = _decode(context, Ws, bs, ikd_prog)
    for i in range(B):
        g = gender[i]
        J_rest = np.empty((J, 3), np.float32)
        for j in range(J):
            for c in range(3):
                v = J_template[g, j, c]
                for k in range(nb):
                    v += J_dirs[g, j, c, k] * betas[i, k]
                J_rest[j, c] = v
        for j in range(J):
            # 6D -> rotation (ProtoRes eq. 14): columns b1, b2, b1 x b2
            o = 6 * j
            a0, a1, a2 = rot6d[i, o] + identity_6d[o], rot6d[i, o + 1] + identity_6d[o + 1], \
                rot6d[i, o + 2] + identity_6d[o + 2]
            c0, c1, c2 = rot6d[i, o + 3] + identity_6d[o + 3], rot6d[i, o + 4] + identity_6d[o + 4], \
                rot6d[i, o + 5] + identity_6d[o + 5]
            n1 = max(np.sqrt(a0 * a0 + a1 * a1 + a2 * a2), _EPS)
            x0, x1, x2 = a0 / n1, a1 / n1, a2 / n1
            d = x0 * c0 + x1 * c1 + x2 * c2
            u0, u1, u2 = c0 - d * x0, c1 - d * x1, c2 - d * x2
            n2 = max(np.sqrt(u0 * u0 + u1 * u1 + u2 * u2), _EPS)
            y0, y1, y2 = u0 / n2, u1 / n2, u2 / n2
            R_local[i, j, 0, 0], R_local[i, j, 1, 0], R_local[i, j, 2, 0] = x0, x1, x2
            R_local[i, j, 0, 1], R_local[i, j, 1, 1], R_local[i, j, 2, 1] = y0, y1, y2
            R_local[i, j, 0, 2] = x1 * y2 - x2 * y1
            R_local[i, j, 1, 2] = x2 * y0 - x0 * y2
            R_local[i, j, 2, 2] = x0 * y1 - x1 * y0
        for c in range(3):
            transl[i, c] = draft[i, c] - J_rest[0, c] + centroid[i, c]
            for j in range(J):
                draft_out[i, j, c] = draft[i, 3 * j + c] + centroid[i, c]
        # FK (parents before children)
        for j in range(J):
            q = parents[j]
            if q < 0:
                R_world[i, j] = R_local[i, j]
                for c in range(3):
                    p_world[i, j, c] = J_rest[j, c] + transl[i, c]
                continue
            for r_ in range(3):
                for c in range(3):
                    R_world[i, j, r_, c] = (R_world[i, q, r_, 0] * R_local[i, j, 0, c]
                                            + R_world[i, q, r_, 1] * R_local[i, j, 1, c]
                                            + R_world[i, q, r_, 2] * R_local[i, j, 2, c])
                p_world[i, j, r_] = p_world[i, q, r_] + (R_world[i, q, r_, 0] * (J_rest[j, 0] - J_rest[q, 0])
                                                        + R_world[i, q, r_, 1] * (J_rest[j, 1] - J_rest[q, 1])
                                                        + R_world[i, q, r_, 2] * (J_rest[j, 2] - J_rest[q, 2]))


def _hidden(block: ResidualBlock) -> list[torch.nn.Linear]:
    return [m for m in block.mlp if isinstance(m, torch.nn.Linear)]


class NumbaNetwork:
    """A :class:`ProtoResIK` (eval mode; weights read once, as float32) run by :func:`forward_kernel`,
    called like ``ProtoResIK.forward`` and :class:`~smplik.onnx_runtime.OnnxNetwork`.

    Raises:
        ValueError: the ``effector_slots`` extension (not in this kernel) or a skeleton other than SMPL's.
    """

    def __init__(self, model: ProtoResIK, *, threads: int = 1):
        if model.cfg.effector_slots:
            raise ValueError("NumbaNetwork does not run the effector_slots extension; use onnxruntime or torch.")
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}.")
        self.model, self.threads = model, threads
        Ws: list[np.ndarray] = []  # a homogeneous tuple in the kernel: no typed list to compile per process
        bs: list[np.ndarray] = []

        def add(lin: torch.nn.Linear) -> int:
            Ws.append(np.ascontiguousarray(lin.weight.detach().float().numpy().T))
            bs.append(np.ascontiguousarray(lin.bias.detach().float().numpy()))
            return len(Ws) - 1

        def program(blocks: list[ResidualBlock]) -> np.ndarray:
            rows = []
            for block in blocks:
                hidden = [add(lin) for lin in _hidden(block)]
                skip = add(block.skip) if block.skip is not None else -1
                rows.append([hidden[0], len(hidden), skip, add(block.forward_out)])
            return np.array(rows, np.int64)

        self._enc = program(list(model.encoder))
        self._gpd = program(list(model.gpd.blocks) if isinstance(model.gpd, FCRDecoder) else [])
        self._ikd = program(list(model.ikd.blocks))
        self._Ws, self._bs = tuple(Ws), tuple(bs)

        def f32(t: Tensor) -> np.ndarray:
            return np.ascontiguousarray(t.detach().float().numpy())

        self._tables = (f32(model.joint_embedding.weight), f32(model.type_embedding.weight), f32(model.J_template),
                        f32(model.J_dirs), np.array(PARENTS, np.int64), f32(model.identity_6d))
        if model.J_template.shape[1] != len(PARENTS) or model.J_dirs.shape[-1] != NUM_BETAS or \
                model.J_template.shape[0] != NUM_GENDERS:
            raise ValueError(f"NumbaNetwork runs SMPL's {len(PARENTS)}-joint skeleton, got rest joints of shape "
                             f"{tuple(model.J_template.shape)}.")

    def with_threads(self, threads: int) -> NumbaNetwork:
        """The same network with another thread count."""
        return NumbaNetwork(self.model, threads=threads)

    def __call__(self, eff: EffectorBatch, betas: Tensor, gender: Tensor) -> IKOutput:
        """eff: B rows of N effectors; betas (B, 10); gender (B,) long -> :class:`IKOutput` (float32, CPU)."""
        tensors = (eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas, gender)
        arrays = [(t.detach() if t.requires_grad else t).cpu().numpy() for t in tensors]
        return IKOutput(*map(torch.from_numpy, self.run_arrays(*arrays)))

    def run_arrays(self, joint: np.ndarray, kind: np.ndarray, data: np.ndarray, tolerance: np.ndarray,
                   mask: np.ndarray, betas: np.ndarray, gender: np.ndarray) -> list[np.ndarray]:
        """The network on numpy inputs (:data:`smplik.onnx_runtime.INPUT_NAMES` order, any numeric dtype)
        -> ``[R_local, R_world, p_world, draft, transl]``, new float32 arrays."""
        ins = (np.ascontiguousarray(joint, np.int64), np.ascontiguousarray(kind, np.int64),
               np.ascontiguousarray(data, np.float32), np.ascontiguousarray(tolerance, np.float32),
               np.ascontiguousarray(mask, np.bool_), np.ascontiguousarray(betas, np.float32),
               np.ascontiguousarray(gender, np.int64))
        B, J = ins[0].shape[0], len(PARENTS)
        outs = (np.empty((B, J, 3, 3), np.float32), np.empty((B, J, 3, 3), np.float32),
                np.empty((B, J, 3), np.float32), np.empty((B, J, 3), np.float32), np.empty((B, 3), np.float32))

        def run(lo: int, hi: int) -> None:
            forward_kernel(*(a[lo:hi] for a in ins), self._Ws, self._bs, self._enc, self._gpd, self._ikd,
                           *self._tables, *(o[lo:hi] for o in outs))

        if B < 2 * CHUNK_ROWS:
            run(0, B)
        else:
            run_spread(run, [*range(0, B, CHUNK_ROWS), B], self.threads)
        return list(outs)
