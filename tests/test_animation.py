"""``smplik scene animate``: video estimates in producers' layouts -> animation file + animated BVH; cleaning math."""

from __future__ import annotations

import json

import numpy as np
import pytest
from animation_fixtures import video_motion, write_gvhmr_video, write_phalp_video, write_wham_video
from estimator_fixtures import write_aist
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, JOINT_NAMES
from smplik.data.bvh import read_bvh
from workflows.animation.clean import (
    CleanConfig,
    foot_contacts,
    foot_skating,
    jitter,
    lock_feet,
    one_euro,
    smooth_motion,
    two_bone_ik,
)
from workflows.animation.clips import AnimationTrack, joints_of, rest_joints, select_keyframes
from workflows.animation.files import AnimationFileError, animation_to_dict, load_animation, save_animation

MM = 1e-3


@pytest.fixture()
def animate(monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    return lambda *args: CliRunner().invoke(scene_app, ["animate", *map(str, args)])


def _track_joints(track: AnimationTrack) -> np.ndarray:
    R = Rotation.from_rotvec(np.concatenate([track.global_orient[:, None], track.body_pose], 1).reshape(-1, 3))
    return joints_of(R.as_matrix().reshape(-1, 24, 3, 3), track.transl, rest_joints(track.betas, track.gender))


def _accessor(g, index: int) -> np.ndarray:
    """An accessor's float32 data (count, width) from a loaded GLB."""
    acc = g.accessors[index]
    view = g.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc.type]
    raw = g.binary_blob()[view.byteOffset + (acc.byteOffset or 0):][:acc.count * width * 4]
    return np.frombuffer(raw, dtype=np.float32).reshape(acc.count, width)


def _glb_animation_joints(path, names) -> tuple[np.ndarray, np.ndarray]:
    """Sampler times (T,) and world joint positions (T, J, 3) of the GLB's animation by FK of its node TRS."""
    import pygltflib

    g = pygltflib.GLTF2.load_binary(str(path))
    (anim,) = g.animations
    trs = {}
    for ch in anim.channels:
        trs[(ch.target.node, ch.target.path)] = _accessor(g, anim.samplers[ch.sampler].output)
    times = _accessor(g, anim.samplers[0].input)[:, 0]
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    index = {n.name: i for i, n in enumerate(g.nodes)}
    T = len(times)
    world: dict[int, np.ndarray] = {}

    def matrix(node: int) -> np.ndarray:
        if node not in world:
            n = g.nodes[node]
            if (node, "rotation") in trs:  # animated
                q, t, sc = trs[(node, "rotation")], trs[(node, "translation")], trs[(node, "scale")]
            else:  # a static node (a glTF character's armature)
                q = np.tile(n.rotation or [0.0, 0.0, 0.0, 1.0], (T, 1))
                t, sc = np.tile(n.translation or [0.0] * 3, (T, 1)), np.tile(n.scale or [1.0] * 3, (T, 1))
            M = np.tile(np.eye(4), (T, 1, 1))
            M[:, :3, :3] = Rotation.from_quat(q).as_matrix() * sc[:, None]
            M[:, :3, 3] = t
            if n.matrix is not None and (node, "rotation") not in trs:
                M[:] = np.asarray(n.matrix, dtype=np.float64).reshape(4, 4).T
            world[node] = matrix(parent[node]) @ M if node in parent else M
        return world[node]

    return times, np.stack([matrix(index[n])[:, :3, 3] for n in names], 1)


def _one_error_line(result) -> str:
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 1 and len(lines) == 1 and "Traceback" not in result.output, result.output
    return lines[0]


