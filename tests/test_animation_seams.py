"""Issue 44's smaller animation seams: the GIF preview plays in the clip's own time, options are refused before
anything heavy loads, and the cleaning's properties on small synthetic clips (never worse than its input, planted
feet held)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from workflows.animation.preview import GIF_TICK_MS, gif_durations, save_gif


@pytest.mark.parametrize("fps", [15.0, 30.0 / 2, 24.0, 25.0, 12.5, 29.97 / 2, 7.0])
@pytest.mark.parametrize("n", [1, 7, 269])
def test_gif_delays_add_up_to_the_clips_duration(fps, n):
    delays = gif_durations(n, fps)
    assert len(delays) == n
    assert all(d % GIF_TICK_MS == 0 and d >= GIF_TICK_MS for d in delays)
    assert abs(sum(delays) - n * 1000.0 / fps) <= GIF_TICK_MS / 2 + 1e-9  # the clip plays in its own time
    assert max(delays) - min(delays) <= GIF_TICK_MS  # evenly spread, no stall


def test_a_written_gif_of_66ms_frames_is_not_played_11_percent_fast(tmp_path):
    # the issue: every frame stored as 60 ms for 66.7 ms frames (a 15 frames/s preview of a 30 frames/s clip)
    n, fps = 30, 15.0
    rng = np.random.default_rng(0)
    images = [Image.fromarray(rng.integers(0, 255, (8, 8, 3), dtype=np.uint8)).quantize(colors=16)
              for _ in range(n)]
    path = tmp_path / "p.gif"
    save_gif(images, path, fps)
    with Image.open(path) as gif:
        stored = []
        for k in range(gif.n_frames):
            gif.seek(k)
            stored.append(gif.info["duration"])
    assert len(stored) == n
    assert abs(sum(stored) - 2000.0) <= 5.0  # 30 frames at 15 frames/s: two seconds
    assert set(stored) == {60, 70}


@pytest.mark.parametrize("args, said", [
    (["--frames", "abc"], "--frames must be 'all' or 'A:B'"),
    (["--frames", "5:2"], "--frames 5:2: need 0 <= A < B"),
    (["--export", "fbx"], "unknown export format"),
    (["--smoothing", "wiener"], "smoothing must be"),
    (["--fps", "0"], "--fps"),
    (["--preview", "x.png"], "x.png"),
    (["--format", "fbx"], "--format must be one of"),
    (["--space", "screen"], "--space must be 'camera' or 'world'"),
])
def test_animate_refuses_bad_options_before_loading_the_model(tmp_path, monkeypatch, args, said):
    from typer.testing import CliRunner

    import workflows.cli_shared
    from workflows.cli import scene_app

    loaded = []
    monkeypatch.setattr(workflows.cli_shared, "_solver", lambda checkpoint: loaded.append(checkpoint))
    source = tmp_path / "missing.npz"  # not even read: the options are refused first
    res = CliRunner().invoke(scene_app, ["animate", str(source), "--out", str(tmp_path / "o"), *args])
    assert res.exit_code == 1, res.output
    assert said in res.output
    assert len(res.output.strip().splitlines()) == 1 and "Traceback" not in res.output
    assert loaded == []  # the model never loaded
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- cleaning never worse, feet planted


def _estimate(aa: np.ndarray, transl: np.ndarray, seed: int, rho: float = 0.0):
    """A synthetic video estimate as ``benchmarks/animation_truth.py`` makes it: 4 degrees rms on every local
    rotation, root sigma 1.5 / 1.5 / 7 cm (x / y / depth), independent or AR(1) over frames (rho)."""
    from scipy.spatial.transform import Rotation

    from smplik.pose import Pose

    rng = np.random.default_rng(seed)
    T = aa.shape[0]
    rot = rng.normal(0, np.deg2rad(4.0) / np.sqrt(3), (T, 24, 3))
    root = rng.normal(0, 1.0, (T, 3)) * [0.015, 0.015, 0.07]
    for t in range(1, T) if rho else ():
        rot[t] = rho * rot[t - 1] + np.sqrt(1 - rho ** 2) * rot[t]
        root[t] = rho * root[t - 1] + np.sqrt(1 - rho ** 2) * root[t]
    noisy = (Rotation.from_rotvec(aa.reshape(-1, 3)) * Rotation.from_rotvec(rot.reshape(-1, 3))).as_rotvec()
    noisy = noisy.reshape(T, 24, 3)
    return [Pose(noisy[t, 0], noisy[t, 1:], transl[t] + root[t], np.zeros(10)) for t in range(T)]


def _truth(aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    from smplik.conventions import Gender
    from workflows.animation.clips import joints_of, rest_joints

    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(aa.shape[0], 24, 3, 3)
    return joints_of(R, transl, rest_joints(np.zeros(10), Gender.NEUTRAL))


def _errors(p: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PA-MPJPE (m, per frame similarity-aligned) and acceleration error (m/frame^2), as the benchmark."""
    import torch

    from smplik.metrics import pa_mpjpe

    acc = (p[2:] - 2 * p[1:-1] + p[:-2]) - (truth[2:] - 2 * truth[1:-1] + truth[:-2])
    return (float(pa_mpjpe(torch.as_tensor(p), torch.as_tensor(truth)).mean()),
            float(np.linalg.norm(acc, axis=-1).mean()))


