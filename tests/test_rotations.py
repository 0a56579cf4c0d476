"""Rotation conversions: round trips in float64, pinned layouts, geodesic, batch shapes."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from smplik.rotations import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    euler_to_matrix,
    geodesic_distance,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    matrix_to_rot6d,
    quaternion_to_axis_angle,
    quaternion_to_matrix,
    rot6d_to_matrix,
)

shapes = st.lists(st.integers(1, 4), min_size=0, max_size=3).map(tuple)


def random_axis_angle(shape, seed=0, max_angle=math.pi - 1e-3):
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(*shape, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.rand(*shape, 1, generator=g, dtype=torch.float64) * max_angle
    return axis * angle


@settings(max_examples=30, deadline=None)
@given(shape=shapes, seed=st.integers(0, 10_000))
def test_round_trips_float64_any_batch_shape(shape, seed):
    aa = random_axis_angle(shape, seed)
    R = axis_angle_to_matrix(aa)
    assert R.shape == (*shape, 3, 3) and R.dtype == torch.float64
    torch.testing.assert_close(matrix_to_axis_angle(R), aa, atol=1e-9, rtol=0)
    torch.testing.assert_close(rot6d_to_matrix(matrix_to_rot6d(R)), R, atol=1e-12, rtol=0)
    torch.testing.assert_close(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-12, rtol=0)
    torch.testing.assert_close(quaternion_to_axis_angle(axis_angle_to_quaternion(aa)), aa, atol=1e-9, rtol=0)


def test_matches_scipy():
    aa = random_axis_angle((50,), 3)
    ref = Rotation.from_rotvec(aa.numpy())
    torch.testing.assert_close(axis_angle_to_matrix(aa), torch.from_numpy(ref.as_matrix()), atol=1e-12, rtol=0)
    q_ref = ref.as_quat(scalar_first=True)
    q_ref = np.where(q_ref[:, :1] < 0, -q_ref, q_ref)
    torch.testing.assert_close(matrix_to_quaternion(axis_angle_to_matrix(aa)), torch.from_numpy(q_ref), atol=1e-12,
                               rtol=0)
    eul = torch.randn(20, 3, dtype=torch.float64)
    torch.testing.assert_close(euler_to_matrix(eul),
                               torch.from_numpy(Rotation.from_euler("ZYX", eul.numpy()).as_matrix()), atol=1e-12,
                               rtol=0)


def test_6d_layout_is_first_two_columns():
    R = axis_angle_to_matrix(torch.tensor([0.3, -1.1, 0.7], dtype=torch.float64))
    six = matrix_to_rot6d(R)
    assert torch.equal(six, torch.cat([R[:, 0], R[:, 1]]))
    # A pinned example: 90 degrees about z maps x -> y, y -> -x.
    Rz = axis_angle_to_matrix(torch.tensor([0, 0, math.pi / 2], dtype=torch.float64))
    torch.testing.assert_close(matrix_to_rot6d(Rz), torch.tensor([0, 1, 0, -1, 0, 0], dtype=torch.float64),
                               atol=1e-12, rtol=0)


def test_quaternion_layout_is_scalar_first():
    q = axis_angle_to_quaternion(torch.tensor([0, 0, math.pi / 2], dtype=torch.float64))
    s = math.sqrt(0.5)
    torch.testing.assert_close(q, torch.tensor([s, 0, 0, s], dtype=torch.float64), atol=1e-12, rtol=0)


def test_small_angles_are_stable():
    aa = torch.tensor([[1e-12, 0, 0], [0, 0, 0], [3e-9, -2e-9, 1e-9]], dtype=torch.float64)
    R = axis_angle_to_matrix(aa)
    torch.testing.assert_close(matrix_to_axis_angle(R), aa, atol=1e-15, rtol=0)
    aa.requires_grad_(True)
    axis_angle_to_matrix(aa).sum().backward()
    assert torch.isfinite(aa.grad).all()


@pytest.mark.parametrize("angle", [0.0, 1e-7, 0.5, math.pi / 2, math.pi - 1e-6, math.pi])
def test_geodesic_exact_including_zero_and_near_pi(angle):
    axis = torch.nn.functional.normalize(torch.tensor([0.2, -0.9, 0.4], dtype=torch.float64), dim=0)
    base = axis_angle_to_matrix(torch.tensor([0.4, 1.0, -2.0], dtype=torch.float64))
    other = base @ axis_angle_to_matrix(axis * angle)
    assert abs(geodesic_distance(base, other).item() - angle) < 1e-7


def test_geodesic_gradients_finite_at_zero_and_pi():
    R = axis_angle_to_matrix(torch.tensor([[0.0, 0.0, 0.0], [0.0, math.pi - 1e-4, 0.0]], dtype=torch.float64))
    aa = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    geodesic_distance(R, axis_angle_to_matrix(aa)).sum().backward()
    assert torch.isfinite(aa.grad).all()


def test_geodesic_broadcasts():
    a = axis_angle_to_matrix(random_axis_angle((4, 1), 1))
    b = axis_angle_to_matrix(random_axis_angle((1, 5), 2))
    assert geodesic_distance(a, b).shape == (4, 5)


def test_bad_shapes_raise_named_errors():
    with pytest.raises(ValueError, match="axis-angle shape"):
        axis_angle_to_matrix(torch.zeros(4, 2))
    with pytest.raises(ValueError, match="6D rotation shape"):
        rot6d_to_matrix(torch.zeros(5))
