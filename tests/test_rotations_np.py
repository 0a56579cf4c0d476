"""The numpy twins of smplik.rotations against the torch twins and scipy, and the explicit quaternion orders."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from smplik import rotations as rot


@pytest.fixture(scope="module")
def poses() -> np.ndarray:
    """(6, 7, 3, 3) random rotations, float64."""
    return Rotation.random(42, random_state=3).as_matrix().reshape(6, 7, 3, 3)


def test_quaternion_orders_are_explicit() -> None:
    q_wxyz = np.array([np.cos(0.3), 0.0, np.sin(0.3), 0.0])  # 0.6 rad about +y
    xyzw = rot.quat_wxyz_to_xyzw(q_wxyz)
    assert xyzw.tolist() == [0.0, np.sin(0.3), 0.0, np.cos(0.3)]
    np.testing.assert_array_equal(rot.quat_xyzw_to_wxyz(xyzw), q_wxyz)
    R = rot.quat_wxyz_to_matrix(q_wxyz)
    np.testing.assert_allclose(R, Rotation.from_rotvec([0.0, 0.6, 0.0]).as_matrix(), atol=1e-15)
    np.testing.assert_allclose(rot.matrix_to_quat_wxyz(R), q_wxyz, atol=1e-15)


def test_numpy_twins_match_torch(poses: np.ndarray) -> None:
    R_t = torch.as_tensor(poses)
    q_t = rot.matrix_to_quaternion(R_t).numpy()  # w >= 0
    q_np = rot.matrix_to_quat_wxyz(poses)
    np.testing.assert_allclose(q_np * np.sign(q_np[..., :1]), q_t, atol=1e-12)
    np.testing.assert_allclose(rot.quat_wxyz_to_matrix(2.0 * q_t), poses, atol=1e-12)  # any norm
    np.testing.assert_allclose(rot.quaternion_to_matrix_np(2.0 * q_t), poses, atol=1e-12)
    aa_t = rot.matrix_to_axis_angle(R_t).numpy()
    for aa in (rot.matrix_to_axis_angle_np(poses), rot.matrix_to_axis_angle_scipy(poses)):
        assert aa.shape == (6, 7, 3)
        np.testing.assert_allclose(aa, aa_t, atol=1e-10)
    np.testing.assert_allclose(rot.axis_angle_to_matrix_np(aa_t), poses, atol=1e-12)
    small = np.linalg.norm(aa_t, axis=-1) < 2.5  # the arccos log map is meant for angles away from pi
    np.testing.assert_allclose(rot.matrix_to_axis_angle_acos_np(poses)[small], aa_t[small], atol=1e-6)
    r6 = rot.matrix_to_rot6d(R_t) * 3.0  # any column scale
    np.testing.assert_allclose(rot.rot6d_to_matrix_np(r6.numpy()), rot.rot6d_to_matrix(r6).numpy(), atol=1e-12)
    angle = np.linalg.norm(aa_t, axis=-1)
    np.testing.assert_allclose(rot.axis_rotation_np(aa_t / angle[..., None], angle), poses, atol=1e-12)


def test_numba_rotvec_copy_matches(poses: np.ndarray) -> None:
    from smplik.tracking.fit import matrix_to_rotvec, rotvec_to_matrix

    aa = rot.matrix_to_axis_angle_np(poses).reshape(-1, 3)
    keep = np.linalg.norm(aa, axis=-1) < 3.0  # the kernel's log map is exact away from pi
    for v, R in zip(aa[keep], poses.reshape(-1, 3, 3)[keep], strict=True):
        np.testing.assert_allclose(rotvec_to_matrix(v), R, atol=1e-12)
        np.testing.assert_allclose(matrix_to_rotvec(R), v, atol=1e-9)


def test_numpy_functions_load_without_torch() -> None:
    code = "import sys, smplik.rotations as r; r.quat_wxyz_to_matrix([1.0, 0, 0, 0]); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_bad_shape_names_the_shape() -> None:
    with pytest.raises(ValueError, match=r"quaternion shape \(3,\)"):
        rot.quaternion_to_matrix(torch.zeros(3))
