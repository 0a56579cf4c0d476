"""protores_loss on known errors: zero at the ground truth, each term's value, and the documented weighting."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, NUM_JOINTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.losses import LossConfig, lookat_angle, protores_loss
from smplik.network import IKOutput
from smplik.rotations import axis_angle_to_matrix

B = 2
POS_A, POS_B, ROT, LOOK = (JOINT_INDEX[n] for n in ("left_wrist", "right_ankle", "spine3", "head"))


def _axis_rotation(axis: str, angle: float) -> torch.Tensor:
    return torch.from_numpy(Rotation.from_euler(axis, angle).as_matrix())


@pytest.fixture(scope="module")
def truth(bodies):
    """Ground truth (float64) and effectors: two positions (tolerance weights 0.5 and 1), one rotation
    (weight 0.8), one exact look-at along the head's +z, and one masked slot of weight 5."""
    g = torch.Generator().manual_seed(0)
    R_local = axis_angle_to_matrix(0.3 * torch.randn(B, NUM_JOINTS, 3, generator=g, dtype=torch.float64))
    J_rest = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    R_world, p_world = forward_kinematics(R_local, J_rest, torch.tensor([0.1, 0.0, -0.2], dtype=torch.float64))
    direction = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    target = p_world[:, LOOK] + 1.5 * (R_world[:, LOOK] @ direction)
    joint = torch.tensor([POS_A, POS_B, ROT, LOOK, 0]).expand(B, 5)
    kind = torch.tensor([int(EffectorType.POSITION), int(EffectorType.POSITION), int(EffectorType.ROTATION),
                         int(EffectorType.LOOK_AT), int(EffectorType.POSITION)]).expand(B, 5)
    data = torch.zeros(B, 5, 6, dtype=torch.float64)
    data[:, 3, :3], data[:, 3, 3:] = target, direction
    mask = torch.tensor([True, True, True, True, False]).expand(B, 5)
    eff = EffectorBatch(joint, kind, data, torch.zeros(B, 5), mask)
    weight = torch.tensor([0.5, 1.0, 0.8, 1.0, 5.0], dtype=torch.float64).expand(B, 5)
    return R_local, R_world, p_world, eff, weight


def test_loss_is_zero_at_the_ground_truth(truth):
    R_local, R_world, p_world, eff, weight = truth
    out = IKOutput(R_local, R_world, p_world, p_world.clone(), torch.zeros(B, 3))
    total, terms = protores_loss(out, R_local, R_world, p_world, eff, weight, LossConfig())
    assert float(total) == pytest.approx(0.0, abs=1e-10)
    assert all(float(v) == pytest.approx(0.0, abs=1e-6) for v in terms.values()), terms


@pytest.mark.parametrize("cfg", [LossConfig(), LossConfig(w_pos_rnd=3.0, w_pos_det=0.5, w_rot_local=2.0,
                                                          w_rot_global=7.0, w_lookat=0.25)])
def test_terms_and_weights_combine_as_documented(truth, cfg):
    """Known errors: draft off by u everywhere, the right ankle off by v, every local rotation off by a,
    spine3's global rotation off by b, the head turned by c about its y axis (away from the look-at target)."""
    R_local, R_world, p_world, eff, weight = truth
    u = torch.tensor([0.03, -0.02, 0.01], dtype=torch.float64)
    v = torch.tensor([0.0, 0.05, 0.02], dtype=torch.float64)
    a, b, c = 0.1, 0.4, 0.3
    draft = p_world + u
    p_out = p_world.clone()
    p_out[:, POS_B] += v
    R_local_out = R_local @ _axis_rotation("z", a)
    R_world_out = R_world.clone()
    R_world_out[:, ROT] = R_world[:, ROT] @ _axis_rotation("x", b)
    R_world_out[:, LOOK] = R_world[:, LOOK] @ _axis_rotation("y", c)
    out = IKOutput(R_local_out, R_world_out, p_out, draft, torch.zeros(B, 3))
    total, terms = protores_loss(out, R_local, R_world, p_world, eff, weight, cfg)

    J, uu, vv = NUM_JOINTS, float(u @ u), float(v @ v)
    expected = {
        "gpd_rnd": uu,  # tolerance-weighted mean over the two position effectors; the masked slot ignored
        "ikd_rnd": 1.0 * vv / (0.5 + 1.0),  # only the right ankle (weight 1 of 1.5) is off
        "gpd_det": J * uu, "ikd_det": vv, "loc_geo": J * a, "glob_geo": b, "lookat": c,
    }
    for key, value in expected.items():
        assert float(terms[key]) == pytest.approx(value, rel=1e-6, abs=1e-9), key
    documented = (cfg.w_pos_rnd / J * (expected["gpd_rnd"] + expected["ikd_rnd"])
                  + cfg.w_pos_det * (expected["gpd_det"] + expected["ikd_det"])
                  + (cfg.w_lookat * c + cfg.w_rot_global * b + cfg.w_rot_local * J * a) / J)
    assert float(total) == pytest.approx(documented, rel=1e-6)


def test_lookat_angle_is_the_angle_to_the_target():
    p = torch.zeros(3, dtype=torch.float64)
    for angle in (0.0, 0.5, math.pi / 2, 3.0):
        target = torch.tensor([math.sin(angle), 0.0, math.cos(angle)], dtype=torch.float64) * 2.0
        got = lookat_angle(target, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), p,
                           torch.eye(3, dtype=torch.float64))
        assert float(got) == pytest.approx(angle, abs=1e-9)


def test_distillation_loss_is_the_deterministic_terms_towards_the_teacher(truth):
    """Zero at the teacher's pose; else w_pos_det (|draft - p_t|^2 + |p - p_t|^2) + w_rot_local / J * sum
    geodesic, with no gradient into the teacher."""
    from smplik.losses import distillation_loss

    R_local, R_world, p_world, eff, weight = truth
    teacher = IKOutput(R_local, R_world, p_world, p_world.clone(), torch.zeros(B, 3))
    cfg = LossConfig(w_pos_det=0.5, w_rot_local=2.0)
    assert float(distillation_loss(teacher, teacher, cfg)) == pytest.approx(0.0, abs=1e-10)
    u, a = torch.tensor([0.01, -0.02, 0.03], dtype=torch.float64), 0.2
    R_off = R_local @ _axis_rotation("x", a).expand(B, NUM_JOINTS, 3, 3)
    draft = (p_world + u).requires_grad_(True)
    student = IKOutput(R_off, R_world, p_world, draft, torch.zeros(B, 3))
    teacher_p = p_world.clone().requires_grad_(True)
    loss = distillation_loss(student, IKOutput(R_local, R_world, teacher_p, p_world, torch.zeros(B, 3)), cfg)
    want = 0.5 * NUM_JOINTS * float(u.square().sum()) + 2.0 / NUM_JOINTS * NUM_JOINTS * a
    assert float(loss.detach()) == pytest.approx(want, rel=1e-6)
    loss.backward()
    assert draft.grad is not None and teacher_p.grad is None
