"""Behaviour of the shipped SMPL-IK model (package data smplik/checkpoints/smplik_cmu.pt).

The fixed set is built without external data: the model poses random bodies from random reachable
hand/foot targets, and those (plausible, in-distribution) poses become the ground truth.
"""

from importlib import resources

import pytest

from smplik.benchmark.tolerance import make_fixed_set, pulled, residual_mm, tracked_joints, tracking_mm
from smplik.model_io import load_model

SHIPPED = resources.files("smplik") / "checkpoints" / "smplik_cmu.pt"
pytestmark = pytest.mark.skipif(not SHIPPED.is_file(), reason="shipped model smplik/checkpoints/smplik_cmu.pt absent")


@pytest.fixture(scope="module")
def model():
    return load_model(SHIPPED)[0]


@pytest.fixture(scope="module")
def fixed_set(model):
    return make_fixed_set(model)


def model_tracking_mm(model, fixed, tolerance):
    """How far the network's effector joints move along a 12 cm pull of their effectors (mean, mm)."""
    truth, betas, gender = fixed
    targets = pulled(truth)
    base = tracked_joints(model, truth, betas, gender, 0.0)
    return tracking_mm(base, tracked_joints(model, targets, betas, gender, tolerance), truth, targets)


def test_higher_tolerance_means_weaker_adherence(model, fixed_set):
    levels = [0.0, 0.5, 0.8, 0.9, 1.0]
    tracking = [model_tracking_mm(model, fixed_set, t) for t in levels]
    assert all(b < a for a, b in zip(tracking, tracking[1:], strict=False)), tracking
    truth, betas, gender = fixed_set
    targets = pulled(truth)
    residual = [residual_mm(tracked_joints(model, targets, betas, gender, t), targets) for t in (0.0, 1.0)]
    assert residual[1] > residual[0], residual


def test_effectors_move_the_pose(model, fixed_set):
    """A 12 cm pull of the effectors moves their joints a substantial way along it."""
    assert model_tracking_mm(model, fixed_set, 0.0) > 40.0


def test_refined_solver_keeps_the_tolerance_order(shipped_solver, model, fixed_set):
    """With the default refinement, tighter effectors are still met more closely and tracked further,
    also when the 12 cm pulls make some of them unreachable."""

    solver = shipped_solver
    truth, betas, gender = fixed_set
    targets = pulled(truth)
    base = tracked_joints(solver.solve_tensors, truth, betas, gender, 0.0)
    residual, tracking = [], []
    for tol in (0.0, 0.5, 1.0):
        moved = tracked_joints(solver.solve_tensors, targets, betas, gender, tol)
        residual.append(residual_mm(moved, targets))
        tracking.append(tracking_mm(base, moved, truth, targets))
    assert residual[0] < residual[1] < residual[2], residual
    assert tracking[0] > tracking[1] > tracking[2], tracking
    # refinement tracks much further than the network
    assert tracking[0] > model_tracking_mm(model, fixed_set, 0.0) + 20.0
