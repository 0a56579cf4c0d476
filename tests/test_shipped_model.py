"""Behaviour of the shipped SMPL-IK model (package data smplik/checkpoints/smplik_cmu.pt)."""

from importlib import resources

import pytest
import torch

from smplik.conventions import JOINT_INDEX
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix
from smplik.train import load_model

SHIPPED = resources.files("smplik") / "checkpoints" / "smplik_cmu.pt"
pytestmark = pytest.mark.skipif(not SHIPPED.is_file(), reason="shipped model smplik/checkpoints/smplik_cmu.pt absent")


@pytest.fixture(scope="module")
def model():
    return load_model(SHIPPED)[0]


def fixed_set(model, B=256, seed=0):
    """Mildly random poses of random bodies; 6 position effectors each pulled 12 cm off the pose."""
    g = torch.Generator().manual_seed(seed)
    R_local = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g) * 0.25)
    betas = torch.randn(B, 10, generator=g)
    gender = torch.randint(0, 3, (B,), generator=g)
    _, p_world = forward_kinematics(R_local, model.rest_joints(betas, gender))
    joints = torch.tensor([JOINT_INDEX[n] for n in ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle",
                                                    "right_ankle")])
    pull = torch.nn.functional.normalize(torch.randn(B, 6, 3, generator=g), dim=-1) * 0.12
    targets = p_world[:, joints] + pull
    return joints.expand(B, 6), targets, betas, gender


@torch.no_grad()
def residual_mm(model, joints, targets, betas, gender, tolerance):
    B, N = joints.shape
    eff = EffectorBatch(joints, torch.zeros(B, N, dtype=torch.long),
                        torch.cat([targets, torch.zeros_like(targets)], -1), torch.full((B, N), tolerance),
                        torch.ones(B, N, dtype=torch.bool))
    out = model(eff, betas, gender)
    return float((out.p_world[torch.arange(B)[:, None], joints] - targets).norm(dim=-1).mean() * 1000)


def test_higher_tolerance_means_weaker_adherence(model):
    case = fixed_set(model)
    levels = [0.0, 0.9, 0.97, 1.0]
    res = [residual_mm(model, *case, t) for t in levels]
    assert all(b >= a - 0.5 for a, b in zip(res, res[1:], strict=False)), res
    assert res[-1] > res[0] + 5.0, res


def test_shipped_model_follows_position_effectors(model):
    joints, targets, betas, gender = fixed_set(model, seed=1)
    assert residual_mm(model, joints, targets, betas, gender, 0.0) < 150.0