def _fast_swing(T: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """A fast synthetic motion at 30 frames/s: legs and arms swinging at 2 Hz by +-0.9 rad (a sprint's cadence),
    the body travelling 5 m/s and bouncing 8 cm: axis-angle (T, 24, 3), transl (T, 3)."""
    phase = 2 * np.pi * 2.0 * np.arange(T) / 30.0
    aa = np.zeros((T, 24, 3))
    aa[:, 1, 0], aa[:, 2, 0] = 0.9 * np.sin(phase), -0.9 * np.sin(phase)  # hips
    aa[:, 4, 0], aa[:, 5, 0] = 0.8 * (1 + np.sin(phase)), 0.8 * (1 - np.sin(phase))  # knees
    aa[:, 16, 0], aa[:, 17, 0] = -0.9 * np.sin(phase), 0.9 * np.sin(phase)  # shoulders
    aa[:, 18, 1], aa[:, 19, 1] = -1.2 + 0.4 * np.sin(phase), 1.2 - 0.4 * np.sin(phase)  # elbows
    transl = np.stack([np.zeros(T), 0.9 + 0.04 * np.sin(2 * phase), 5.0 * np.arange(T) / 30.0], -1)
    return aa, transl


def _standing(T: int = 150) -> tuple[np.ndarray, np.ndarray]:
    """Standing with both feet planted (legs and pelvis still), the arms punching and waving: truth feet still."""
    phase = 2 * np.pi * np.arange(T) / 30.0
    aa = np.zeros((T, 24, 3))
    aa[:, 16, 2], aa[:, 17, 2] = -1.0 + 0.5 * np.sin(phase), 1.0 + 0.5 * np.sin(1.3 * phase)
    aa[:, 18, 1], aa[:, 19, 1] = -0.8 + 0.6 * np.sin(2 * phase), 0.8 - 0.6 * np.sin(2 * phase)
    aa[:, 3, 1] = 0.2 * np.sin(0.5 * phase)  # the spine turns; the legs stay
    return aa, np.tile([0.0, 0.93, 0.0], (T, 1))


@pytest.mark.parametrize("rho", [0.0, 0.8])
def test_cleaning_a_fast_clip_is_never_worse_than_its_raw_input(rho):
    from workflows.animation.clean import CleanConfig
    from workflows.animation.clips import clean_track

    aa, transl = _fast_swing()
    truth = _truth(aa, transl)
    for seed in range(3):
        poses = _estimate(aa, transl, seed, rho)
        raw = _errors(clean_track(poses, 30.0, CleanConfig(smoothing="none", foot_lock=False,
                                                             repair_glitches=False), 1.0)[4], truth)
        ours = _errors(clean_track(poses, 30.0, CleanConfig(), 1.0)[4], truth)
        assert ours[0] <= raw[0] and ours[1] <= raw[1], (seed, ours, raw)  # PA-MPJPE, acceleration error


@pytest.mark.parametrize("rho", [0.0, pytest.param(0.8, marks=pytest.mark.xfail(
    strict=True, reason="issue 44, not met yet: under AR(1) noise the planted feet skate about 1.1 mm/frame on one "
    "seed (the lock's gaps where the drifting foot leaves the speed threshold); see docs/animation.md"))])
def test_planted_feet_of_a_noisy_estimate_stay_within_the_skating_bound(rho):
    from workflows.animation.clean import CleanConfig, foot_contacts, foot_skating
    from workflows.animation.clips import clean_track

    aa, transl = _standing()
    truth = _truth(aa, transl)
    contacts = foot_contacts(truth, 30.0, CleanConfig())
    assert contacts.all()  # the truth's feet are planted throughout
    for seed in range(2):
        poses = _estimate(aa, transl, seed, rho)
        out = clean_track(poses, 30.0, CleanConfig(), 1.0)
        raw_skating = foot_skating(out[3], contacts)
        skating = foot_skating(out[4], contacts)
        assert raw_skating > 0.02  # the estimate's feet move several cm per frame
        assert skating <= foot_skating(truth, contacts) + 0.001, (seed, skating)  # the bound: truth + 1 mm


def test_stance_noise_is_zero_on_still_feet_and_grows_with_the_noise():
    from smplik.contacts import stance_noise

    aa, transl = _standing(90)
    truth = _truth(aa, transl)
    assert np.allclose(stance_noise(truth, 30.0, 0.08), 0.0)
    rng = np.random.default_rng(0)
    small = truth + rng.normal(0, 0.002, truth.shape)
    large = truth + rng.normal(0, 0.01, truth.shape)
    assert (stance_noise(large, 30.0, 0.08) > 3 * stance_noise(small, 30.0, 0.08)).all()
    flying = truth + [0.0, 1.0, 0.0]  # no foot near the floor it fits: still defined, from the feet alone
    assert np.isfinite(stance_noise(flying, 30.0, 0.08)).all()


def test_a_sliding_run_is_no_contact_a_noisy_planted_one_is():
    from workflows.animation.clean import drop_sliding_runs

    T = 20
    rng = np.random.default_rng(1)
    feet = np.zeros((T, 2, 3))
    feet[:, 0] = rng.normal(0, 0.01, (T, 3))  # planted, 1 cm noise: fast frame to frame, still on average
    feet[:, 1, 2] = 0.04 * np.arange(T)  # sliding 4 cm per frame (1.2 m/s)
    kept = drop_sliding_runs(feet, np.ones((T, 2), dtype=bool), 0.7 / 30.0)
    assert kept[:, 0].all() and not kept[:, 1].any()


@pytest.mark.parametrize("T, window, order", [(7, 7, 3), (50, 7, 3), (40, 9, 2), (9, 9, 2), (100, 5, 1)])
def test_savgol_smooth_equals_scipys_filter(T, window, order):
    # the animation's smoothing no longer imports scipy.signal (seconds of CPU per run): same numbers
    from scipy.signal import savgol_coeffs, savgol_filter

    from smplik.smoothing import savgol_coefficients, savgol_smooth

    y = np.random.default_rng(T).normal(size=(T, 4, 3))
    np.testing.assert_allclose(savgol_smooth(y, window, order),
                               savgol_filter(y, window, order, axis=0, mode="interp"), atol=1e-12)
    np.testing.assert_allclose(savgol_coefficients(window, order), savgol_coeffs(window, order), atol=1e-12)
    with pytest.raises(ValueError):
        savgol_smooth(y[:3], window, order)


# ----------------------------------------------------------------------------- the 3D preview's camera


def _walking_animation(T: int = 60, metres: float = 5.0):
    """One SMPL body walking ``metres`` sideways to the camera (along x, facing +z) over T frames at 30 frames/s."""
    from smplik.conventions import Gender
    from workflows.animation.clips import Animation, AnimationTrack

    phase = 2 * np.pi * np.arange(T) / 30.0
    body = np.zeros((T, 23, 3))
    body[:, 0, 0], body[:, 1, 0] = 0.4 * np.sin(phase), -0.4 * np.sin(phase)  # hips swing
    transl = np.stack([np.linspace(0.0, metres, T), 0.02 * np.sin(2 * phase), np.zeros(T)], -1)
    track = AnimationTrack("person_0", "0", Gender.NEUTRAL, np.zeros(10), 1.0, None, 0, np.zeros((T, 3)), body,
                           transl)
    return Animation((track,), 30.0, space="world")


def test_the_3d_preview_follows_a_walker_smoothly_and_frames_the_body():
    from workflows.animation.preview import PreviewConfig, _track_joints, shown_frames, world_view

    anim = _walking_animation()
    frames, _ = shown_frames(anim, 1, 1000, 15.0)
    config = PreviewConfig()
    world = world_view(anim, frames, config)
    pelvis = _track_joints(anim.tracks[0])[:, 0]
    centers = np.array([world.views[f].center for f in frames])
    # follows the root: the camera looks at the walker's horizontal position on every shown frame ...
    assert np.abs(centers[:, [0, 2]] - pelvis[frames][:, [0, 2]]).max() < 0.15
    assert np.ptp(centers[:, 1]) < 1e-9  # ... at one height (no bounce)
    step = np.diff(centers[:, 0])
    assert step.min() > 0 and np.abs(np.diff(step)).max() < 0.02  # smoothly: no jerk from one frame to the next
    # frames the body: one distance, at which the 1.7 m body fills most of the picture's height
    distance = {world.views[f].distance for f in frames}
    assert len(distance) == 1
    visible = 2 * distance.pop() * np.tan(world.views[frames[0]].yfov / 2)  # metres of height seen at the body
    assert 1.7 / visible > 0.5  # a fixed camera framing the whole 5 m walk showed it at about a quarter


def test_the_3d_preview_keeps_the_walker_in_the_middle_of_the_picture(tmp_path):
    import os

    from workflows.animation.preview import PreviewConfig, iter_preview_frames, shown_frames

    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    anim = _walking_animation(30, 3.0)
    frames, _ = shown_frames(anim, 1, 1000, 15.0)
    try:
        images = dict(iter_preview_frames(anim, frames, config=PreviewConfig(size=(160, 120))))
    except Exception as exc:  # smplik.render.RenderError: no GL backend on this machine
        if "OpenGL" in str(exc) or "pyrender" in str(exc) or "EGL" in str(exc):
            pytest.skip(f"no OpenGL backend for pyrender: {exc}")
        raise
    for f in (frames[0], frames[-1]):
        img = images[f].astype(int)
        body = img[..., 2] - img[..., 0] > 15  # the body's blue (the floor is grey, the sky white)
        ys, xs = np.nonzero(body)
        assert xs.size > 0.03 * body.size  # the body is drawn large ...
        assert abs(xs.mean() - 80) < 25  # ... and in the middle, at the start and at the end of the walk


@pytest.mark.parametrize("args, said", [
    (["--frame", "3", "--export", "fbx"], "unknown export format"),
    (["--frame", "999"], "frame 999 is outside track person_0's frames 0..9"),
    (["--frame", "3", "--track", "nobody"], "no track 'nobody'"),
])
def test_edit_keyframe_refuses_bad_options_before_loading_the_model_or_writing(tmp_path, monkeypatch, args, said):
    import json

    from typer.testing import CliRunner

    import workflows.cli_shared
    from workflows.animation.files import save_animation
    from workflows.cli import scene_app

    path = save_animation(_walking_animation(10, 0.5), tmp_path / "animation.json")
    before = path.read_bytes()
    effectors = tmp_path / "wave.json"
    effectors.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "right_wrist", "type": "position", "value": [0.3, 1.5, 0.1]}]}))
    loaded = []
    monkeypatch.setattr(workflows.cli_shared, "_solver", lambda checkpoint: loaded.append(checkpoint))
    res = CliRunner().invoke(scene_app, ["edit-keyframe", str(path), "--effectors", str(effectors), *args])
    assert res.exit_code == 1, res.output
    assert said in res.output and len(res.output.strip().splitlines()) == 1
    assert loaded == []  # the model never loaded
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["animation.json",
                                                                                          "wave.json"]
