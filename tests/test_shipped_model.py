"""Behaviour of the shipped SMPL-IK model (package data smplik/checkpoints/smplik_cmu.pt).

The fixed set is built without external data: the model poses random bodies from random reachable
hand/foot targets, and those (plausible, in-distribution) poses become the ground truth.
"""

from importlib import resources

import pytest
import torch

from smplik.conventions import JOINT_INDEX
from smplik.effectors import EffectorBatch
from smplik.model_io import load_model

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


def pulled(fixed):
    truth, betas, gender = fixed
    g = torch.Generator().manual_seed(1)
    return truth + torch.nn.functional.normalize(torch.randn(truth.shape, generator=g), dim=-1) * 0.12


@torch.no_grad()
def tracking_mm(model, fixed, tolerance):
    """How far the effector joints move along a 12 cm pull of their effectors (mean, mm)."""
    truth, betas, gender = fixed
    targets = pulled(fixed)
    base = model(positions(truth, 0.0), betas, gender).p_world[:, JOINTS]
    moved = model(positions(targets, tolerance), betas, gender).p_world[:, JOINTS]
    return float(((moved - base) * (targets - truth)).sum(-1).mean() / 0.12 * 1000)


def test_higher_tolerance_means_weaker_adherence(model, fixed_set):
    levels = [0.0, 0.5, 0.8, 0.9, 1.0]
    tracking = [tracking_mm(model, fixed_set, t) for t in levels]
    assert all(b < a for a, b in zip(tracking, tracking[1:], strict=False)), tracking
    _, betas, gender = fixed_set
    residual = [residual_mm(model, pulled(fixed_set), betas, gender, t) for t in (0.0, 1.0)]
    assert residual[1] > residual[0], residual


def test_effectors_move_the_pose(model, fixed_set):
    """A 12 cm pull of the effectors moves their joints a substantial way along it."""
    assert tracking_mm(model, fixed_set, 0.0) > 40.0


def test_refined_solver_keeps_the_tolerance_order(model, fixed_set):
    """With the default refinement, tighter effectors are still met more closely and tracked further,
    also when the 12 cm pulls make some of them unreachable."""
    from smplik.solver import IKSolver

    solver = IKSolver.load(SHIPPED)
    truth, betas, gender = fixed_set
    targets = pulled(fixed_set)
    base = solver.solve_tensors(positions(truth, 0.0), betas, gender).p_world[:, JOINTS]
    residual, tracking = [], []
    for tol in (0.0, 0.5, 1.0):
        moved = solver.solve_tensors(positions(targets, tol), betas, gender).p_world[:, JOINTS]
        residual.append(float((moved - targets).norm(dim=-1).mean() * 1000))
        tracking.append(float(((moved - base) * (targets - truth)).sum(-1).mean() / 0.12 * 1000))
    assert residual[0] < residual[1] < residual[2], residual
    assert tracking[0] > tracking[1] > tracking[2], tracking
    assert tracking[0] > tracking_mm(model, fixed_set, 0.0) + 20.0  # refinement tracks much further than the network