def test_gvhmr_video_gives_every_frame_keyframes_and_an_animated_bvh(tmp_path, animate):
    from workflows.estimators import read_estimate
    from workflows.scene.pipeline import retarget_to_body

    aa, transl = video_motion(40, seed=1)
    path = write_gvhmr_video(tmp_path, aa, transl)
    res = animate(path, "--out", tmp_path / "raw", "--fps", 25, "--smoothing", "none", "--no-foot-lock",
                  "--max-effectors", 3, "--export", "bvh,glb", "--space", "camera")
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "raw" / "animation.json")
    assert anim.fps == 25 and anim.space == "camera" and anim.source_format == "gvhmr" and anim.camera is not None
    (track,) = anim.tracks
    assert track.num_frames == 40 and track.first_frame == 0
    # every row is that frame as from-estimate reads and retargets it
    for f in (0, 17, 39):
        person = read_estimate(path, frame=f, space="camera")[0]
        want = retarget_to_body(person, track.betas, track.gender, 1.0)
        assert np.allclose(track.transl[f], want.transl, atol=1e-9)
        assert np.allclose(Rotation.from_rotvec(track.body_pose[f]).as_matrix(),
                           Rotation.from_rotvec(want.body_pose).as_matrix(), atol=1e-9)
    keys = [k.frame for k in track.keyframes]
    assert keys[0] == 0 and keys[-1] == 39 and 2 < len(keys) < 40
    assert all(0 < len(k.effectors) <= 3 for k in track.keyframes)
    # the animated BVH: 40 frames at 1/25 s, SMPL's joint names, joints within 1 mm of the animation's
    bvh = read_bvh(tmp_path / "raw" / "person_0.bvh")
    assert bvh.num_frames == 40 and bvh.frame_time == pytest.approx(1 / 25, abs=1e-6)
    assert sorted(bvh.joint_names) == sorted(JOINT_NAMES)
    order = [bvh.index(n) for n in JOINT_NAMES]
    assert np.abs(bvh.positions[:, order] - _track_joints(track)).max() < MM
    # the animated GLB (skinned SMPL mesh): 40 samples 1/25 s apart, joint nodes within 1 mm
    times, glb_joints = _glb_animation_joints(tmp_path / "raw" / "person_0.glb", JOINT_NAMES)
    assert len(times) == 40 and np.allclose(np.diff(times), 1 / 25, atol=1e-6)
    assert np.abs(glb_joints - _track_joints(track)).max() < MM
    # cleaning on: less jitter, still close to the estimate
    res = animate(path, "--out", tmp_path / "clean", "--fps", 25, "--max-effectors", 2)  # world by default
    assert res.exit_code == 0, res.output
    clean = load_animation(tmp_path / "clean" / "animation.json")
    assert clean.space == "world" and clean.camera is None and clean.clean == CleanConfig()
    raw_world = load_animation(tmp_path / "raw" / "animation.json")  # camera frame; compare local motion only
    assert jitter(_track_joints(clean.tracks[0])) < 0.7 * jitter(_track_joints(raw_world.tracks[0]))


