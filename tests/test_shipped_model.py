"""Behaviour of the shipped SMPL-IK model (package data smplik/checkpoints/smplik_cmu.pt).

The fixed set is built without external data: the model poses random bodies from random reachable
hand/foot targets, and those (plausible, in-distribution) poses become the ground truth.
"""

from importlib import resources

import pytest
import torch

from smplik.conventions import JOINT_INDEX
from smplik.effectors import EffectorBatch
from smplik.train import load_model

SHIPPED = resources.files("smplik") / "checkpoints" / "smplik_cmu.pt"
pytestmark = pytest.mark.skipif(not SHIPPED.is_file(), reason="shipped model smplik/checkpoints/smplik_cmu.pt absent")
JOINTS = torch.tensor([JOINT_INDEX[n] for n in ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle",
                                                "right_ankle")])


@pytest.fixture(scope="module")
def model():
    return load_model(SHIPPED)[0]


def positions(targets: torch.Tensor, tolerance: float) -> EffectorBatch:
    B, N, _ = targets.shape
    return EffectorBatch(JOINTS.expand(B, N), torch.zeros(B, N, dtype=torch.long),
                         torch.cat([targets, torch.zeros_like(targets)], -1), torch.full((B, N), tolerance),
                         torch.ones(B, N, dtype=torch.bool))


def make_fixed_set(model, B: int = 256, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(B, 10, generator=g)
    gender = torch.randint(0, 3, (B,), generator=g)
    rest = model.rest_joints(betas, gender)[:, JOINTS]
    targets = rest + torch.randn(B, 6, 3, generator=g).clamp(-2, 2) * 0.12
    targets[:, 0] = rest[:, 0]  # pelvis stays put
    with torch.no_grad():
        truth = model(positions(targets, 0.0), betas, gender).p_world[:, JOINTS]
    return truth, betas, gender


@pytest.fixture(scope="module")
def fixed_set(model):
    return make_fixed_set(model)


@torch.no_grad()
def residual_mm(model, targets, betas, gender, tolerance):
    out = model(positions(targets, tolerance), betas, gender)
    return float((out.p_world[:, JOINTS] - targets).norm(dim=-1).mean() * 1000)


def pulled_residuals(model, fixed, levels):
    truth, betas, gender = fixed
    g = torch.Generator().manual_seed(1)
    pulled = truth + torch.nn.functional.normalize(torch.randn(truth.shape, generator=g), dim=-1) * 0.12
    return [residual_mm(model, pulled, betas, gender, t) for t in levels]


def test_higher_tolerance_means_weaker_adherence(model, fixed_set):
    res = pulled_residuals(model, fixed_set, [0.0, 0.5, 0.8, 1.0])
    assert all(b >= a - 0.5 for a, b in zip(res, res[1:], strict=False)), res
    assert res[-1] > res[0] + 5.0, res


def test_shipped_model_follows_exact_position_effectors(model, fixed_set):
    truth, betas, gender = fixed_set
    assert residual_mm(model, truth, betas, gender, 0.0) < 60.0
