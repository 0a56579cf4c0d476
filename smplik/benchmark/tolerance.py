"""The tolerance-tracking scenario: how far effector joints follow a 12 cm pull of their effectors.

Shared by ``tests/test_shipped_model.py`` (which asserts on it) and ``benchmarks/tolerance_tracking.py``
(which reports it): B random bodies; six position effectors (:data:`TRACKED_JOINTS`: pelvis, head,
wrists, ankles) at the joints of a plausible pose the model itself produced from random reachable
targets (:func:`make_fixed_set`); then every effector pulled :data:`PULL_M` in a random direction
(:func:`pulled`; some pulls are out of reach).
"""

from __future__ import annotations

import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX, EffectorType
from smplik.effectors import EffectorBatch

TRACKED_JOINTS = torch.tensor([JOINT_INDEX[n] for n in ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle",
                                                        "right_ankle")])
PULL_M = 0.12
"""Length of each effector's pull (metres)."""


def position_effectors(targets: Tensor, tolerance: float) -> EffectorBatch:
    """Position effectors on :data:`TRACKED_JOINTS`. targets (B, 6, 3) -> a batch of B rows of 6."""
    B, N, _ = targets.shape
    return EffectorBatch(TRACKED_JOINTS.expand(B, N), torch.full((B, N), int(EffectorType.POSITION)),
                         torch.cat([targets, torch.zeros_like(targets)], -1), torch.full((B, N), tolerance),
                         torch.ones(B, N, dtype=torch.bool))


@torch.no_grad()
def make_fixed_set(model, B: int = 256, seed: int = 0) -> tuple[Tensor, Tensor, Tensor]:
    """The model's own poses for random reachable targets: joints (B, 6, 3), betas (B, 10), gender (B,).

    ``model`` is a :class:`smplik.network.ProtoResIK`; the targets are the rest joints moved by
    ``PULL_M * clamp(N(0, 1), -2, 2)`` per axis (the pelvis stays put).
    """
    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(B, 10, generator=g)
    gender = torch.randint(0, 3, (B,), generator=g)
    rest = model.rest_joints(betas, gender)[:, TRACKED_JOINTS]
    targets = rest + torch.randn(B, 6, 3, generator=g).clamp(-2, 2) * PULL_M
    targets[:, 0] = rest[:, 0]
    truth = model(position_effectors(targets, 0.0), betas, gender).p_world[:, TRACKED_JOINTS]
    return truth, betas, gender


def pulled(truth: Tensor, seed: int = 1) -> Tensor:
    """``truth`` (B, 6, 3) with every point moved :data:`PULL_M` in a random direction."""
    g = torch.Generator().manual_seed(seed)
    return truth + torch.nn.functional.normalize(torch.randn(truth.shape, generator=g), dim=-1) * PULL_M


def tracked_joints(solve, targets: Tensor, betas: Tensor, gender: Tensor, tolerance: float) -> Tensor:
    """The tracked joints (B, 6, 3) of ``solve(effectors, betas, gender)`` (a model or a bound solver method)
    for position effectors at ``targets`` (B, 6, 3) with one tolerance."""
    with torch.no_grad():
        return solve(position_effectors(targets, tolerance), betas, gender).p_world[:, TRACKED_JOINTS]


def tracking_mm(base: Tensor, moved: Tensor, truth: Tensor, targets: Tensor) -> float:
    """Mean distance (mm) the joints moved along their pulls: ``base``/``moved`` solved for ``truth``/``targets``."""
    return float(((moved - base) * (targets - truth)).sum(-1).mean() / PULL_M * 1000)


def residual_mm(moved: Tensor, targets: Tensor) -> float:
    """Mean distance (mm) of the joints from their targets."""
    return float((moved - targets).norm(dim=-1).mean() * 1000)
