"""Camera-space animations: near-orthographic producers (4D-Humans/PHALP) at a realistic depth, the floor and
foot contacts in a camera frame (tilted, the ground moving through it), pose fidelity against the estimate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from animation_fixtures import video_motion, write_phalp_video
from estimator_fixtures import FOCAL, IMAGE_H, IMAGE_W
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX
from workflows.animation.clean import (
    FOOT_JOINTS,
    CleanConfig,
    floor_plane,
    foot_contacts,
    foot_skating,
    ground_velocity,
    jitter,
    motion_metrics,
)
from workflows.animation.clips import NORMAL_FOV_DEG, camera_fov, clean_track, read_clip, realistic_depth
from workflows.animation.files import load_animation
from workflows.estimators.base import rest_pelvis


@pytest.fixture()
def animate(monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    return lambda *args: CliRunner().invoke(scene_app, ["animate", *map(str, args)])


def _phalp_walk(tmp_path, T: int = 40, depth_noise_m: float = 0.4):
    """A PHALP ``track.py`` output (tests/animation_fixtures.write_phalp_video, PHALP.track's joblib layout) of
    one person ~88 m away (4D-Humans' focal 5000/256 * max(W, H)), its depth jumping like the real files'."""
    aa, transl = video_motion(T, seed=3, fmt="phalp")
    rng = np.random.default_rng(7)
    transl = transl.copy()
    transl[:, 2] += rng.normal(0, depth_noise_m, T)
    return write_phalp_video(tmp_path, [{1: (aa[i], transl[i])} for i in range(T)])


def _pelvis(clip) -> np.ndarray:
    people = [p for _, p in next(iter(clip.tracks.values()))]
    return np.stack([p.transl for p in people]) + rest_pelvis(np.stack([p.betas for p in people]), people[0].gender)


def test_phalp_depth_is_placed_for_a_normal_camera_keeping_pixels_and_apparent_size(tmp_path, animate):
    path = _phalp_walk(tmp_path)
    clip = read_clip(path)
    camera = next(iter(clip.tracks.values()))[0][1].camera
    assert camera.focal_px == pytest.approx(FOCAL["phalp"]) and camera_fov(camera) < 3.0
    moved, new_camera, change = realistic_depth(clip, camera)
    focal_60 = max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(NORMAL_FOV_DEG / 2))
    assert new_camera.focal_px == pytest.approx(focal_60) and change.factor == pytest.approx(focal_60 / FOCAL["phalp"])
    before, after = _pelvis(clip), _pelvis(moved)
    assert np.median(-before[:, 2]) > 80 and 2.5 < np.median(-after[:, 2]) < 5.0  # ~88 m -> ~4 m
    # the same pixel (y-up camera, looking down -z) and the same apparent size (focal / depth)
    px_before = camera.focal_px * before[:, :2] / -before[:, 2:]
    px_after = new_camera.focal_px * after[:, :2] / -after[:, 2:]
    assert np.abs(px_after - px_before).max() < 1e-6
    assert np.allclose(new_camera.focal_px / -after[:, 2], camera.focal_px / -before[:, 2])
    # the depth noise shrinks by the same factor; the local rotations are untouched
    assert np.std(np.diff(after[:, 2])) == pytest.approx(change.factor * np.std(np.diff(before[:, 2])))
    rows_b, rows_a = next(iter(clip.tracks.values())), next(iter(moved.tracks.values()))
    assert all(np.array_equal(a.body_pose, b.body_pose) and np.array_equal(a.global_orient, b.global_orient)
               for (_, a), (_, b) in zip(rows_a, rows_b, strict=True))

    # end to end: one printed line, the realistic camera in the file, no depth jump taken for a glitch
    res = animate(path, "--out", tmp_path / "out", "--fps", 30, "--max-effectors", 2)
    assert res.exit_code == 0, res.output
    assert sum("near-orthographic" in line for line in res.output.splitlines()) == 1
    anim = load_animation(tmp_path / "out" / "animation.json")
    (track,) = anim.tracks
    assert anim.camera.focal_px == pytest.approx(focal_60)
    assert track.repaired == ()
    assert 2.5 < np.median(-track.transl[:, 2]) < 5.0
    assert np.abs(np.diff(track.transl[:, 2])).mean() < 0.03  # was ~0.45 m per frame at the source depth
    res = animate(path, "--out", tmp_path / "kept", "--fps", 30, "--max-effectors", 2, "--keep-depth", "--export", "")
    assert res.exit_code == 0 and "near-orthographic" not in res.output, res.output
    assert np.median(-load_animation(tmp_path / "kept" / "animation.json").tracks[0].transl[:, 2]) > 80


def test_other_cameras_and_world_clips_keep_their_depth(tmp_path):
    path = _phalp_walk(tmp_path, T=12, depth_noise_m=0.0)
    clip = read_clip(path)
    camera = next(iter(clip.tracks.values()))[0][1].camera
    assert realistic_depth(clip, camera, None)[2] is None  # switched off
    import dataclasses

    normal = dataclasses.replace(camera, focal_px=FOCAL["romp"])  # a 60-degree camera (ROMP/BEV, VIBE)
    assert realistic_depth(clip, normal)[0] is clip
    assert realistic_depth(dataclasses.replace(clip, space="world"), camera)[0].tracks is clip.tracks


def _camera_walk(T: int = 90, fps: float = 30.0, pan_mps: float = 1.2, roll_deg: float = 10.0):
    """Feet of a person walking along +x on a floor, seen by a camera that pans with them (the ground moves
    through the frame at -pan_mps) and is rolled by roll_deg (a tilted floor in camera space): joints
    (T, 24, 3) y up and the true contacts (T, 2)."""
    t = np.arange(T)
    period, step = 30, 2 * pan_mps * 30 / fps * 0.5  # one stride per 30 frames at the walking speed
    p = np.zeros((T, 24, 3))
    truth = np.zeros((T, 2), dtype=bool)
    for side, foot in enumerate(FOOT_JOINTS):
        phase = (t + side * period // 2) % period
        stance = phase < period // 2
        truth[:, side] = stance
        cycles = (t + side * period // 2) // period
        swing_s = np.clip((phase - period // 2) / (period // 2), 0, 1)
        x = cycles * step + np.where(stance, 0.0, swing_s * step)
        y = np.where(stance, 0.0, 0.12 * np.sin(np.pi * swing_s))
        p[:, foot] = np.stack([x - pan_mps / fps * t, y, np.full(T, -0.1 if side else 0.1)], 1)
    p[:, JOINT_INDEX["pelvis"]] = [0.0, 0.9, 0.0]
    R = Rotation.from_euler("z", roll_deg, degrees=True).as_matrix()
    return p @ R.T + [0.0, -0.9, -4.0], truth


def test_camera_space_contacts_follow_a_moving_tilted_ground():
    p, truth = _camera_walk()
    cfg = CleanConfig(contact_min_frames=3)
    plane = floor_plane(p)
    assert plane[0] == pytest.approx(np.tan(np.radians(10.0)), abs=0.03)  # the floor's tilt is found
    g = ground_velocity(p, 0.35 / 30)
    assert g == pytest.approx(Rotation.from_euler("z", 10, degrees=True).apply([-1.2 / 30, 0, 0]), abs=2e-3)
    found = foot_contacts(p, 30.0, cfg, g)
    inner = np.ones(len(p), dtype=bool)
    inner[[0, -1]] = False
    assert (found == truth)[inner].mean() > 0.9
    # a still ground (world frames) finds none of them: the stance feet move at the pan speed
    assert foot_contacts(p, 30.0, cfg).sum() < 0.1 * truth.sum()
    # a still camera (the same walk, ground at rest) keeps a still ground
    p_still = p + Rotation.from_euler("z", 10, degrees=True).apply([1.2 / 30, 0, 0]) * np.arange(len(p))[:, None, None]
    assert np.array_equal(ground_velocity(p_still, 0.35 / 30), np.zeros(3))
    assert foot_skating(p, truth, g) < 0.005 < 0.03 < foot_skating(p, truth)  # m/frame; the run edges blur


def test_pose_fidelity_is_pelvis_aligned_and_the_trajectory_is_separate():
    rng = np.random.default_rng(0)
    ref = rng.normal(0, 0.3, (20, 24, 3))
    moved = ref + [0.0, 0.0, 0.25]
    m = motion_metrics(moved, ref, np.zeros((20, 2), dtype=bool))
    assert m.mpjpe_mm == pytest.approx(0.0, abs=1e-9) and m.trajectory_mm == pytest.approx(250.0)
    bent = ref.copy()
    bent[:, 5] += [0.0, 0.01, 0.0]
    assert motion_metrics(bent, ref, np.zeros((20, 2), dtype=bool)).mpjpe_mm == pytest.approx(10.0 / 24)


def test_a_noisy_estimate_is_cleaned_within_the_pose_budget():
    from smplik.pose import Pose

    aa, transl = video_motion(45, seed=2, fmt="romp")  # 0.02 rad per-frame noise: PHALP-like jitter (~45 mm)
    poses = [Pose(aa[i, 0], aa[i, 1:], transl[i] * [1, -1, -1], np.zeros(10)) for i in range(len(aa))]
    budget = clean_track(poses, 30.0, CleanConfig(smoothing="sequence", pose_budget_mm=5.0), 1.0)  # an option
    free = clean_track(poses, 30.0, CleanConfig(smoothing="sequence"), 1.0)  # no budget by default
    raw = budget[3]
    held = motion_metrics(budget[4], raw, budget[2])
    assert held.mpjpe_mm <= 5.0 and jitter(budget[4]) < 0.8 * jitter(raw)
    assert motion_metrics(free[4], raw, free[2]).mpjpe_mm > 5.0  # uncapped, the default smoothness moves it more


def _running_feet(T: int, camera_x: np.ndarray, travel: float, stance_frames: int, period: int = 20):
    """Joints (T, 24, 3) of a runner's feet and pelvis along +x, seen from a camera at ``camera_x`` (T,): each foot
    stands ``stance_frames`` of every ``period`` frames (half a period apart) and moves ``travel`` metres during
    its swing, 0.3 m at its highest. Returns the joints, the true contacts (T, 2) and the foot heights (T, 2)."""
    t = np.arange(T)
    p = np.zeros((T, 24, 3))
    truth = np.zeros((T, 2), dtype=bool)
    height = np.zeros((T, 2))
    for side, foot in enumerate(FOOT_JOINTS):
        shifted = t + side * period // 2
        phase, cycles = shifted % period, shifted // period
        stance = phase < stance_frames
        s = np.clip((phase - stance_frames + 1) / (period - stance_frames + 1), 0, 1)  # swing progress
        x = cycles * travel + np.where(stance, 0.0, (3 * s ** 2 - 2 * s ** 3) * travel)
        y = np.where(stance, 0.0, 0.3 * np.sin(np.pi * s))
        truth[:, side], height[:, side] = stance, y
        p[:, foot] = np.stack([x - camera_x, y, np.full(T, -0.1 if side else 0.1)], 1)
    p[:, JOINT_INDEX["pelvis"]] = [0.0, 0.95, 0.0]
    return p, truth, height


def _camera_run(T: int = 80, fps: float = 30.0, speed_mps: float = 3.0, seed: int = 0):
    """Feet of a person running along +x (a stride of 20 frames; each foot's stance 6 frames, two flight phases
    of 4 frames) seen by a camera panning with them, y up, with a monocular estimator's per-frame noise: 5 mm
    on the image axes, 40 mm in depth (z; PHALP's depth comes from the person's image scale). Returns the
    noisy joints (T, 24, 3), the true contacts (T, 2) and the true foot heights (T, 2)."""
    p, truth, height = _running_feet(T, speed_mps * np.arange(T) / fps, speed_mps * 20 / fps, stance_frames=6)
    noise = np.random.default_rng(seed).normal(size=p.shape) * [0.005, 0.005, 0.04]
    return p + noise + [0.0, -0.9, -4.0], truth, height


def test_running_stances_are_found_on_a_noisy_panning_estimate_and_flights_stay_free():
    from smplik.sequence import smooth_trajectories
    from workflows.animation.clean import foot_noise, ground_of

    fps = 30.0
    p_raw, truth, height = _camera_run()
    cfg = CleanConfig(ground_moves=True)
    smooth = smooth_trajectories(p_raw, np.ones(p_raw.shape[:2]), cfg.smoothness)
    noise = foot_noise(p_raw, smooth, fps)
    assert noise[2] > 3 * max(noise[0], noise[1])  # the depth axis is the noisy one, and it is measured
    ground = ground_of(smooth, fps, cfg, noise=noise)
    assert ground.shape == (len(smooth), 3)  # per frame (a steady pan: the same on every frame)
    assert ground[:, 0] == pytest.approx(np.full(len(smooth), -3.0 / fps), abs=0.4 / fps)  # from the low feet only
    found = foot_contacts(smooth, fps, cfg, ground, noise)
    airborne = height > 0.05  # flight and swing frames with the foot well off the ground
    assert not found[airborne].any()  # no false contact in the air
    inner = [(side, s, e) for side in range(2) for s, e in _runs_of(truth[:, side]) if s > 1 and e < len(truth) - 1]
    hits = [found[s:e, side].sum() >= 3 for side, s, e in inner]  # a stance found: 3 or more of its 6 frames
    assert len(inner) == 7 and sum(hits) >= 5, hits  # most stances, though the smoothing blurs each landing
    assert (found & ~truth).sum() <= 0.1 * found.sum()  # and the contacts found are stance frames
    # the fixed 0.35 m/s threshold on the noisy depth, without hysteresis, finds (almost) none of them
    old = foot_contacts(smooth, fps, dataclasses.replace(cfg, contact_release_ratio=1.0), ground)
    assert old.sum() < 0.2 * truth.sum()


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    padded = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.nonzero(padded == 1)[0], np.nonzero(padded == -1)[0], strict=True))


def test_contact_hysteresis_and_the_noise_scaled_threshold():
    from workflows.animation.clean import contact_threshold, foot_noise

    T, fps = 21, 30.0
    p = np.zeros((T, 24, 3))
    left, right = FOOT_JOINTS
    p[:, left, 0] = (0.2 / fps / 2) * (np.arange(T) - 10.0) ** 2  # on the floor, 0.2 m/s per frame from frame 10
    p[:, right, 1] = 0.3  # the other foot in the air
    cfg = CleanConfig(contact_min_frames=5)
    strict = foot_contacts(p, fps, dataclasses.replace(cfg, contact_release_ratio=1.0))
    assert not strict.any()  # only frames 9-11 are below 0.35 m/s: too short
    found = foot_contacts(p, fps, cfg)  # the run extends over frames 8-12 (0.4 m/s < 1.5 * 0.35)
    assert np.array_equal(np.nonzero(found[:, 0])[0], np.arange(8, 13)) and not found[:, 1].any()
    # a clip whose feet jitter 0.4 m/s in depth (z) gets a depth threshold 3 times that; image axes keep 0.35
    rng = np.random.default_rng(0)
    raw = p + rng.normal(size=p.shape) * [0.0, 0.0, 0.4 / fps * np.sqrt(2)]  # central differences: 0.4 m/s std
    noise = foot_noise(raw, p, fps)  # a median: 0.674 times the standard deviation of Gaussian noise
    assert noise[2] == pytest.approx(0.674 * 0.4, rel=0.35) and noise[0] == noise[1] == 0.0
    assert contact_threshold(cfg, noise)[:2] == pytest.approx([0.35, 0.35])
    assert contact_threshold(cfg, noise)[2] == pytest.approx(3 * noise[2])


def _panning_run(T: int = 90, fps: float = 30.0, speed_mps: float = 3.0, sway: float = 0.3):
    """Feet of a person running along +x (a stride of 20 frames; each foot's stance 5 frames, flights between)
    seen by a camera that pans with them at a varying speed, ``speed_mps * (1 + sway * sin(2 pi t / 45))``: the
    ground moves through the frame at minus that. Returns joints (T, 24, 3) y up, the true contacts (T, 2) and the
    ground's true velocity (T, 3) m/frame."""
    pan = speed_mps / fps * (1 + sway * np.sin(2 * np.pi * np.arange(T) / 45))  # m/frame
    camera = np.concatenate([[0.0], np.cumsum(0.5 * (pan[1:] + pan[:-1]))])  # the camera's x
    p, truth, _ = _running_feet(T, camera, speed_mps * 20 / fps, stance_frames=5)
    return p + [0.0, -0.9, -4.0], truth, np.stack([-pan, np.zeros(T), np.zeros(T)], 1)


def test_a_pan_of_varying_speed_gives_a_varying_ground_and_short_stances_are_found_and_locked_on_it():
    from workflows.animation.clean import ground_drift, ground_of, lock_plan

    fps = 30.0
    p, truth, pan = _panning_run()
    cfg = CleanConfig(ground_moves=True)
    ground = ground_of(p, fps, cfg)
    assert ground.shape == (len(p), 3)
    stance = truth.any(1)
    # the ground follows the pan where a foot stands (its speed changes by 1.8 m/s over the clip)
    assert np.abs(ground - pan)[stance].max() < 0.2 / fps
    found = foot_contacts(p, fps, cfg, ground)
    inner = [(side, s, e) for side in range(2) for s, e in _runs_of(truth[:, side]) if s > 1 and e < len(p) - 1]
    assert len(inner) >= 7 and all(found[s:e, side].sum() >= 3 for side, s, e in inner)  # 3 of 5 frames
    assert not (found & ~truth).any()  # no swing or flight frame
    # a constant ground (the clip's median pan) misses most stances: they move up to 0.9 m/s against it
    constant = ground_of(p, fps, dataclasses.replace(cfg, ground_smoothness=None))
    assert np.ptp(constant, axis=0).max() == 0.0
    assert foot_contacts(p, fps, cfg, constant).sum() < 0.5 * found.sum()
    # the locks hold each foot still relative to the moving ground, and skating is measured against it
    targets, weights, held = lock_plan(p, found, 3, ground, 0.02, hold=1, ease=True)
    drift = ground_drift(ground, len(p))
    for side, s, e in inner:
        rows = np.arange(s, e)[held[s:e, side]]
        relative = targets[rows, side] - drift[rows]
        assert len(rows) >= 3 and np.abs(relative - relative.mean(0)).max() < 1e-9
    # blending in and out moves the foot by its own offset from the lock, not by the ground's drift (10 cm/frame)
    assert np.linalg.norm(targets - p[:, list(FOOT_JOINTS)], axis=-1)[weights > 0].max() < 0.005
    assert foot_skating(p, found, ground) < 0.002 < 0.01 < foot_skating(p, found, constant)  # m/frame
    # a still camera (the same run, the pan taken out) keeps a still ground, and a steady pan a constant one
    still = p - ground_drift(pan, len(p))[:, None]
    assert np.abs(ground_of(still, fps, cfg)).max() < 1e-12
    steady = ground_of(_camera_walk()[0], fps, cfg)
    assert np.ptp(steady, axis=0).max() == 0.0 and np.linalg.norm(steady[0]) == pytest.approx(1.2 / fps, abs=0.1 / fps)
