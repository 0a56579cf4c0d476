"""``scene animate`` on joint positions: HumanML3D joints (T, 22, 3), HumanML3D 263-d features, MDM's
``results.npy`` and BVH files -> SMPL animations (:mod:`workflows.animation.joint_motion`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from animation_fixtures import humanml3d_features, walking_joints
from bvh_producers import write_rotation_only_bvh
from scipy.spatial.transform import Rotation

from workflows.animation.clips import joints_of, rest_joints
from workflows.animation.joint_motion import joint_motion_kind, recover_from_ric


def _track_joints(track) -> np.ndarray:
    R = Rotation.from_rotvec(np.concatenate([track.global_orient[:, None], track.body_pose], 1).reshape(-1, 3))
    return joints_of(R.as_matrix().reshape(-1, 24, 3, 3), track.transl,
                     rest_joints(track.betas, track.gender)) * track.scale


# ----------------------------------------------------------------------------- HumanML3D's recover_from_ric


def _qinv(q: torch.Tensor) -> torch.Tensor:  # HumanML3D common/quaternion.py qinv
    return q * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def _qrot(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:  # HumanML3D common/quaternion.py qrot
    qvec = q[..., 1:]
    uv = torch.cross(qvec, v, dim=-1)
    uuv = torch.cross(qvec, uv, dim=-1)
    return v + 2 * (q[..., :1] * uv + uuv)


def _recover_from_ric_reference(data: torch.Tensor, joints_num: int) -> torch.Tensor:
    """HumanML3D's own torch code (github.com/EricGuo5513/HumanML3D common/motion_process.py recover_root_rot_pos
    and recover_from_ric; the same in MDM's data_loaders/humanml/scripts/motion_process.py), as the reference."""
    rot_vel = data[..., 0]
    r_rot_ang = torch.zeros_like(rot_vel)
    r_rot_ang[..., 1:] = rot_vel[..., :-1]
    r_rot_ang = torch.cumsum(r_rot_ang, dim=-1)
    r_rot_quat = torch.zeros(data.shape[:-1] + (4,), dtype=data.dtype)
    r_rot_quat[..., 0] = torch.cos(r_rot_ang)
    r_rot_quat[..., 2] = torch.sin(r_rot_ang)
    r_pos = torch.zeros(data.shape[:-1] + (3,), dtype=data.dtype)
    r_pos[..., 1:, [0, 2]] = data[..., :-1, 1:3]
    r_pos = _qrot(_qinv(r_rot_quat), r_pos)
    r_pos = torch.cumsum(r_pos, dim=-2)
    r_pos[..., 1] = data[..., 3]
    positions = data[..., 4:(joints_num - 1) * 3 + 4].view(data.shape[:-1] + (-1, 3))
    positions = _qrot(_qinv(r_rot_quat[..., None, :]).expand(positions.shape[:-1] + (4,)), positions)
    positions[..., 0] += r_pos[..., 0:1]
    positions[..., 2] += r_pos[..., 2:3]
    return torch.cat([r_pos.unsqueeze(-2), positions], dim=-2)


def test_recover_from_ric_matches_humanml3d_code():
    rng = np.random.default_rng(3)
    feats = rng.normal(0, 0.3, (2, 50, 263))
    ours = recover_from_ric(feats)
    ref = _recover_from_ric_reference(torch.as_tensor(feats), 22).numpy()
    assert ours.shape == (2, 50, 22, 3)
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    # a turning root: the joints' root-relative offsets are rotated with the heading
    feats = np.zeros((5, 263))
    feats[:, 0] = np.pi / 4  # the quaternion (cos a, 0, sin a, 0) turns by 2a: 90 degrees per frame
    feats[:, 4:7] = [1.0, 0.0, 0.0]  # joint 1 one metre along +x of the root's frame
    P = recover_from_ric(feats)
    assert np.allclose(P[1, 1], [0.0, 0.0, 1.0], atol=1e-12)  # after one frame's turn: +x -> +z (inverse y turn)


