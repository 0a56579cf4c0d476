"""Optimization IK baseline: batched Adam on SMPL with a Gaussian pose prior.

:class:`OptimizationIK` runs Adam over local 6D rotations and the root translation, our FK with
``J(beta, gender)``, on the same effector losses plus a pose prior: a diagonal Gaussian over the 6D
local rotations of joints 1..23 fitted to the train split (:class:`PosePrior`); the root is free.
Initialised at the rest pose, root rotation and translation by a Kabsch fit
(:func:`smplik.metrics.rigid_align`) of the rest joints to the position effectors, or at a given pose
(:meth:`OptimizationIK.solve` with ``init``: the edit benchmark starts from the pose being edited); a
fixed iteration count.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import NUM_JOINTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.metrics import rigid_align
from smplik.rotations import axis_angle_to_matrix, matrix_to_rot6d, rot6d_to_matrix

from .evaluate import Prediction
from .files import BenchmarkSet
from .methods import position_targets, rest_transl_to_centroid


@dataclass(frozen=True)
class PosePrior:
    """Diagonal Gaussian over the 6D local rotations: mean (24, 6), std (24, 6) (joint 0 unused)."""

    mean: Tensor
    std: Tensor

    @classmethod
    def fit(cls, pose_axis_angle: Tensor, min_std: float = 0.02) -> PosePrior:
        """Fit to local rotations (M, 24, 3) axis-angle (e.g. a train split's ``pose``)."""
        x = matrix_to_rot6d(axis_angle_to_matrix(pose_axis_angle.double()))
        return cls(x.mean(0).float(), x.std(0).clamp_min(min_std).float())

    def nll(self, rot6d: Tensor) -> Tensor:
        """0.5 * squared Mahalanobis distance over joints 1..23. rot6d (S, 24, 6) -> (S,)."""
        z = (rot6d[:, 1:] - self.mean[1:]) / self.std[1:]
        return 0.5 * z.square().sum((-1, -2))


@dataclass(frozen=True)
class OptimizationIK:
    """Gradient-based IK on SMPL: Adam over local 6D rotations + root translation (module docstring).

    Loss per pose: ``sum_pos |p - t|^2 / sigma_pos^2 + sum_rot |R - R*|_F^2 / sigma_rot^2 +
    sum_lookat (1 - cos) / sigma_lookat^2 + prior_weight * prior.nll``.
    """

    bodies: BodyModelSet
    prior: PosePrior
    iterations: int = 200
    lr: float = 0.1
    sigma_pos: float = 0.01
    """metres."""
    sigma_rot: float = 0.1
    """Frobenius norm (about radians x sqrt 2)."""
    sigma_lookat: float = 0.05
    """on 1 - cos (about 0.3 rad)."""
    prior_weight: float = 3.0
    """Defaults (iterations, lr, sigmas, prior weight) were chosen on validation-split benchmark files."""

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        return self.solve(bset.effectors, bset.betas, bset.gender)

    def solve(self, eff: EffectorBatch, betas: Tensor, gender: Tensor, *, init: Prediction | None = None
              ) -> Prediction:
        """Optimize S poses for ``eff`` (S rows), betas (S, 10), gender (S,) long; ``init``: the starting
        poses (local rotations (S, 24, 3, 3), transl (S, 3)), else the rest pose fitted to the positions."""
        S = eff.joint.shape[0]
        J_rest = self.bodies.rest_joints(betas, gender)
        rows = torch.arange(S)[:, None]
        w_pos, target = position_targets(eff)
        if init is None:
            R0 = rigid_align(J_rest[rows, eff.joint], target, w_pos, scale=False).R
            x = matrix_to_rot6d(torch.eye(3)).expand(S, NUM_JOINTS, 6).clone()
            x[:, 0] = matrix_to_rot6d(R0)
            transl = rest_transl_to_centroid(eff, J_rest, R0).clone()
        else:
            x = matrix_to_rot6d(init.R_local.float()).clone()
            transl = init.transl.float().clone()
        x.requires_grad_(True)
        transl.requires_grad_(True)
        w_rot = (eff.mask & (eff.type == int(EffectorType.ROTATION))).float()
        w_look = (eff.mask & (eff.type == int(EffectorType.LOOK_AT))).float()
        R_target = rot6d_to_matrix(torch.where(w_rot.bool()[..., None], eff.data,
                                               torch.tensor([1.0, 0, 0, 0, 1.0, 0])))
        look_target, look_dir = eff.data[..., :3], eff.data[..., 3:]
        opt = torch.optim.Adam([x, transl], lr=self.lr)
        with torch.enable_grad():
            for _ in range(self.iterations):
                opt.zero_grad(set_to_none=True)
                R_local = rot6d_to_matrix(x)
                R_world, p_world = forward_kinematics(R_local, J_rest, transl)
                p = p_world[rows, eff.joint]
                R = R_world[rows, eff.joint]
                loss_pos = ((p - target).square().sum(-1) * w_pos).sum(1) / self.sigma_pos ** 2
                loss_rot = ((R - R_target).square().sum((-1, -2)) * w_rot).sum(1) / self.sigma_rot ** 2
                axis = (R @ look_dir[..., None])[..., 0]
                cos = torch.nn.functional.cosine_similarity(axis, look_target - p, dim=-1)
                loss_look = ((1 - cos) * w_look).sum(1) / self.sigma_lookat ** 2
                loss = (loss_pos + loss_rot + loss_look + self.prior_weight * self.prior.nll(x)).sum()
                loss.backward()
                opt.step()
        with torch.no_grad():
            return Prediction(rot6d_to_matrix(x).detach(), transl.detach().clone())

