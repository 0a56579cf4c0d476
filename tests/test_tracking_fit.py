"""The end-effector fit (smplik.tracking.fit): head and wrists on exact trackers, no tracker noise passed through,
the same in streaming and offline, on by default."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from smplik.conventions import JOINT_INDEX, Gender
from smplik.tracking.config import FitConfig, TrackerRuntimeConfig
from smplik.tracking.fast import fk_np
from smplik.tracking.fit import EffectorFit, _Band, steady_gain
from smplik.tracking.io import signals_from_motion
from smplik.tracking.runtime import Tracker, track_sequence

TRACKERS = ("head", "left_wrist", "right_wrist", "pelvis")
HEAD_AND_WRISTS = ("head", "left_wrist", "right_wrist")


def rest_joints(betas=None, gender=Gender.NEUTRAL) -> np.ndarray:
    from smplik.body_model import BodyModelSet

    b = torch.zeros(10) if betas is None else torch.as_tensor(betas, dtype=torch.float32)
    return BodyModelSet.load().rest_joints(b, torch.tensor(gender.index)).double().numpy()


@pytest.fixture(scope="module")
def cmu_motion(shared_data):
    """CMU 02_05 (punch/strike, subject 02: test split) at 60 Hz, 300 frames: R_local, transl, J_rest."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.dataset import find_sources, read_source, subsample_indices
    from smplik.rotations import axis_angle_to_matrix

    path = shared_data.cmu("02_05.bvh")
    src = next(s for s in find_sources(path.parent, "bvh") if s.path.name == "02_05.bvh")
    seq = read_source(src, rig_mapper=auto_preset)
    idx = subsample_indices(seq.num_frames, seq.fps, 60.0)[60:360]
    R = axis_angle_to_matrix(torch.as_tensor(seq.pose[idx], dtype=torch.float64)).numpy()
    return R, seq.transl[idx].astype(np.float64), rest_joints()


def joints(res, J: np.ndarray) -> np.ndarray:
    return fk_np(res.R_local, J, res.transl)[1]


def misses(p: np.ndarray, sig) -> dict[str, np.ndarray]:
    """Per-frame distance (m) of the head and wrist joints to their trackers."""
    return {n: np.linalg.norm(p[:, JOINT_INDEX[n]] - sig.positions[:, sig.names.index(n)], axis=-1)
            for n in HEAD_AND_WRISTS}


def accel_error(p: np.ndarray, truth: np.ndarray) -> float:
    """Mean joint acceleration error (m/s^2 at 60 Hz) over all joints and frames."""
    return float(np.linalg.norm(np.diff(p, 2, axis=0) - np.diff(truth, 2, axis=0), axis=-1).mean() * 3600)


def test_fit_is_on_by_default():
    assert TrackerRuntimeConfig().effector_fit
    assert Tracker.load().effector_fit is not None
    assert Tracker.load(config=TrackerRuntimeConfig(effector_fit=False)).effector_fit is None


@pytest.mark.slow
@pytest.mark.parametrize("model", [None, "smplik/checkpoints/smplik_tracking_3.pt"], ids=["4 trackers", "3 trackers"])
def test_exact_trackers_put_head_and_wrists_within_a_centimetre(cmu_motion, model):
    """Exact trackers of held-out motion: without the fit the network misses its trackers by centimetres; with it
    (the default) the head and the wrists are on them, within 1 cm on every frame after the first second (a new
    stream starts by assuming jittery trackers, :attr:`FitConfig.prior_jitter_m`, until its own show otherwise)."""
    R, transl, J = cmu_motion
    tracker = Tracker.load(model)
    sig = signals_from_motion(R, transl, J, tracker.trackers, 60.0)
    fitted = misses(joints(track_sequence(tracker, sig), J), sig)
    raw = misses(joints(track_sequence(Tracker.load(model, config=TrackerRuntimeConfig(effector_fit=False)), sig), J),
                 sig)
    for name in HEAD_AND_WRISTS:
        assert raw[name].mean() > 0.015, (name, raw[name].mean())
        assert fitted[name][60:].max() < 0.01, (name, fitted[name][60:].max())
        assert fitted[name].mean() < 0.25 * raw[name].mean(), name


