"""Evaluation metrics (pure, batched): MPJPE, PA-MPJPE, rotation geodesic error, and rigid alignment.

:func:`rigid_align` is the project's one Kabsch / Umeyama implementation (weighted least-squares
rotation, translation and optionally a uniform scale between two point sets); PA-MPJPE, the
optimization baseline's initial root and the custom-character placement use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from smplik.rotations import geodesic_distance


@dataclass(frozen=True)
class SimilarityTransform:
    """``x -> scale * R @ x + t`` (column vectors). Batched over leading axes ``...``.

    Attributes:
        R: (..., 3, 3) rotation (det +1).
        t: (..., 3) translation.
        scale: (...) uniform scale (ones when fitted with ``scale=False``).
    """

    R: Tensor
    t: Tensor
    scale: Tensor

    def apply(self, points: Tensor) -> Tensor:
        """Transform points (..., N, 3) -> (..., N, 3)."""
        return self.scale[..., None, None] * (points @ self.R.transpose(-1, -2)) + self.t[..., None, :]


def rigid_align(src: Tensor, dst: Tensor, weights: Tensor | None = None, *, scale: bool) -> SimilarityTransform:
    """Least-squares alignment of ``src`` onto ``dst``: Kabsch (``scale=False``) or Umeyama (``scale=True``).

    Minimises ``sum_i w_i |s R src_i + t - dst_i|^2`` over rotations R (reflections excluded),
    translations t and, with ``scale=True``, a uniform scale s > 0 (else s = 1). Umeyama 1991,
    "Least-squares estimation of transformation parameters between two point patterns".

    Args:
        src, dst: (..., N, 3) corresponding points.
        weights: (..., N) non-negative weights (default: all 1). Points of weight 0 are ignored;
            with all weights 0 the fit is the identity rotation plus the translation of the means.
        scale: also fit the uniform scale (keyword-only: the choice must be explicit).

    Returns:
        The transform; ``rigid_align(src, dst, scale=...).apply(src)`` is the aligned ``src``.
    """
    if src.shape != dst.shape or src.shape[-1] != 3:
        raise ValueError(f"rigid_align needs two (..., N, 3) point sets of one shape, got {tuple(src.shape)} "
                         f"and {tuple(dst.shape)}.")
    w = torch.ones(src.shape[:-1], dtype=src.dtype) if weights is None else weights.to(src.dtype)
    w = w / w.sum(-1, keepdim=True).clamp_min(1e-12)  # (..., N), sums to 1
    mu_src = (w[..., None] * src).sum(-2)  # (..., 3)
    mu_dst = (w[..., None] * dst).sum(-2)
    A = src - mu_src[..., None, :]
    B = dst - mu_dst[..., None, :]
    H = (B * w[..., None]).transpose(-1, -2) @ A  # (..., 3, 3) = sum_i w_i B_i A_i^T
    U, S, Vh = torch.linalg.svd(H)
    d = torch.where(torch.linalg.det(U @ Vh) < 0, -1.0, 1.0).to(src.dtype)
    D = torch.ones_like(S)
    D[..., -1] = d
    R = (U * D[..., None, :]) @ Vh
    if scale:
        var = (w * A.square().sum(-1)).sum(-1)
        s = (S * D).sum(-1) / var.clamp_min(1e-12)
    else:
        s = torch.ones(src.shape[:-2], dtype=src.dtype)
    t = mu_dst - s[..., None] * (R @ mu_src[..., None])[..., 0]
    return SimilarityTransform(R, t, s)


def mpjpe(pred: Tensor, target: Tensor) -> Tensor:
    """Mean per-joint position error. (..., J, 3) x2 -> (...) in the input units."""
    return (pred - target).norm(dim=-1).mean(-1)


def procrustes_align(pred: Tensor, target: Tensor) -> Tensor:
    """Similarity-align ``pred`` to ``target`` (rotation, translation, uniform scale; :func:`rigid_align`).

    (..., J, 3) x2 -> aligned pred (..., J, 3).
    """
    return rigid_align(pred, target, scale=True).apply(pred)


def pa_mpjpe(pred: Tensor, target: Tensor) -> Tensor:
    """MPJPE after Procrustes (similarity) alignment. (..., J, 3) x2 -> (...)."""
    return mpjpe(procrustes_align(pred, target), target)


def local_geodesic(R_pred: Tensor, R_target: Tensor) -> Tensor:
    """Mean geodesic angle (rad) of local joint rotations. (..., J, 3, 3) x2 -> (...)."""
    return geodesic_distance(R_pred, R_target).mean(-1)
