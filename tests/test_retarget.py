"""Retargeting BVH -> SMPL: synthetic round trips from known SMPL poses, presets, real CMU clips."""


import numpy as np
import pytest
import torch

from smplik.body_model import load_body_model
from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_BETAS, PARENTS
from smplik.data.bvh import format_bvh, parse_bvh
from smplik.data.retarget import (
    RetargetError,
    bone_direction_errors,
    load_preset,
    retarget_bvh,
    swing_rotation,
)
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix, geodesic_distance, matrix_to_euler_deg_np

ORDERS = ("ZYX", "XYZ", "YZX", "ZXY")
Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z-up -> y-up


def random_smpl_motion(T=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    betas = 0.8 * torch.randn(NUM_BETAS, generator=g, dtype=torch.float64)
    aa = 0.45 * torch.randn(T, 24, 3, generator=g, dtype=torch.float64)
    aa[:, 0] = torch.randn(T, 3, generator=g, dtype=torch.float64) * 1.2
    transl = torch.randn(T, 3, generator=g, dtype=torch.float64) * 0.5
    return betas, axis_angle_to_matrix(aa), transl


def smpl_to_bvh_text(J_rest, R_local, transl, *, units=1.0, C=None):
    """A BVH whose skeleton is the SMPL rest skeleton, in a world ``C^T`` (y-up -> file axes), scaled by ``units``."""
    J_rest, R_local, transl = (x.numpy() for x in (J_rest, R_local, transl))
    C = np.eye(3) if C is None else C
    R_file = C.T @ R_local @ C  # conjugated locals keep the same motion in file axes
    offsets = np.zeros((24, 3))
    offsets[1:] = (J_rest[1:] - J_rest[list(PARENTS[1:])]) @ C / units
    root = (J_rest[0] + transl) @ C / units
    channels, cols = [], []
    for j in range(24):
        order = ORDERS[j % len(ORDERS)]
        rot = [f"{a}rotation" for a in order]
        channels.append(tuple(["Xposition", "Yposition", "Zposition"] + rot) if j == 0 else tuple(rot))
        euler = matrix_to_euler_deg_np(R_file[:, j], order)
        cols.append(np.concatenate([root, euler], 1) if j == 0 else euler)
    leaves = {j: [0.0, 0.05 / units, 0.0] for j in range(24) if j not in PARENTS}
    return format_bvh(JOINT_NAMES, PARENTS, offsets, channels, np.concatenate(cols, 1), 1 / 30, leaves, precision=9)


def floor_of(model, betas):
    shapedirs = model.arrays["shapedirs"][:, :, :NUM_BETAS]
    return float((model.arrays["v_template"] + shapedirs @ betas.numpy())[:, 1].min())


@pytest.mark.parametrize("axes", ["y-up metres", "z-up centimetres"])
def test_round_trip_from_known_smpl_pose(axes):
    model = load_body_model("neutral")
    betas, R_local, transl = random_smpl_motion()
    J_rest = model.rest_joints(betas.float()).double()
    zup = axes.startswith("z")
    units, C = (0.01, Z_UP) if zup else (1.0, np.eye(3))
    motion = parse_bvh(smpl_to_bvh_text(J_rest, R_local, transl, units=units, C=C), name="synthetic")
    preset = {"name": "smpl", "units": "cm" if zup else 1.0, "up": "z" if zup else "y", "rest": "offsets",
              "floor": floor_of(model, betas) / units, "joints": {n: n for n in JOINT_NAMES}}
    clip = retarget_bvh(motion, preset, betas=betas)
    assert clip.rest_mode == "offsets" and clip.root_scale == pytest.approx(1.0, abs=1e-6)

    R_rec = axis_angle_to_matrix(torch.from_numpy(np.concatenate([clip.global_orient[:, None], clip.body_pose], 1)))
    assert geodesic_distance(R_rec.double(), R_local).max() < 1e-3  # radians
    _, p_ref = forward_kinematics(R_local, J_rest, transl)
    p_rec = model.joints(torch.from_numpy(clip.global_orient), torch.from_numpy(clip.body_pose),
                         torch.from_numpy(clip.transl), torch.from_numpy(clip.betas).expand(len(clip.transl), -1))
    assert (p_rec.double() - p_ref).norm(dim=-1).max() < 1e-4  # metres
    by_name = [clip.source_joint_names.index(n) for n in JOINT_NAMES]  # the file lists joints depth-first
    np.testing.assert_allclose(clip.source_joints[:, by_name], p_ref.numpy(), atol=1e-5)
    err = bone_direction_errors(clip)
    assert err.degrees.max() < 1.0 and err.mean() < 0.05


def test_swing_rotation_edge_cases():
    u = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0], [0.0, 0.0, 0.0]])
    v = np.array([[0.0, -3.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    R = swing_rotation(u, v)
    np.testing.assert_allclose(R @ R.swapaxes(-1, -2), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(R[0] @ u[0], [0, -1, 0], atol=1e-12)  # opposite: a half turn
    np.testing.assert_allclose(R[1] @ u[1], [0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(R[2], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[3], np.eye(3), atol=1e-12)  # zero vector: identity


def test_preset_validation_and_errors(tmp_path):
    cmu = load_preset("cmu")
    example = load_preset("generic_example")  # the documented template for user rigs stays valid
    assert example.up == "z" and example.units == 0.01 and example.aim["pelvis"] == ("right_hip", "left_hip")
    assert cmu.joints["pelvis"] == "Hips" and cmu.motion_start == 1 and cmu.units == pytest.approx(0.0254 / 0.45)
    with pytest.raises(RetargetError, match="'joints': unknown joint 'hips'"):
        load_preset({"joints": {"hips": "Hips", "pelvis": "Hips"}})
    with pytest.raises(RetargetError, match="must map 'pelvis'"):
        load_preset({"joints": {"left_hip": "L"}})
    with pytest.raises(RetargetError, match="'up' must be"):
        load_preset({"joints": {"pelvis": "Hips"}, "up": "x"})
    with pytest.raises(RetargetError, match="Unknown retarget preset 'nope'.*cmu"):
        load_preset("nope")
    bad = tmp_path / "rig.json"
    bad.write_text("{not json")
    with pytest.raises(RetargetError, match="rig.json: invalid JSON"):
        load_preset(bad)
    model = load_body_model("neutral")
    betas, R_local, transl = random_smpl_motion(T=2)
    motion = parse_bvh(smpl_to_bvh_text(model.rest_joints(betas.float()).double(), R_local, transl), name="syn.bvh")
    with pytest.raises(RetargetError, match="syn.bvh: preset 'cmu' names source joints.*Hips"):
        retarget_bvh(motion, "cmu")


@pytest.mark.parametrize("name", ["07_01", "49_06", "09_11"])
def test_real_cmu_clips(name, shared_data):
    clip = retarget_bvh(shared_data.cmu(f"{name}.bvh"), "cmu")
    assert clip.fps == pytest.approx(120, rel=1e-3) and clip.motion_start == 1
    err = bone_direction_errors(clip)  # frames 1.. (the rest frame 0 is skipped)
    assert err.mean() < 10.0, err.group_means()
    assert set(err.group_means()) == {"thighs", "shins", "feet", "spine", "neck", "upper_arms", "forearms"}
    joints = load_body_model("neutral").joints(*(torch.from_numpy(x) for x in (clip.global_orient, clip.body_pose,
                                                                                clip.transl)))
    feet = joints[1:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].min(dim=1).values
    if name == "07_01":  # a walk: one ankle stays near the floor, the pelvis at standing height
        assert clip.rest_mode == "frame0"
        assert 0.0 < float(feet.median()) < 0.2
        assert 0.75 < float(joints[1:, 0, 1].mean()) < 1.05


def test_fps_resampling_and_unmapped_spine2(shared_data):
    path = shared_data.cmu("07_01.bvh")
    clip = retarget_bvh(path, "cmu", fps=30)
    assert clip.fps == 30 and clip.num_frames == 1 + len(np.arange(0, 316 - 1 + 1e-9, 4))
    preset = load_preset("cmu")
    joints = {k: v for k, v in preset.joints.items() if k != "spine2"}
    clip = retarget_bvh(path, {"joints": joints, "units": preset.units, "motion_start": 1})
    np.testing.assert_allclose(clip.body_pose[:, JOINT_INDEX["spine2"] - 1], 0.0, atol=1e-5)
    err = bone_direction_errors(clip, bones=(("spine", "spine", "spine1", "spine3"),))
    assert err.mean() < 1e-2