def test_noisy_trackers_are_not_passed_through(cmu_motion):
    """Trackers with 1 cm / 2 degree white noise: the fit's acceleration error stays within 2 % of the network's
    alone (the fit follows the trackers slowly under noise), while the naive fit that meets every tracker exactly
    (``tracker_fit``) passes the noise through (several times the acceleration error); the joints stay at least
    as close to the truth as without the fit."""
    R, transl, J = cmu_motion
    truth = fk_np(R, J, transl)[1]
    sig = signals_from_motion(R, transl, J, TRACKERS, 60.0, noise_m=0.01, noise_deg=2.0,
                              rng=np.random.default_rng(1))
    runs = {name: joints(track_sequence(Tracker.load(config=TrackerRuntimeConfig(**kw)), sig), J)
            for name, kw in (("fit", {}), ("none", {"effector_fit": False}),
                             ("naive", {"effector_fit": False, "tracker_fit": True}))}
    acc = {name: accel_error(p, truth) for name, p in runs.items()}
    assert acc["fit"] <= 1.02 * acc["none"], acc
    assert acc["naive"] > 2.0 * acc["none"], acc
    mpjpe = {name: float(np.linalg.norm(p - truth, axis=-1).mean()) for name, p in runs.items()}
    assert mpjpe["fit"] <= mpjpe["none"], mpjpe


def test_streaming_equals_offline():
    """Tracker.step frame by frame gives the fitted poses track_sequence gives (the fit is causal and part of the
    per-frame path), including with noisy trackers."""
    from smplik.rotations import axis_angle_to_matrix

    T = 90
    t = np.arange(T) / 60.0
    aa = np.zeros((T, 24, 3))
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    aa[:, 18, 1] = -0.8 + 0.6 * np.sin(2 * np.pi * t)
    aa[:, 19, 1] = 0.8
    aa[:, 3, 0] = 0.2 * np.sin(np.pi * t)
    transl = np.stack([np.zeros(T), np.zeros(T), 0.5 * t], -1)
    J = rest_joints()
    sig = signals_from_motion(axis_angle_to_matrix(torch.as_tensor(aa)).numpy(), transl, J, TRACKERS, 60.0,
                              noise_m=0.005, noise_deg=1.0)
    cfg = TrackerRuntimeConfig(foot_lock=False)
    offline = track_sequence(Tracker.load(config=cfg), sig)
    tracker = Tracker.load(config=cfg)
    tracker.reset(sig.has_rotation)
    stream = [tracker.step(sig.positions[i], sig.rotations[i]) for i in range(T)]
    np.testing.assert_allclose(np.stack([p.R_local for p in stream]), offline.R_local, atol=1e-9)
    np.testing.assert_allclose(np.stack([p.transl for p in stream]), offline.transl, atol=1e-9)
    # and the fit changed the pose: the raw network is elsewhere
    raw = track_sequence(Tracker.load(config=TrackerRuntimeConfig(foot_lock=False, effector_fit=False)), sig)
    assert np.abs(raw.R_local - offline.R_local).max() > 1e-2


def test_jitter_estimate_and_gain():
    """The band's jitter estimate recovers the sigma of white noise on a moving signal (less its floor), and the
    gain is 1 without jitter and falls with it."""
    rng = np.random.default_rng(0)
    band = _Band(60, floor=0.0)  # no prior, no floor: the estimate alone
    for i in range(200):
        s = band.sigma(np.array([0.01 * i, 1.0, 0.0]) + rng.normal(0.0, 0.01, 3))
    assert s == pytest.approx(0.01, rel=0.2)
    assert steady_gain(0.0, 0.0015) == 1.0
    assert 0.05 < steady_gain(0.008, 0.0015) < 0.3
    assert steady_gain(0.02, 0.0015) < steady_gain(0.008, 0.0015)


def test_fit_leaves_legs_and_root_alone():
    """The fit turns only the spine, head and arms (and may shift the whole body): legs and root rotations are
    the network's."""
    J = rest_joints()
    fit = EffectorFit(TRACKERS, np.ones(4, bool), J, FitConfig())
    rng = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(0, 0.2, (24, 3))).as_matrix()
    p = fk_np(R[None], J, np.zeros((1, 3)))[1][0]
    idx = [JOINT_INDEX[n] for n in TRACKERS]
    out, transl, G, q = fit.apply(R, np.zeros(3), p[idx] + rng.normal(0, 0.03, (4, 3)),
                          Rotation.from_rotvec(rng.normal(0, 0.2, (4, 3))).as_matrix())
    legs = [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("hip", "knee", "ankle", "foot")] + [0]
    np.testing.assert_allclose(out[legs], R[legs], atol=1e-12)
    np.testing.assert_allclose(q, fk_np(out[None], J, transl[None])[1][0], atol=1e-9)
    assert np.abs(out - R).max() > 1e-3
