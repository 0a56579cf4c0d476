"""Training-time effector sampling (ProtoRes Algorithm 1, App. B), next to the pose sampler.

:func:`sample_effectors` turns the ground-truth joints of a :class:`~smplik.data.sampler.PoseBatch`
into a randomised :class:`~smplik.effectors.EffectorBatch` plus per-effector loss weights;
:func:`tolerance_loss_weight` is the tolerance -> weight map that the solver's refinement reuses.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from smplik.configs import EffectorSamplingConfig
from smplik.conventions import JOINT_INDEX, LIMB_ZONES, ZONES, EffectorType
from smplik.effectors import EffectorBatch
from smplik.rotations import euler_to_matrix, matrix_to_rot6d

__all__ = ["EffectorSamplingConfig", "SampledEffectors", "sample_effectors", "tolerance_loss_weight"]


def tolerance_loss_weight(tolerance: Tensor, cfg: EffectorSamplingConfig) -> Tensor:
    """ProtoRes' per-effector loss weight ``W = min(W_M, 1 / sigma)`` with ``sigma = sigma_M tolerance^eta``.

    tolerance (...) -> (...)."""
    sigma = cfg.sigma_max * tolerance.pow(cfg.eta)
    return torch.clamp(1.0 / sigma.clamp_min(1e-12), max=cfg.weight_max)


def _limb_first_layout(kind: Tensor, perms: Tensor, fraction: float,
                       g: torch.Generator) -> tuple[Tensor, Tensor]:
    """For a random ``fraction`` of rows, make the first (up to) four effectors positions on one random
    joint of each limb zone: their kinds become POSITION and those joints move to the front of the
    row's position permutation (the other joints keep their random order, so joints stay unique per
    type). kind (B, N), perms (B, 3, J) -> the same shapes."""
    B, N = kind.shape
    J = perms.shape[-1]
    chosen = torch.stack([torch.tensor([JOINT_INDEX[n] for n in ZONES[z]])[
        torch.randint(len(ZONES[z]), (B,), generator=g)] for z in LIMB_ZONES], dim=1)  # (B, 4)
    rows = torch.rand(B, generator=g) < fraction
    first = min(N, len(LIMB_ZONES))
    kind = kind.clone()
    kind[rows, :first] = int(EffectorType.POSITION)
    # Sort key of each joint in the position permutation: its rank there, after the chosen ones.
    pos_perm = perms[:, int(EffectorType.POSITION)]
    key = torch.empty_like(pos_perm).scatter_(1, pos_perm, torch.arange(J).expand(B, J) + first)
    key.scatter_(1, chosen[:, :first], torch.arange(first).expand(B, first))
    perms = perms.clone()
    perms[:, int(EffectorType.POSITION)] = torch.where(rows[:, None], key.argsort(dim=-1), pos_perm)
    return kind, perms


@dataclass(frozen=True)
class SampledEffectors:
    effectors: EffectorBatch
    weight: Tensor  # (B, N) randomized loss weight W(tolerance)


def sample_effectors(p_world: Tensor, R_world: Tensor, cfg: EffectorSamplingConfig,
                     generator: torch.Generator, num_effectors: int | None = None) -> SampledEffectors:
    """Sample noisy effectors from ground-truth joints (ProtoRes Algorithm 1, App. B).

    Types are drawn with replacement, joints per type without replacement, the first effector is
    always a position (so every sample has one). Args: p_world (B, J, 3), R_world (B, J, 3, 3).
    """
    B, J = p_world.shape[:2]
    dev, dt = p_world.device, p_world.dtype
    g = generator
    N = num_effectors or int(torch.randint(cfg.min_effectors, cfg.max_effectors + 1, (1,), generator=g))
    kind = torch.randint(0, 3, (B, N), generator=g)
    kind[:, 0] = int(EffectorType.POSITION)
    # Without replacement per type: a random permutation of joints per (sample, type); the i-th
    # effector of type t takes the next unused joint of that permutation.
    perms = torch.rand(B, 3, J, generator=g).argsort(dim=-1)
    if cfg.limb_first > 0:
        kind, perms = _limb_first_layout(kind, perms, cfg.limb_first, g)
    one_hot = torch.nn.functional.one_hot(kind, 3)
    rank = ((one_hot.cumsum(1) - 1) * one_hot).sum(-1)  # (B, N) index within its type
    joint = perms[torch.arange(B)[:, None], kind, rank]
    tol = torch.rand(B, N, generator=g, dtype=dt)
    sigma = cfg.sigma_max * tol.pow(cfg.eta)
    weight = tolerance_loss_weight(tol, cfg)

    bi = torch.arange(B)[:, None]
    g_pos = p_world[bi, joint]  # (B, N, 3)
    G_rot = R_world[bi, joint]  # (B, N, 3, 3)
    eps = torch.randn(B, N, 3, generator=g, dtype=dt)
    pos_data = torch.cat([g_pos + sigma[..., None] * eps, torch.zeros_like(g_pos)], -1)
    psi = euler_to_matrix(torch.randn(B, N, 3, generator=g, dtype=dt) * sigma[..., None])
    rot_data = matrix_to_rot6d(psi @ G_rot)
    d_local = torch.nn.functional.normalize(torch.randn(B, N, 3, generator=g, dtype=dt), dim=-1)
    dist = torch.randn(B, N, 1, generator=g, dtype=dt).abs() * cfg.lookat_distance_std + 0.1
    target = g_pos + dist * (G_rot @ d_local[..., None])[..., 0] + sigma[..., None] * eps
    look_data = torch.cat([target, d_local], -1)
    data = torch.where((kind == 0)[..., None], pos_data, torch.where((kind == 1)[..., None], rot_data, look_data))
    mask = torch.ones(B, N, dtype=torch.bool)
    batch = EffectorBatch(joint.to(dev), kind.to(dev), data.to(dev), tol.to(dev), mask.to(dev))
    return SampledEffectors(batch, weight.to(dev))