def test_kinds():
    assert joint_motion_kind(np.zeros((5, 22, 3))) == "joints"
    assert joint_motion_kind(np.zeros((5, 263))) == "humanml3d_vec"
    assert joint_motion_kind({"motion": np.zeros((2, 22, 3, 9))}) == "mdm"
    assert joint_motion_kind(np.zeros((5, 72))) is None
    assert joint_motion_kind(np.zeros((5, 24, 3))) is None


# ----------------------------------------------------------------------------- end to end


def test_humanml3d_joints_become_an_animation_on_the_right_body(animate_shipped, tmp_path):
    """A taller person's joints (scale 1.1): SMPL-SI finds the size; the animation's joints match the input."""
    from workflows.animation.files import load_animation

    P = walking_joints(40, scale=1.1)
    np.save(tmp_path / "motion.npy", P[:, :22].astype(np.float32))  # HumanML3D new_joints layout (T, 22, 3)
    result = animate_shipped(tmp_path / "motion.npy", "--out", tmp_path / "out", "--export", "bvh,glb")
    assert result.exit_code == 0, result.output
    assert "20 frames/s assumed" in result.output
    anim = load_animation(tmp_path / "out" / "animation.json")
    (track,) = anim.tracks
    assert anim.fps == 20.0 and track.num_frames == 40 and anim.space == "world"
    assert abs(track.scale * np.linalg.norm(rest_joints(track.betas, track.gender)[15]
                                            - rest_joints(track.betas, track.gender)[7])
               - 1.1 * np.linalg.norm(rest_joints(np.zeros(10), "neutral")[15]
                                      - rest_joints(np.zeros(10), "neutral")[7])) < 0.03
    err = np.linalg.norm(_track_joints(track)[:, :22] - P[:, :22], axis=-1)
    assert err.mean() < 0.03, err.mean()
    assert (tmp_path / "out" / "person_0.bvh").is_file() and (tmp_path / "out" / "person_0.glb").is_file()


def test_humanml3d_features_with_mean_std(animate_shipped, tmp_path):
    """Normalised 263-d features + Mean/Std: the joints recovered by recover_from_ric become the animation."""
    from workflows.animation.files import load_animation

    P = walking_joints(30)[:, :22]
    feats = humanml3d_features(P)  # root without rotation: ric = joints relative to the root's xz, root height
    assert np.allclose(recover_from_ric(feats)[:, :, [0, 2]] + P[0, 0, [0, 2]], P[..., [0, 2]], atol=1e-9)
    mean, std = np.linspace(-1, 1, 263), np.linspace(0.5, 2, 263)
    np.save(tmp_path / "Mean.npy", mean)
    np.save(tmp_path / "Std.npy", std)
    np.save(tmp_path / "feats.npy", ((feats - mean) / std).astype(np.float32))
    result = animate_shipped(tmp_path / "feats.npy", "--out", tmp_path / "out", "--mean", tmp_path / "Mean.npy",
                     "--std", tmp_path / "Std.npy", "--fps", 20, "--export", "")
    assert result.exit_code == 0, result.output
    assert "de-normalised by --mean/--std" in result.output
    assert "frames/s assumed" not in result.output  # --fps given: no rate assumed
    (track,) = load_animation(tmp_path / "out" / "animation.json").tracks
    shifted = P - np.array([P[0, 0, 0], 0, P[0, 0, 2]])
    assert np.linalg.norm(_track_joints(track)[:, :22] - shifted, axis=-1).mean() < 0.03
    # half the pair is an error naming the options, not a traceback
    result = animate_shipped(tmp_path / "feats.npy", "--out", tmp_path / "o2", "--mean", tmp_path / "Mean.npy")
    assert result.exit_code == 1 and "--mean and --std go together" in result.output


