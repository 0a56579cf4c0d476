"""Benchmark methods: the SMPL-IK solver, the rest pose, and helpers shared by the baselines.

A method is any callable ``BenchmarkSet -> Prediction`` (:data:`Method`); it may use the effectors,
betas and gender, never the ground truth.

* :class:`LearnedMethod`: the SMPL-IK solver (:meth:`IKSolver.solve_tensors`): ``smplik`` is its
  default (network, then three Levenberg-Marquardt refinement steps anchored to the network's pose,
  :mod:`smplik.refine`), ``smplik_net`` the network's pose alone.
* :class:`RestPoseMethod`: the rest (T) pose, translated so that its position-effector joints'
  centroid matches the targets' centroid.

The optimization and nearest-neighbour baselines are in :mod:`.optimization` and :mod:`.nearest`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import NUM_JOINTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.ensemble import EnsembleConfig
from smplik.refine import RefineConfig

from .evaluate import Prediction
from .files import BenchmarkSet

Method = Callable[[BenchmarkSet], Prediction]
"""A method maps a set to a prediction; it may use the effectors, betas and gender (not the ground truth)."""


def position_targets(eff: EffectorBatch) -> tuple[Tensor, Tensor]:
    """Position-effector weights (S, N) (1 for real position effectors) and the targets (S, N, 3)."""
    w = (eff.mask & (eff.type == int(EffectorType.POSITION))).float()
    return w, eff.data[..., :3]


def rest_transl_to_centroid(eff: EffectorBatch, J_rest: Tensor, R_root: Tensor | None = None) -> Tensor:
    """smplx transl placing the posed (root rotation only) effector-joint centroid on the targets' centroid."""
    w, target = position_targets(eff)
    rows = torch.arange(J_rest.shape[0])[:, None]
    P = J_rest[rows, eff.joint]  # (S, N, 3) rest positions of the effector joints
    wsum = w.sum(1, keepdim=True).clamp_min(1.0)
    P_bar = (P * w[..., None]).sum(1) / wsum
    T_bar = (target * w[..., None]).sum(1) / wsum
    J0 = J_rest[:, 0]
    rel = P_bar - J0
    if R_root is not None:
        rel = (R_root @ rel[..., None])[..., 0]
    return T_bar - J0 - rel


@dataclass(frozen=True)
class RestPoseMethod:
    """The rest pose (all local rotations identity) at the position effectors' centroid."""

    bodies: BodyModelSet

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        J_rest = self.bodies.rest_joints(bset.betas, bset.gender)
        R = torch.eye(3).expand(len(bset), NUM_JOINTS, 3, 3).clone()
        return Prediction(R, rest_transl_to_centroid(bset.effectors, J_rest))


@dataclass(frozen=True)
class LearnedMethod:
    """SMPL-IK: the solver's local rotations and translation, in batches of ``batch_size``.

    ``refine`` overrides the solver's refinement and ``ensemble`` its test-time ensemble; None keeps them.
    """

    solver: Any  # smplik.solver.IKSolver (not imported here: keeps this module free of the solver)
    batch_size: int = 1024
    refine: RefineConfig | None = None
    ensemble: EnsembleConfig | None = None

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        Rs, ts = [], []
        e = bset.effectors
        for s in range(0, len(bset), self.batch_size):
            sl = slice(s, s + self.batch_size)
            chunk = EffectorBatch(e.joint[sl], e.type[sl], e.data[sl], e.tolerance[sl], e.mask[sl])
            out = self.solver.solve_tensors(chunk, bset.betas[sl], bset.gender[sl], refine=self.refine,
                                            ensemble=self.ensemble)
            Rs.append(out.R_local)
            ts.append(out.transl)
        return Prediction(torch.cat(Rs), torch.cat(ts))

