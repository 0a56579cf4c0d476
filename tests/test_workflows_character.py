"""Custom characters: SMPL <-> custom retargeting round trip, BVH export re-parsed, SMPL-SI fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smplik.conventions import JOINT_NAMES
from smplik.data.bvh import read_bvh
from workflows.character import custom_to_smpl, export_bvh, load_character, smpl_to_custom
from workflows.examples_gen import MIXAMO_NAMES, example_poses, write_mixamo_character


@pytest.fixture(scope="module")
def character(tmp_path_factory):
    path = write_mixamo_character(tmp_path_factory.mktemp("char") / "hero.bvh")
    return load_character(path)


def test_smpl_si_fits_the_generated_character(character):
    assert character.rig.name == "mixamo"
    assert character.units_m == pytest.approx(0.01)
    assert 0.9 < character.scale < 1.3
    assert character.estimate.max_feature_residual_m < 0.05
    assert (character.smpl_of >= 0).sum() == 24  # every SMPL joint mapped; the 3 end joints are not


@pytest.mark.parametrize("seed", [0, 1])
def test_smpl_to_custom_to_smpl_returns_the_local_rotations(character, seed, synthetic_pose):
    pose = dataclasses.replace(synthetic_pose(seed), betas=character.betas, gender=character.gender)
    back = custom_to_smpl(smpl_to_custom(pose, character), character)
    np.testing.assert_allclose(back.body_pose, pose.body_pose, atol=1e-6)
    np.testing.assert_allclose(back.global_orient, pose.global_orient, atol=1e-6)
    np.testing.assert_allclose(back.transl, pose.transl, atol=1e-6)


def test_retargeted_skeleton_follows_the_smpl_joints(character):
    """The posed custom joints stay near the scaled SMPL approximation's joints (proportions differ a little)."""
    from workflows.scene.recovery import TargetPose

    pose = dataclasses.replace(example_poses()[1].pose, betas=character.betas, gender=character.gender)
    smpl_joints = TargetPose.from_pose(pose).p_world.double().numpy() * character.scale
    custom = smpl_to_custom(pose, character)
    _, p_file = custom.positions(character)
    p = (p_file * character.units_m) @ character.C_canon_file.T - character.shift
    names = list(character.names)
    for smpl_name in ("left_wrist", "right_ankle", "head", "left_knee"):
        k = names.index("mixamorig:" + MIXAMO_NAMES[smpl_name])
        assert np.linalg.norm(p[k] - smpl_joints[JOINT_NAMES.index(smpl_name)]) < 0.1, smpl_name


def test_bvh_export_reparses_to_the_same_pose(character, tmp_path):
    poses = [smpl_to_custom(dataclasses.replace(p.pose, betas=character.betas), character) for p in example_poses()]
    path = export_bvh(tmp_path / "posed.bvh", character, poses)
    motion = read_bvh(path)
    assert motion.joint_names == character.names and motion.num_frames == 2
    source = character.skeleton.bvh  # the source file's layout is kept
    np.testing.assert_allclose(motion.offsets, source.offsets, atol=1e-5)
    assert motion.channels == source.channels
    for t, cp in enumerate(poses):
        R, p = cp.positions(character)
        np.testing.assert_allclose(motion.positions[t], p, atol=1e-4)
        np.testing.assert_allclose(motion.global_rotations[t], R @ character.skeleton.rest_rotations, atol=1e-5)
