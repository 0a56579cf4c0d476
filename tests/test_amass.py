"""AMASS reader: layouts, z-up -> y-up conversion, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, NUM_JOINTS, Gender
from smplik.data.amass import R_YUP_ZUP, PoseSequence, read_amass, z_up_to_y_up
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix

T = 7


def write_amass(path: Path, layout: str, *, T: int = T, seed: int = 0, **overrides: object) -> dict[str, np.ndarray]:
    """Write an AMASS-style fixture of ``layout`` (smplh, smplx, smplx_split, smpl) and return its arrays."""
    rng = np.random.default_rng(seed)
    width = {"smplh": 156, "smplx": 165, "smplx_split": 165, "smpl": 72}[layout]
    poses = rng.normal(scale=0.3, size=(T, width))
    arrays: dict[str, object] = {"trans": rng.normal(size=(T, 3)), "gender": np.array("female")}
    if layout == "smplx_split":
        arrays.update(root_orient=poses[:, :3], pose_body=poses[:, 3:66], pose_hand=poses[:, 75:165],
                      betas=rng.normal(size=16), mocap_frame_rate=np.array(60.0))
    elif layout == "smplx":
        arrays.update(poses=poses, betas=rng.normal(size=16), mocap_frame_rate=np.array(60.0))
    elif layout == "smplh":
        arrays.update(poses=poses, betas=rng.normal(size=16), mocap_framerate=np.array(120.0))
    else:
        arrays.update(poses=poses, betas=rng.normal(size=10), mocap_framerate=np.array(30.0))
    arrays.update(overrides)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    np.savez(path, **arrays)
    return {k: np.asarray(v) for k, v in arrays.items()}


def toy_rest_joints() -> np.ndarray:
    """(24, 3) a crude upright T-pose skeleton (y-up, head above pelvis), pelvis at y = 0.9."""
    rng = np.random.default_rng(1)
    J = np.zeros((NUM_JOINTS, 3))
    J[0] = (0.0, 0.9, 0.02)
    for j, name in enumerate(("left_hip", "right_hip", "spine1")):
        J[j + 1] = J[0] + {"left_hip": (0.08, -0.08, 0), "right_hip": (-0.08, -0.08, 0), "spine1": (0, 0.1, 0)}[name]
    J[JOINT_INDEX["head"]] = J[0] + (0, 0.6, 0)
    mask = np.all(J == 0, axis=1)
    J[mask] = J[0] + rng.normal(scale=0.2, size=(mask.sum(), 3))
    return J


@pytest.mark.parametrize("layout", ["smplh", "smplx", "smplx_split", "smpl"])
def test_layouts(tmp_path: Path, layout: str) -> None:
    path = tmp_path / f"{layout}.npz"
    arrays = write_amass(path, layout)
    seq = read_amass(path)
    assert isinstance(seq, PoseSequence)
    assert seq.global_orient.shape == (T, 3) and seq.body_pose.shape == (T, 23, 3) and seq.transl.shape == (T, 3)
    assert seq.global_orient.dtype == np.float32
    assert seq.gender is Gender.FEMALE
    assert seq.fps == {"smplh": 120.0, "smplx": 60.0, "smplx_split": 60.0, "smpl": 30.0}[layout]
    np.testing.assert_allclose(seq.betas, arrays["betas"][:10], rtol=1e-6)
    poses = arrays["poses"] if "poses" in arrays else np.concatenate([arrays["root_orient"], arrays["pose_body"]], 1)
    # The 21 body joints are copied unchanged.
    np.testing.assert_allclose(seq.body_pose[:, :21].reshape(T, 63), poses[:, 3:66], atol=1e-6)
    if layout == "smpl":
        np.testing.assert_allclose(seq.body_pose[:, 21:].reshape(T, 6), poses[:, 66:72], atol=1e-6)
    else:  # SMPL's hand joints are set to zero for SMPL-H/X
        assert np.all(seq.body_pose[:, 21:] == 0)
    assert seq.pose.shape == (T, 24, 3)


def test_z_up_to_y_up_root_rotation(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    arrays = write_amass(path, "smplh")
    seq = read_amass(path)
    R_in = Rotation.from_rotvec(arrays["poses"][:, :3]).as_matrix()
    R_out = Rotation.from_rotvec(seq.global_orient.astype(np.float64)).as_matrix()
    np.testing.assert_allclose(R_out, R_YUP_ZUP @ R_in, atol=1e-5)
    np.testing.assert_allclose(R_YUP_ZUP @ np.array([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0])  # z-up -> y-up


def test_upright_body_stays_upright(tmp_path: Path) -> None:
    """A body standing in AMASS's z-up world (root R_x(+90 deg)) stands in our y-up world."""
    J_rest = toy_rest_joints()
    poses = np.zeros((1, 156))
    poses[0, :3] = (np.pi / 2, 0, 0)  # the SMPL template (y-up) turned to stand along +z
    path = tmp_path / "upright.npz"
    write_amass(path, "smplh", T=1, poses=poses, trans=np.array([[1.0, 2.0, 0.3]]))
    seq = read_amass(path, rest_pelvis=J_rest[0])
    R = axis_angle_to_matrix(torch.as_tensor(seq.pose, dtype=torch.float64))
    _, p = forward_kinematics(R, torch.as_tensor(J_rest), torch.as_tensor(seq.transl, dtype=torch.float64))
    head, pelvis = p[0, JOINT_INDEX["head"]], p[0, 0]
    assert head[1] - pelvis[1] > 0.55  # head above pelvis along +y
    assert abs(float(head[0] - pelvis[0])) < 1e-5 and abs(float(head[2] - pelvis[2])) < 1e-5
    # The pelvis sits where the z-up pelvis J0 + t lands after rotating the world: (x, z, -y).
    np.testing.assert_allclose(p[0, 0].numpy(), R_YUP_ZUP @ (J_rest[0] + [1.0, 2.0, 0.3]), atol=1e-6)