def test_wham_tracks_ranges_and_bad_input_get_one_line(tmp_path, animate):
    a0, t0 = video_motion(30, seed=2, fmt="wham")
    a1, t1 = video_motion(20, seed=3, fmt="wham", x=0.8)
    path = write_wham_video(tmp_path, {0: (a0, t0, np.arange(30)), 1: (a1, t1, np.arange(10, 30))})
    res = animate(path, "--out", tmp_path / "all", "--fps", 30, "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "all" / "animation.json")
    assert anim.space == "world" and [(t.track_id, t.first_frame, t.num_frames) for t in anim.tracks] == [
        ("0", 0, 30), ("1", 10, 20)]
    assert all(k.frame in t.frames for t in anim.tracks for k in t.keyframes)
    assert read_bvh(tmp_path / "all" / "person_1.bvh").num_frames == 20
    res = animate(path, "--out", tmp_path / "one", "--fps", 30, "--frames", "12:20", "--track", 1,
                  "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    (t,) = load_animation(tmp_path / "one" / "animation.json").tracks
    assert (t.track_id, t.first_frame, t.num_frames) == ("1", 12, 8)
    out = tmp_path / "bad"
    assert "track 1 starts at frame 10" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--frames", "0:20",
                                                             "--track", 1))
    assert "outside the clip" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--frames", "0:50"))
    assert "A < B" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--frames", "9:3"))
    assert "'all' or 'A:B'" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--frames", "1-3"))
    assert "frame rate" in _one_error_line(animate(path, "--out", out, "--fps", 0))
    assert "pass --fps" in _one_error_line(animate(path, "--out", out))
    assert "unknown export format(s) ['fbx']" in _one_error_line(animate(path, "--out", out, "--fps", 30,
                                                                        "--export", "bvh,fbx"))
    assert "smoothing must be" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--smoothing", "wavy"))
    assert "smoothness must be a positive number" in _one_error_line(animate(path, "--out", out, "--fps", 30,
                                                                             "--smoothness", 0))
    assert "keyframe threshold" in _one_error_line(animate(path, "--out", out, "--fps", 30,
                                                           "--keyframe-threshold", 0))
    assert "refusing more than 5" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--max-frames", 5))
    assert "no track '7'" in _one_error_line(animate(path, "--out", out, "--fps", 30, "--track", 7))
    far = write_wham_video(tmp_path, {4: (a0[:2], t0[:2], np.array([0, 900_000_000]))})  # sparse ids: no hang
    assert "no pose at frame(s) 1, 2, 3" in _one_error_line(animate(far, "--out", out, "--fps", 30))
    from workflows.animation.clips import read_clip

    with pytest.raises(ValueError, match="refusing more than 1 "):
        read_clip(far, max_frames=1)
    gap = write_wham_video(tmp_path, {3: (a0[:20], t0[:20], np.r_[np.arange(10), np.arange(14, 24)])})
    assert "frame(s) 10, 11, 12, 13" in _one_error_line(animate(gap, "--out", out, "--fps", 30))
    assert not out.exists() or not (out / "animation.json").exists()


