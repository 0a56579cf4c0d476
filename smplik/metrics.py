"""Evaluation metrics (pure, batched): MPJPE, PA-MPJPE, rotation geodesic error, residuals."""

from __future__ import annotations

import torch
from torch import Tensor

from smplik.rotations import geodesic_distance


def mpjpe(pred: Tensor, target: Tensor) -> Tensor:
    """Mean per-joint position error. (..., J, 3) x2 -> (...) in the input units."""
    return (pred - target).norm(dim=-1).mean(-1)


def procrustes_align(pred: Tensor, target: Tensor) -> Tensor:
    """Similarity-align ``pred`` to ``target`` (rotation, translation, uniform scale; Umeyama).

    (..., J, 3) x2 -> aligned pred (..., J, 3).
    """
    mu_p, mu_t = pred.mean(-2, keepdim=True), target.mean(-2, keepdim=True)
    P, T = pred - mu_p, target - mu_t
    cov = P.transpose(-1, -2) @ T  # (..., 3, 3)
    U, S, Vh = torch.linalg.svd(cov)
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.ones_like(S)
    D[..., -1] = d
    R = (U * D[..., None, :]) @ Vh  # rotation mapping P onto T: T ≈ s P R
    scale = (S * D).sum(-1) / P.square().sum((-1, -2)).clamp_min(1e-12)
    return scale[..., None, None] * (P @ R) + mu_t


def pa_mpjpe(pred: Tensor, target: Tensor) -> Tensor:
    """MPJPE after Procrustes (similarity) alignment. (..., J, 3) x2 -> (...)."""
    return mpjpe(procrustes_align(pred, target), target)


def local_geodesic(R_pred: Tensor, R_target: Tensor) -> Tensor:
    """Mean geodesic angle (rad) of local joint rotations. (..., J, 3, 3) x2 -> (...)."""
    return geodesic_distance(R_pred, R_target).mean(-1)