def test_conversion_rotates_every_joint(tmp_path: Path) -> None:
    """With the right rest pelvis, each converted joint is exactly the z-up joint rotated by R_x(-90)."""
    J_rest = torch.as_tensor(toy_rest_joints())
    path = tmp_path / "a.npz"
    arrays = write_amass(path, "smpl")
    seq = read_amass(path, rest_pelvis=J_rest[0].numpy())
    aa_in = torch.as_tensor(arrays["poses"].reshape(T, 24, 3))
    _, p_in = forward_kinematics(axis_angle_to_matrix(aa_in), J_rest, torch.as_tensor(arrays["trans"]))
    aa_out = torch.as_tensor(seq.pose, dtype=torch.float64)
    t_out = torch.as_tensor(seq.transl, dtype=torch.float64)
    _, p_out = forward_kinematics(axis_angle_to_matrix(aa_out), J_rest, t_out)
    np.testing.assert_allclose(p_out.numpy(), p_in.numpy() @ R_YUP_ZUP.T, atol=2e-5)


def test_rest_pelvis_callable_gets_file_values(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    arrays = write_amass(path, "smplh")
    seen = {}

    def rest_pelvis(betas: np.ndarray | None, gender: Gender | None) -> np.ndarray:
        seen["betas"], seen["gender"] = betas, gender
        return np.array([0.0, 0.5, 0.0])

    seq = read_amass(path, rest_pelvis=rest_pelvis)
    assert seen["gender"] is Gender.FEMALE
    np.testing.assert_allclose(seen["betas"], arrays["betas"][:10])
    _, t = z_up_to_y_up(arrays["poses"][:, :3], arrays["trans"], np.array([0.0, 0.5, 0.0]))
    np.testing.assert_allclose(seq.transl, t, atol=1e-6)


def test_optional_keys(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    write_amass(path, "smpl", betas=None, gender=None, mocap_framerate=None)
    with pytest.raises(ValueError, match="frame rate"):
        read_amass(path)
    seq = read_amass(path, fps=25.0)
    assert seq.betas is None and seq.gender is None and seq.fps == 25.0


def test_gender_as_bytes(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    write_amass(path, "smplh", gender=np.array(b"male"))
    assert read_amass(path).gender is Gender.MALE


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"trans": None}, "'trans'"),
        ({"trans": np.zeros((T, 2))}, "'trans' has shape"),
        ({"trans": np.zeros((T + 1, 3))}, "'trans' has 8 frames"),
        ({"poses": np.zeros((T, 100))}, "'poses' has shape"),
        ({"poses": np.full((T, 156), np.nan)}, "'poses' contains NaN"),
        ({"betas": np.array([np.inf] * 16)}, "'betas' contains NaN"),
        ({"gender": np.array("robot")}, "'gender'"),
        ({"gender": np.array(["male"], dtype=object)}, "'gender' cannot be read without pickle"),
        ({"mocap_framerate": np.array(-1.0)}, "'mocap_framerate'"),
    ],
)
def test_errors_name_file_and_key(tmp_path: Path, overrides: dict, match: str) -> None:
    path = tmp_path / "bad.npz"
    write_amass(path, "smplh", **overrides)
    with pytest.raises(ValueError, match=match) as info:
        read_amass(path)
    assert str(path) in str(info.value)


def test_unknown_layout_and_unreadable(tmp_path: Path) -> None:
    path = tmp_path / "shape.npz"
    np.savez(path, betas=np.zeros(16), gender=np.array("male"))
    with pytest.raises(ValueError, match="unknown layout"):
        read_amass(path)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="readable"):
        read_amass(garbage)
    with pytest.raises(FileNotFoundError):
        read_amass(tmp_path / "missing.npz")