def test_mdm_results_npy_one_track_per_motion(animate_shipped, tmp_path):
    """MDM's sample/generate.py: np.save('results.npy', {'motion': (N, 22, 3, T), 'text', 'lengths', ...})."""
    from workflows.animation.files import load_animation

    a, b = walking_joints(30, seed=1)[:, :22], walking_joints(30, seed=2)[:, :22]
    motion = np.stack([a, b]).transpose(0, 2, 3, 1).astype(np.float32)  # (2, 22, 3, 30)
    np.save(tmp_path / "results.npy", {"motion": motion, "text": ["a person walks", "a person walks forward"],
                                       "lengths": np.array([30, 24]), "num_samples": 2, "num_repetitions": 1})
    result = animate_shipped(tmp_path / "results.npy", "--out", tmp_path / "out", "--export", "")
    assert result.exit_code == 0, result.output
    anim = load_animation(tmp_path / "out" / "animation.json")
    assert [t.num_frames for t in anim.tracks] == [30, 24]
    assert np.linalg.norm(_track_joints(anim.tracks[1])[:, :22] - b[:24], axis=-1).mean() < 0.03


def test_bvh_read_as_joint_positions_round_trip(animate_shipped, tmp_path):
    """The BVH an animation exports, read back as joint positions, gives the same motion."""
    from workflows.animation.files import load_animation

    P = walking_joints(30)[:, :22]
    np.save(tmp_path / "m.npy", P)
    assert animate_shipped(tmp_path / "m.npy", "--out", tmp_path / "a", "--fps", 30).exit_code == 0
    result = animate_shipped(tmp_path / "a" / "person_0.bvh", "--out", tmp_path / "b", "--export", "")
    assert result.exit_code == 0, result.output
    assert "a BVH read as joint positions" in result.output
    first = load_animation(tmp_path / "a" / "animation.json").tracks[0]
    anim = load_animation(tmp_path / "b" / "animation.json")
    assert anim.fps == pytest.approx(30.0, rel=1e-3)
    err = np.linalg.norm(_track_joints(anim.tracks[0])[:, :22] - _track_joints(first)[:, :22], axis=-1)
    assert err.mean() < 0.03, err.mean()


def test_bad_joint_files_are_one_line(animate_shipped, tmp_path):
    np.save(tmp_path / "nan.npy", np.full((10, 22, 3), np.nan))
    result = animate_shipped(tmp_path / "nan.npy", "--out", tmp_path / "o")
    assert result.exit_code == 1 and "NaN" in result.output and "Traceback" not in result.output
    np.save(tmp_path / "cm.npy", walking_joints(10)[:, :22] * 1e5)
    result = animate_shipped(tmp_path / "cm.npy", "--out", tmp_path / "o")
    assert result.exit_code == 1 and "expected metres" in result.output
    np.save(tmp_path / "mdm.npy", {"motion": np.zeros((2, 22, 3, 9)), "lengths": np.array(["9", "x"])})
    result = animate_shipped(tmp_path / "mdm.npy", "--out", tmp_path / "o")
    assert result.exit_code == 1 and "'lengths'" in result.output
    np.save(tmp_path / "flat.npy", np.zeros((10, 22, 3)))
    result = animate_shipped(tmp_path / "flat.npy", "--out", tmp_path / "o")
    assert result.exit_code == 1 and "error" in result.output.lower() and "Traceback" not in result.output


# ----------------------------------------------------------------------------- a BVH whose body is in its rotations

