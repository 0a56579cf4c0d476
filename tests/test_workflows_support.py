"""Helpers shared by the workflow tests: solvers (stand-in network, oracle) and a pose builder.

No tests here; the other ``test_workflows_*`` modules import from it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from smplik.conventions import NUM_JOINTS, PARENTS
from smplik.effectors import EffectorBatch
from smplik.network import IKOutput

SHIPPED = Path(__file__).resolve().parents[1] / "smplik" / "checkpoints" / "smplik_cmu.pt"


def stand_in_solver():
    """An IKSolver around a tiny untrained network (for plumbing tests when no model is shipped)."""
    from smplik.body_model import BodyModelSet
    from smplik.network import NetworkConfig, ProtoResIK
    from smplik.solver import IKSolver

    torch.manual_seed(0)
    bodies = BodyModelSet.load()
    model = ProtoResIK(NetworkConfig(width=32, encoder_blocks=2, decoder_blocks=1, layers_per_block=1),
                       bodies.J_template, bodies.J_dirs).eval()
    return IKSolver(model, bodies, {}, "stand-in")


def best_solver():
    """The shipped model when present, else the stand-in."""
    from smplik.solver import IKSolver

    return IKSolver.load(SHIPPED) if SHIPPED.is_file() else stand_in_solver()


class OracleSolver:
    """A solver whose answer improves with every effector: joints start 0.3 m off the target; an
    effector on joint j puts j on the target (a rotation effector also its children)."""

    def __init__(self, target_joints: torch.Tensor):
        self.target = target_joints.float()

    def solve_tensors(self, eff: EffectorBatch, betas: torch.Tensor, gender: torch.Tensor, *,
                      refine: object = None) -> IKOutput:
        B = eff.joint.shape[0]
        fixed = torch.zeros(B, NUM_JOINTS, dtype=torch.bool)
        fixed[torch.arange(B)[:, None], eff.joint] = True
        rot = torch.zeros(B, NUM_JOINTS, dtype=torch.bool)
        rot[torch.arange(B)[:, None], eff.joint] = eff.type == 1
        for j, p in enumerate(PARENTS):
            if p >= 0:
                fixed[:, j] |= rot[:, p]
        p = torch.where(fixed[..., None], self.target, self.target + torch.tensor([0.3, 0.0, 0.0]))
        eye = torch.eye(3).expand(B, NUM_JOINTS, 3, 3)
        return IKOutput(eye, eye, p, p, torch.zeros(B, 3))


def synthetic_pose(seed: int = 0):
    """A plausible random pose (small local rotations) on a random body."""
    from smplik.pose import Pose

    rng = np.random.default_rng(seed)
    body = rng.normal(0, 0.25, (23, 3))
    return Pose(rng.normal(0, 0.3, 3), body, np.array([0.1, 0.05, -0.2]), rng.normal(0, 0.8, 10))