def test_phalp_tracks_and_aist_on_a_custom_character(tmp_path, animate):
    from workflows.character import character_from_estimate, smpl_to_custom

    a, t = video_motion(12, seed=4, fmt="phalp")
    b, u = video_motion(12, seed=5, fmt="phalp", x=0.8)
    frames = [{3: (a[i], t[i]), **({8: (b[i], u[i])} if i >= 4 else {})} for i in range(12)]
    path = write_phalp_video(tmp_path, frames)
    res = animate(path, "--out", tmp_path / "phalp", "--fps", 24, "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "phalp" / "animation.json")
    assert [(x.track_id, x.first_frame, x.num_frames) for x in anim.tracks] == [("3", 0, 12), ("8", 4, 8)]
    # AIST++: world frame at its 60 frames/s, on the demo's Mixamo character
    from workflows.examples_gen import write_mixamo_character

    aa, tr = video_motion(16, seed=6, fmt="gvhmr")
    aist = write_aist(tmp_path, *(_x for _x in (aa, tr)))
    hero = write_mixamo_character(tmp_path / "mixamo_character.bvh")
    res = animate(aist, "--out", tmp_path / "aist", "--character", hero, "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "aist" / "animation.json")
    (track,) = anim.tracks
    assert anim.fps == 60 and anim.space == "world" and track.skeleton is not None and track.num_frames == 16
    char = character_from_estimate(track.skeleton.path, track.skeleton.options, track.betas, track.scale,
                                   track.gender)
    bvh = read_bvh(tmp_path / "aist" / "person_0.bvh")
    assert bvh.num_frames == 16 and bvh.frame_time == pytest.approx(1 / 60, abs=1e-6)
    assert bvh.joint_names == read_bvh(hero).joint_names
    for f in (0, 9, 15):  # exported in the scene's world frame (metres, y-up), like the GLB
        _, p_file = smpl_to_custom(track.pose(f), char).positions(char)
        p_world = char.units_m * p_file @ char.C_canon_file.T - char.shift
        assert np.abs(bvh.positions[f] - p_world).max() < MM


def test_animation_file_round_trips_and_the_reader_is_strict(tmp_path, animate):
    aa, transl = video_motion(10, seed=7)
    res = animate(write_gvhmr_video(tmp_path, aa, transl), "--out", tmp_path, "--fps", 30, "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    path = tmp_path / "animation.json"
    anim = load_animation(path)
    again = save_animation(anim, tmp_path / "again.json")
    good, back = json.loads(path.read_text()), json.loads(again.read_text())
    keys_good, keys_back = good["tracks"][0].pop("keyframes"), back["tracks"][0].pop("keyframes")
    assert back == good  # poses, contacts, body, camera, clean settings exactly
    assert [k["frame"] for k in keys_back] == [k["frame"] for k in keys_good]
    for k_good, k_back in zip(keys_good, keys_back, strict=True):  # rotations re-orthonormalised on reading
        for e_good, e_back in zip(k_good["effectors"], k_back["effectors"], strict=True):
            assert e_good["joint"] == e_back["joint"] and np.allclose(e_good["value"], e_back["value"], atol=1e-12)
    good["tracks"][0]["keyframes"] = keys_good

    def broken(edit) -> str:
        data = json.loads(json.dumps(good))
        edit(data)
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(data))
        with pytest.raises(AnimationFileError) as info:
            load_animation(bad)
        message = str(info.value)
        assert "\n" not in message and message.startswith(str(bad))
        return message

    assert "tracks[0].keyframes[0].frame: 10 is outside the track's frames 0..9" in broken(
        lambda d: d["tracks"][0]["keyframes"][0].update(frame=10))
    assert "fps: must be a frame rate" in broken(lambda d: d.update(fps=0))
    assert "version" in broken(lambda d: d.update(version=2))
    assert "unknown key(s) ['colour']" in broken(lambda d: d["tracks"][0].update(colour=1))
    assert "tracks[0].body_pose: has 9 frames; expected 10" in broken(
        lambda d: d["tracks"][0].update(body_pose=d["tracks"][0]["body_pose"][:9]))
    assert "tracks[0].contacts" in broken(lambda d: d["tracks"][0].update(contacts=[[1, 0]] * 10))
    assert "tracks[0].betas" in broken(lambda d: d["tracks"][0].update(betas=[0.0] * 3))
    assert "tracks[0].repaired[0]: 10 is outside [0, 9]" in broken(lambda d: d["tracks"][0].update(repaired=[10]))
    assert "strictly increasing" in broken(lambda d: d["tracks"][0]["keyframes"].append(
        d["tracks"][0]["keyframes"][0]))
    # atomic: an animation that would not read back is refused and the old file stays
    import dataclasses

    before = path.read_bytes()
    nan = dataclasses.replace(anim.tracks[0], transl=anim.tracks[0].transl * np.nan)
    with pytest.raises(AnimationFileError):
        save_animation(dataclasses.replace(anim, tracks=(nan,)), path)
    assert path.read_bytes() == before
    assert animation_to_dict(load_animation(path))["tracks"][0]["transl"] == good["tracks"][0]["transl"]


# ----------------------------------------------------------------------------- cleaning math


def test_two_bone_ik_reaches_targets_and_keeps_bone_lengths():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(500, 3))
    b = a + rng.normal(size=(500, 3))
    c = b + rng.normal(size=(500, 3))
    l_ab, l_bc = np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1)
    direction = rng.normal(size=(500, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    reach = np.abs(l_ab - l_bc) + (l_ab + l_bc - np.abs(l_ab - l_bc)) * rng.uniform(0.05, 0.95, 500)
    target = a + direction * reach[:, None]
    R_a, R_b = two_bone_ik(a, b, c, target, np.tile([1.0, 0.0, 0.0], (500, 1)))
    b2 = a + (R_a @ (b - a)[..., None])[..., 0]
    c2 = a + (R_a @ ((b - a) + (R_b @ (c - b)[..., None])[..., 0])[..., None])[..., 0]
    assert np.abs(c2 - target).max() < 1e-9
    assert np.abs(np.linalg.norm(b2 - a, axis=-1) - l_ab).max() < 1e-9
    assert np.abs(np.linalg.norm(c2 - b2, axis=-1) - l_bc).max() < 1e-9
    # a straight SMPL-like leg bends its knee forward (+z), about minus the knee's x axis
    R_a, R_b = two_bone_ik(np.zeros((1, 3)), np.array([[0, -0.4, 0.0]]), np.array([[0, -0.8, 0.0]]),
                           np.array([[0, -0.6, 0.0]]), -np.array([[1.0, 0, 0]]))
    assert (R_a @ np.array([0, -0.4, 0.0]))[0, 2] > 0.2


def test_one_euro_smooths_jitter_and_keeps_fast_motion():
    rng = np.random.default_rng(0)
    t = np.arange(300) / 30.0
    slow = np.stack([np.sin(0.5 * t), np.cos(0.5 * t), 0 * t], -1)
    noisy = slow + rng.normal(0, 0.01, slow.shape)
    out = one_euro(noisy, 30.0, min_cutoff_hz=1.0, beta=0.3)
    assert np.abs(out - slow).mean() < 0.4 * np.abs(noisy - slow).mean()
    fast = np.stack([np.sin(2 * np.pi * 1.5 * t), 0 * t, 0 * t], -1)  # 1.5 Hz swing of 1 rad (9 rad/s peaks)
    kept = one_euro(fast, 30.0, min_cutoff_hz=1.0, beta=0.3)
    assert np.abs(kept - fast)[20:-20].max() < 0.25  # the adaptive cutoff follows the fast swing
    fixed = one_euro(fast, 30.0, min_cutoff_hz=1.0, beta=0.0)  # the same filter with a fixed 1 Hz cutoff
    assert np.abs(fixed - fast)[20:-20].max() > 0.5


def _standing_sway(T: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local rotations (T, 24, 3, 3), transl and rest joints of a person swaying with jittery legs (feet should
    stay planted)."""
    from smplik.conventions import Gender

    rng = np.random.default_rng(seed)
    aa = np.zeros((T, 24, 3))
    aa[:, [1, 2, 4, 5], 0] = rng.normal(0, 0.03, (T, 4))
    aa[:, [1, 2], 0] -= 0.25  # slightly bent legs (a straight leg cannot reach a lock above its reach)
    aa[:, [4, 5], 0] += 0.5
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    transl = np.zeros((T, 3))
    J = rest_joints(np.zeros(10), Gender.NEUTRAL)
    transl[:, 1] = -J[[10, 11], 1].min()  # feet on y = 0
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    return R, transl, J


def test_foot_contacts_are_locked_without_skating_and_only_legs_change():
    R, transl, J = _standing_sway()
    p = joints_of(R, transl, J)
    cfg = CleanConfig(contact_speed_mps=3.0)  # the jitter here is fast; the feet are low all along
    contact = foot_contacts(p, 30.0, cfg)
    assert contact.mean() > 0.9
    locked = lock_feet(R, p, contact, cfg.blend_frames)
    p2 = joints_of(locked, transl, J)
    assert foot_skating(p2, contact) < 0.05 * foot_skating(p, contact)
    feet = [JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"]]
    assert np.abs(p2[:, feet] - p[:, feet].mean(0)).max() < 0.005  # pinned near the mean
    legs = {JOINT_INDEX[n] for n in ("left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
                                     "right_ankle")}
    others = [j for j in range(24) if j not in legs]
    assert np.array_equal(locked[:, others], R[:, others])
    # the ankles keep their world rotations
    from workflows.animation.clean import local_to_world

    ankles = [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]]
    assert np.abs(local_to_world(locked)[:, ankles] - local_to_world(R)[:, ankles]).max() < 1e-9


def test_smoothing_methods_and_keyframes():
    R, transl, J = _standing_sway(seed=1)
    p = joints_of(R, transl, J)
    for method in ("one_euro", "savgol"):
        R_s, t_s = smooth_motion(R, transl, 30.0, CleanConfig(smoothing=method))
        assert jitter(joints_of(R_s, t_s, J)) < 0.5 * jitter(p)
    # a motion that is an interpolation of its ends needs two keyframes; a sharp middle pose adds one there
    from workflows.animation.clips import interpolate_poses

    w = np.linspace(0, 1, 21)
    R_end = Rotation.from_rotvec(np.tile([0.0, 0.0, 0.8], (24, 1))).as_matrix()
    R_i, t_i = interpolate_poses(R[0], R_end, transl[0], transl[0] + [0.3, 0, 0], w)
    assert select_keyframes(R_i, t_i, J, 0.01) == [0, 20]
    R_i[13, JOINT_INDEX["left_shoulder"]] = Rotation.from_rotvec([0, 0, 1.5]).as_matrix()
    assert 13 in select_keyframes(R_i, t_i, J, 0.01)


def test_keyframe_edit_moves_only_its_window(tmp_path, animate, best_solver):
    from typer.testing import CliRunner

    from smplik.effector_schema import save_effector_file
    from smplik.effectors import Effector
    from workflows.cli import scene_app

    aa, transl = video_motion(40, seed=8)
    res = animate(write_gvhmr_video(tmp_path, aa, transl), "--out", tmp_path, "--fps", 30, "--max-effectors", 4)
    assert res.exit_code == 0, res.output
    path = tmp_path / "animation.json"
    before = load_animation(path).tracks[0]
    frame, window = 20, 5
    p_before = _track_joints(before)
    wrist = JOINT_INDEX["right_wrist"]
    target = p_before[frame, wrist] + np.array([0.0, 0.15, 0.1])
    effs = [Effector.position("right_wrist", target), Effector.position("pelvis", p_before[frame, 0]),
            Effector.position("left_wrist", p_before[frame, JOINT_INDEX["left_wrist"]])]
    save_effector_file(tmp_path / "edit.json", effs)
    res = CliRunner().invoke(scene_app, ["edit-keyframe", str(path), "--frame", str(frame), "--effectors",
                                         str(tmp_path / "edit.json"), "--window", str(window),
                                         "--exact", "--out", str(tmp_path / "edited" / "edited.json"),
                                         "--export", "bvh"])
    assert res.exit_code == 0, res.output
    after = load_animation(tmp_path / "edited" / "edited.json").tracks[0]
    outside = np.r_[0:frame - window, frame + window + 1:40]
    for key in ("global_orient", "body_pose", "transl"):  # bit for bit outside the window
        assert np.array_equal(getattr(after, key)[outside], getattr(before, key)[outside])
        assert not np.array_equal(getattr(after, key)[frame], getattr(before, key)[frame])
    p_after = _track_joints(after)
    key = next(k for k in after.keyframes if k.frame == frame)  # the given effectors merged into the recovered
    names = [e.joint_name for e in key.effectors]
    assert {"right_wrist", "pelvis", "left_wrist"} <= set(names) and len(names) == len(set(names))
    assert np.allclose(key.effectors[names.index("right_wrist")].value, target)
    solved = best_solver.solve(list(key.effectors), betas=before.betas, gender=before.gender)
    assert np.abs(p_after[frame] - np.asarray(solved.joints)).max() < 1e-4  # --exact: the keyframe is the solve
    moved = np.linalg.norm(p_after[:, wrist] - p_before[:, wrist], axis=-1)
    assert moved[frame] > moved[frame - 3] > moved[frame - window] > 0 == moved[frame - window - 1]
    bvh = read_bvh(tmp_path / "edited" / "person_0.bvh")  # re-exported: the edit is in the file
    order = [bvh.index(n) for n in JOINT_NAMES]
    assert bvh.num_frames == 40 and np.abs(bvh.positions[:, order] - p_after).max() < MM
    bad = CliRunner().invoke(scene_app, ["edit-keyframe", str(path), "--frame", "99", "--effectors",
                                         str(tmp_path / "edit.json")])
    assert "frame 99 is outside track person_0's frames 0..39" in _one_error_line(bad)


def test_single_frame_glitches_are_flagged_and_repaired_but_fast_motion_is_not():
    from smplik.pose import Pose
    from workflows.animation.clean import glitch_frames
    from workflows.animation.clips import clean_track

    R, transl, J = _standing_sway(T=40, seed=2)
    aa = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(40, 24, 3)
    aa[:, 16, 2] += 1.2 * np.sin(2 * np.pi * 1.5 * np.arange(40) / 30.0)  # a fast real arm swing
    truth = joints_of(Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(40, 24, 3, 3), transl, J)
    assert not glitch_frames(truth).any()
    aa[17, 18] += [0.0, 2.0, 0.0]  # frame 17: the left elbow snaps away for one frame
    poses = [Pose(aa[t, 0], aa[t, 1:], transl[t], np.zeros(10)) for t in range(40)]
    _, _, _, raw, clean, glitches = clean_track(poses, 30.0, CleanConfig(foot_lock=False, smoothing="none"), 1.0)
    assert np.nonzero(glitches)[0].tolist() == [17]
    hand = JOINT_INDEX["left_wrist"]
    assert np.linalg.norm(raw[17, hand] - raw[16, hand]) > 0.2
    # the neighbours' slerp is near the unglitched pose (the fast swing's curve is what it misses)
    assert np.linalg.norm(raw[17] - truth[17], axis=-1).max() > 0.3 > 0.08 > np.linalg.norm(
        clean[17] - truth[17], axis=-1).max()
    assert np.abs(clean[:17] - raw[:17]).max() < 1e-9  # the other frames are kept


def test_gltf_character_gets_an_animated_glb_of_its_own_file(tmp_path, animate):
    from workflows.character import character_from_estimate, smpl_to_custom
    from workflows.layout_examples import smpl_rest, write_mixamo_gltf

    J, V, F, W = smpl_rest()
    hero = write_mixamo_gltf(tmp_path / "hero.glb", J, (V, F, W))
    aa, tr = video_motion(12, seed=9, fmt="gvhmr")
    res = animate(write_aist(tmp_path, aa, tr), "--out", tmp_path / "out", "--character", hero, "--max-effectors", 2,
                  "--export", "bvh,glb")
    assert res.exit_code == 0, res.output
    (track,) = load_animation(tmp_path / "out" / "animation.json").tracks
    char = character_from_estimate(track.skeleton.path, track.skeleton.options, track.betas, track.scale,
                                   track.gender)
    want = np.stack([smpl_to_custom(track.pose(f), char).positions(char)[1] for f in range(12)])
    want = char.units_m * want @ char.C_canon_file.T - char.shift  # the GLB sits in the scene's world frame
    times, got = _glb_animation_joints(tmp_path / "out" / "person_0.glb", char.names)
    assert len(times) == 12 and np.allclose(np.diff(times), 1 / 60, atol=1e-6)  # AIST++: 60 frames/s
    assert np.abs(got - want).max() < MM


def test_preview_over_the_source_video_and_in_3d(tmp_path, animate, monkeypatch):
    import os

    import imageio.v2 as imageio
    from estimator_fixtures import IMAGE_H, IMAGE_W

    monkeypatch.setenv("PYOPENGL_PLATFORM", os.environ.get("PYOPENGL_PLATFORM", "egl"))
    aa, transl = video_motion(6, seed=10)
    path = write_gvhmr_video(tmp_path, aa, transl)
    video = tmp_path / "input.mp4"
    imageio.mimsave(video, [np.full((IMAGE_H, IMAGE_W, 3), 40 + 20 * i, np.uint8) for i in range(6)], fps=30,
                    macro_block_size=1)
    res = animate(path, "--out", tmp_path / "out", "--fps", 30, "--space", "camera", "--max-effectors", 2,
                  "--video", video, "--preview", tmp_path / "out" / "preview.gif")
    if res.exit_code == 1 and "OpenGL" in res.output:  # smplik.render.RenderError: no backend on this machine
        pytest.skip(f"no OpenGL backend for pyrender (PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')})")
    assert res.exit_code == 0, res.output
    gif = imageio.mimread(tmp_path / "out" / "preview.gif")
    assert len(gif) == 3 and gif[0].shape[:2] == (IMAGE_H, IMAGE_W)  # a GIF: every 2nd frame, 15 frames/s
    assert imageio.get_reader(tmp_path / "out" / "preview.gif").get_meta_data()["duration"] == pytest.approx(
        1000 / 15, abs=10)  # GIF frame delays are whole centiseconds
    background = np.asarray(gif[2])[..., :3].astype(int)  # source frame 4
    assert (np.abs(background - (40 + 20 * 4)).max(-1) > 60).mean() > 0.01  # the person drawn over the frame
    res = animate(path, "--out", tmp_path / "out3d", "--fps", 30, "--max-effectors", 2, "--preview",
                  tmp_path / "out3d" / "preview.mp4", "--preview-every", 2)
    assert res.exit_code == 0, res.output
    assert imageio.get_reader(tmp_path / "out3d" / "preview.mp4").count_frames() == 3
    assert "camera frame" in _one_error_line(animate(path, "--out", tmp_path / "bad", "--fps", 30, "--video", video,
                                                     "--preview", tmp_path / "bad" / "p.gif"))


def test_timeline_scrubs_plays_jumps_keyframes_and_applies_edits_with_undo(tmp_path, animate, best_solver):
    import dataclasses

    from smplik.effectors import Effector
    from workflows.animation.clips import AnimationError
    from workflows.editor.timeline import AnimationTimeline

    aa, transl = video_motion(30, seed=11)
    res = animate(write_gvhmr_video(tmp_path, aa, transl), "--out", tmp_path, "--fps", 30, "--max-effectors", 3)
    assert res.exit_code == 0, res.output
    tl = AnimationTimeline.open(tmp_path / "animation.json", best_solver, window=4)
    assert tl.frames == range(0, 30) and tl.frame == 0 and tl.frame_time == pytest.approx(1 / 30)
    assert tl.step(29) == 29 and tl.step() == 0  # playback wraps
    keys = tl.keyframes()
    assert keys[0] == 0 and keys[-1] == 29
    assert tl.next_keyframe() == keys[1] and tl.next_keyframe(-1) == 0
    with pytest.raises(AnimationError, match="outside the animation's frames 0..29"):
        tl.set_frame(30)
    with pytest.raises(AnimationError, match="blend window"):
        tl.window = -1
    tl.set_frame(15)
    scene = tl.scene()
    (c,) = scene.characters
    before = tl.animation.tracks[0]
    p15 = _track_joints(before)[15]
    moved = dataclasses.replace(c, effectors=(Effector.position("left_wrist", p15[20] + [0.0, 0.2, 0.0]),
                                              Effector.position("pelvis", p15[0])))
    assert tl.apply_scene(dataclasses.replace(scene, characters=(moved,))) == ["person_0"]
    after = tl.animation.tracks[0]
    assert np.array_equal(after.body_pose[:11], before.body_pose[:11])
    assert np.array_equal(after.body_pose[20:], before.body_pose[20:])
    assert not np.array_equal(after.body_pose[15], before.body_pose[15])
    assert [len(k.effectors) for k in after.keyframes if k.frame == 15] == [2]
    assert tl.apply_scene(tl.scene()) == []  # nothing changed: nothing applied
    assert tl.undo() and np.array_equal(tl.animation.tracks[0].body_pose, before.body_pose)
    assert tl.redo() and np.array_equal(tl.animation.tracks[0].body_pose, after.body_pose)
    saved = tl.save(tmp_path / "edited.json")
    assert np.array_equal(load_animation(saved).tracks[0].body_pose, after.body_pose)