_UNIT = 0.0254 / 0.45  # cgspeed CMU units
_BVH_JOINTS = (  # (name, parent, SMPL joint or None for a zero-OFFSET helper), CMU cgspeed names
    ("Hips", None, 0), ("LHipJoint", "Hips", None), ("LeftUpLeg", "LHipJoint", 1), ("LeftLeg", "LeftUpLeg", 4),
    ("LeftFoot", "LeftLeg", 7), ("LeftToeBase", "LeftFoot", 10), ("RHipJoint", "Hips", None),
    ("RightUpLeg", "RHipJoint", 2), ("RightLeg", "RightUpLeg", 5), ("RightFoot", "RightLeg", 8),
    ("RightToeBase", "RightFoot", 11), ("LowerBack", "Hips", 3), ("Spine", "LowerBack", 6), ("Spine1", "Spine", 9),
    ("Neck", "Spine1", None), ("Neck1", "Neck", 12), ("Head", "Neck1", 15), ("LCollarRoot", "Spine1", None),
    ("LeftShoulder", "LCollarRoot", 13), ("LeftArm", "LeftShoulder", 16), ("LeftForeArm", "LeftArm", 18),
    ("LeftHand", "LeftForeArm", 20), ("RCollarRoot", "Spine1", None), ("RightShoulder", "RCollarRoot", 14),
    ("RightArm", "RightShoulder", 17), ("RightForeArm", "RightArm", 19), ("RightHand", "RightForeArm", 21))


def test_bvh_whose_body_is_in_its_rotations(animate_shipped, tmp_path):
    """Every OFFSET along +y (MediaPipe-to-BVH): read by forward kinematics as joint positions, no options."""
    from smplik.data.bvh import read_bvh
    from workflows.animation.files import load_animation
    from workflows.animation.joint_motion import offsets_share_one_direction

    P = walking_joints(30)[:, :22]
    write_rotation_only_bvh(tmp_path / "mp.bvh", P, _BVH_JOINTS, unit=_UNIT)
    motion = read_bvh(tmp_path / "mp.bvh")
    names = list(motion.joint_names)
    fk = motion.positions[:, [names.index(n) for n, _, j in _BVH_JOINTS if j is not None]] * _UNIT
    smpl = [j for _, _, j in _BVH_JOINTS if j is not None]
    assert np.allclose(fk, P[:, smpl], atol=1e-4)  # the fixture's FK is the body
    assert offsets_share_one_direction(tmp_path / "mp.bvh")
    result = animate_shipped(tmp_path / "mp.bvh", "--out", tmp_path / "out", "--export", "")
    assert result.exit_code == 0, result.output
    assert "OFFSETs all point one way" in result.output
    (track,) = load_animation(tmp_path / "out" / "animation.json").tracks
    err = np.linalg.norm(_track_joints(track)[:, :22] - P, axis=-1)
    assert err.mean() < 0.03, err.mean()


def test_t2m_gpt_motion_npy_and_a_character(animate_shipped, tmp_path):
    """T2M-GPT's demo: np.save('motion.npy', recover_from_ric(...).reshape(1, -1, 22, 3)); onto a Mixamo character
    (workflows/layout_examples.py writes Mixamo's BVH layout): the BVH is the character's own skeleton."""
    from smplik.data.bvh import read_bvh
    from workflows.animation.files import load_animation
    from workflows.layout_examples import write_mixamo_bvh

    P = walking_joints(24)[:, :22]
    np.save(tmp_path / "motion.npy", P[None].astype(np.float32))
    write_mixamo_bvh(tmp_path / "hero.bvh", rest_joints(np.zeros(10), "neutral") * 1.2)
    result = animate_shipped(tmp_path / "motion.npy", "--out", tmp_path / "out", "--character", tmp_path / "hero.bvh")
    assert result.exit_code == 0, result.output
    (track,) = load_animation(tmp_path / "out" / "animation.json").tracks
    assert track.num_frames == 24 and track.scale == pytest.approx(1.2, rel=0.05)  # the character's size
    out = read_bvh(tmp_path / "out" / "person_0.bvh")
    assert out.num_frames == 24 and out.joint_names[0].startswith("mixamorig:")


def test_from_estimate_on_joints_points_to_animate(tmp_path):
    from workflows.estimators import EstimateFormatError, read_estimate

    np.save(tmp_path / "j.npy", np.zeros((5, 22, 3)))
    with pytest.raises(EstimateFormatError, match="scene animate FILE"):
        read_estimate(tmp_path / "j.npy")
