"""Full body from a few trackers (smplik.tracking, workflows.tracking): the smplik-trackers format, the network,
streaming inference, samples, foot locks, ONNX, the command, and the shipped model on real held-out motion."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from smplik.conventions import Gender
from smplik.tracking.config import TRACKER_SETS, TrackerRuntimeConfig, TrackingNetConfig
from smplik.tracking.data import body_vector
from smplik.tracking.features import OUT_DIM, decode_pose, pose_targets, tracker_features
from smplik.tracking.io import (
    TrackerFileError,
    read_steamvr_jsonl,
    signals_from_dict,
    signals_from_motion,
)
from smplik.tracking.model_io import TrackingModelError, load_model
from smplik.tracking.network import TrackingNet, WindowMLP, input_dim
from smplik.tracking.recordings import read_trackers
from smplik.tracking.runtime import Tracker, _FootLock, contact_segments, offline_foot_lock, track_sequence

TRACKERS = TRACKER_SETS["4"]


@pytest.fixture(scope="module")
def model():
    return load_model()


def walking_motion(T: int = 120, fps: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """A simple synthetic motion: the rest pose walking forward (+z) at 1 m/s with swinging legs and arms."""
    from smplik.rotations import axis_angle_to_matrix

    t = np.arange(T) / fps
    aa = np.zeros((T, 24, 3))
    swing = 0.4 * np.sin(2 * np.pi * 1.0 * t)
    aa[:, 1, 0], aa[:, 2, 0] = swing, -swing  # hips
    aa[:, 4, 0], aa[:, 5, 0] = np.maximum(0, -swing), np.maximum(0, swing)  # knees bend on the back swing
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2  # arms down
    aa[:, 18, 1], aa[:, 19, 1] = -0.8, 0.8  # elbows bent
    transl = np.stack([np.zeros(T), np.zeros(T), 1.0 * t], -1)
    return axis_angle_to_matrix(torch.as_tensor(aa)).numpy(), transl


def rest_joints(betas=None, gender=Gender.NEUTRAL) -> np.ndarray:
    from smplik.body_model import BodyModelSet

    b = torch.zeros(10) if betas is None else torch.as_tensor(betas, dtype=torch.float32)
    return BodyModelSet.load().rest_joints(b, torch.tensor(gender.index)).double().numpy()


def synthetic_signals(T: int = 120) -> tuple:
    R, transl = walking_motion(T)
    J = rest_joints()
    transl[:, 1] += -min(0.0, 0.0)  # the rest pose stands on y = 0 in the built-in body
    return signals_from_motion(R, transl, J, TRACKERS, 60.0), R, transl, J


def doc(**overrides) -> dict:
    d = {"format": "smplik-trackers", "version": 1, "fps": 60,
         "trackers": {"head": {"position": [[0, 1.6, 0], [0, 1.6, 0.01]], "rotation": [[1, 0, 0, 0], [1, 0, 0, 0]]},
                      "left_wrist": {"position": [[0.3, 1.0, 0], [0.3, 1.0, 0.01]]}}}
    d.update(overrides)
    return d


# ----------------------------------------------------------------------------- format


def test_trackers_document_reads_back():
    sig = signals_from_dict(doc(), "t.json")
    assert sig.names == ("head", "left_wrist") and sig.positions.shape == (2, 2, 3)
    assert sig.has_rotation.tolist() == [True, False]
    again = signals_from_dict(json.loads(json.dumps(sig.to_dict())), "t.json")
    np.testing.assert_allclose(again.positions, sig.positions)
    np.testing.assert_allclose(again.rotations, sig.rotations)


@pytest.mark.parametrize(("change", "message"), [
    ({"format": "smplik-scene"}, 'format: is "smplik-scene"'),
    ({"version": 2}, "version: is 2"),
    ({"fps": 0}, "fps: must be a frame rate"),
    ({"fps": True}, "fps: must be a frame rate"),
    ({"extra": 1}, "extra: unknown key"),
    ({"trackers": {}}, "trackers: must be a non-empty object"),
    ({"trackers": {"nose": {"position": [[0, 0, 0]]}}}, "trackers.nose: unknown joint"),
    ({"trackers": {"head": {"rotation": [[1, 0, 0, 0]]}}}, "trackers.head.position: missing"),
    ({"trackers": {"head": {"position": [[0, 0]]}}}, "trackers.head.position: has shape (1, 2); expected (1, 3)"),
    ({"trackers": {"head": {"position": [[0, 0, float("nan")]]}}}, "trackers.head.position: contains NaN"),
    ({"trackers": {"head": {"position": [[0, 1, 0]], "rotation": [[0, 0, 0, 0]]}}},
     "trackers.head.rotation[0]: is a zero quaternion"),
    ({"trackers": {"head": {"position": [[0, 1, 0]]}, "pelvis": {"position": [[0, 1, 0], [0, 1, 0]]}}},
     "trackers.pelvis.position: has 2 rows; the first tracker has 1"),
    ({"trackers": {"head": {"position": [[0, 1, 0]], "scale": 1}}}, "trackers.head.scale: unknown key"),
])
def test_trackers_document_errors_name_the_problem(change, message):
    with pytest.raises(TrackerFileError) as err:
        signals_from_dict(doc(**change), "t.json")
    assert str(err.value).startswith("t.json: ") and message in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_tracker_for_the_model_is_named():
    sig = signals_from_dict(doc(), "t.json")
    with pytest.raises(TrackerFileError, match="trackers.right_wrist: missing; the model needs"):
        sig.select(TRACKERS)


def test_steamvr_log_reader(tmp_path):
    """JSON lines in the layout of a SteamVR logger polling OpenVR (poll_frame: {"timestamp", "devices": [{"index",
    "class", "pose": {"valid", "position": {x, y, z}, "quaternion": {x, y, z, w}}}]}), 90 Hz, standing universe."""
    lines = []
    for n in range(46):
        t = 100.0 + n / 90.0
        hmd = {"index": 0, "class": "HMD", "pose": {"valid": True, "position": {"x": 0.0, "y": 1.7, "z": -0.5 * t + 50},
                                                     "quaternion": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        # the user looks along OpenVR's -z; their left hand is at -x
        q0 = {"x": 0, "y": 0, "z": 0, "w": 1}
        left = {"index": 3, "class": "Controller",
                "pose": {"valid": True, "position": {"x": -0.3, "y": 1.0, "z": 0.0}, "quaternion": q0}}
        right = {"index": 4, "class": "Controller",
                 "pose": {"valid": n != 7, "position": {"x": 0.3, "y": 1.0, "z": 0.0}, "quaternion": q0},
                 "inputs": {"buttons": {}}}
        lines.append(json.dumps({"timestamp": t, "devices": [hmd, right, left]}))
    path = tmp_path / "captures.jsonl"
    path.write_text("\n".join(lines) + "\n")
    sig = read_trackers(path)
    assert sig.names == ("head", "left_wrist", "right_wrist") and sig.fps == 60.0
    assert sig.num_frames == 31  # 0.5 s at 60 Hz
    np.testing.assert_allclose(sig.positions[:, 1, 0], -0.3)  # the controller on the user's left
    # the head looks along -z (OpenVR's forward): SMPL's +z axis of the head points to -z in the world
    from smplik.rotations import quaternion_to_matrix_np

    np.testing.assert_allclose(quaternion_to_matrix_np(sig.rotations[0, 0])[:, 2], [0, 0, -1], atol=1e-6)
    assert sig.has_rotation.tolist() == [True, False, False]
    bad = tmp_path / "bad.jsonl"
    bad.write_text(lines[0] + "\n{not json\n")
    with pytest.raises(TrackerFileError, match="bad.jsonl: line 2: not a SteamVR log record"):
        read_steamvr_jsonl(bad)
    with pytest.raises(TrackerFileError, match="is a folder, not a tracker file"):
        read_steamvr_jsonl(tmp_path)
    with pytest.raises(TrackerFileError, match="Tracker file not found: .*missing.jsonl"):
        read_steamvr_jsonl(tmp_path / "missing.jsonl")
    (tmp_path / "latin1.jsonl").write_bytes(b"\xff\xfe{}")
    with pytest.raises(TrackerFileError, match="latin1.jsonl: tracker file is not UTF-8 text"):
        read_steamvr_jsonl(tmp_path / "latin1.jsonl")


# ----------------------------------------------------------------------------- network and features


def test_shapes_and_heading_invariance():
    cfg = TrackingNetConfig(hidden=32, decoder=32, latent=4)
    net = TrackingNet(cfg)
    sig, R, transl, J = synthetic_signals(30)
    from smplik.rotations import quaternion_to_matrix_np

    p = torch.as_tensor(sig.positions, dtype=torch.float32)
    Rq = torch.as_tensor(quaternion_to_matrix_np(sig.rotations), dtype=torch.float32)
    x, yaw, origin = tracker_features(p, Rq, torch.ones(4, dtype=torch.bool), 60.0)
    assert x.shape == (30, input_dim(cfg)) and yaw.shape == (30,) and origin.shape == (30, 3)
    # turning and moving the whole recording leaves the features unchanged
    from smplik.symmetry import rotation_about_y

    Y = rotation_about_y(torch.tensor(1.1))
    x2, _, _ = tracker_features(p @ Y.T + torch.tensor([3.0, 0.0, -2.0]), Y @ Rq, torch.ones(4, dtype=torch.bool), 60.0)
    torch.testing.assert_close(x2, x, atol=1e-4, rtol=0)
    body = body_vector(torch.zeros(2, 10), torch.tensor([0, 2]))
    out = net(x[None].expand(2, -1, -1), body)
    assert out.shape == (2, 30, OUT_DIM)
    target = pose_targets(torch.as_tensor(R, dtype=torch.float32), torch.zeros(30, 3), yaw, origin)
    out_t, kl = net.forward_train(x[None].expand(2, -1, -1), body, target[None].expand(2, -1, -1))
    assert out_t.shape == (2, 30, OUT_DIM) and kl.shape == (2, 30, 4) and (kl >= -1e-5).all()
    Rl, tr, prob = decode_pose(out, yaw, origin, torch.as_tensor(J, dtype=torch.float32))
    assert Rl.shape == (2, 30, 24, 3, 3) and tr.shape == (2, 30, 3) and ((prob >= 0) & (prob <= 1)).all()
    assert WindowMLP(TrackingNetConfig(kind="mlp", window=5))(x[None], body[:1]).shape == (1, 30, OUT_DIM)


def test_targets_decode_back_to_the_pose():
    sig, R, transl, J = synthetic_signals(10)
    from smplik.kinematics import forward_kinematics
    from smplik.rotations import quaternion_to_matrix_np
    from smplik.tracking.features import NUM_OUT_ROT

    Rt = torch.as_tensor(R, dtype=torch.float32)
    Jt = torch.as_tensor(J, dtype=torch.float32)
    _, p = forward_kinematics(Rt, Jt, torch.as_tensor(transl, dtype=torch.float32))
    x, yaw, origin = tracker_features(torch.as_tensor(sig.positions, dtype=torch.float32),
                                      torch.as_tensor(quaternion_to_matrix_np(sig.rotations), dtype=torch.float32),
                                      torch.ones(4, dtype=torch.bool), 60.0)
    target = pose_targets(Rt, p[:, 0], yaw, origin)
    out = torch.cat([target, torch.zeros(10, OUT_DIM - NUM_OUT_ROT - 3)], -1)
    R2, t2, _ = decode_pose(out, yaw, origin, Jt)
    torch.testing.assert_close(R2, Rt, atol=1e-5, rtol=0)
    torch.testing.assert_close(t2, torch.as_tensor(transl, dtype=torch.float32), atol=1e-5, rtol=0)


# ----------------------------------------------------------------------------- runtime


def test_one_pose_per_input_frame(model):
    sig, *_ = synthetic_signals(45)
    for samples in (1, 4):
        res = track_sequence(Tracker.load(config=TrackerRuntimeConfig(samples=samples)), sig)
        assert res.R_local.shape == (45, 24, 3, 3) and res.transl.shape == (45, 3) and res.contacts.shape == (45, 2)
        assert np.isfinite(res.R_local).all() and np.isfinite(res.transl).all()
    # a 30 Hz recording is resampled to the model's 60 Hz and mapped back: still one pose per input frame
    half = type(sig)(30.0, sig.names, sig.positions[::2], sig.rotations[::2], sig.has_rotation, "half")
    assert track_sequence(Tracker.load(), half).R_local.shape[0] == 23


@pytest.mark.parametrize("fast", [True, False])
def test_streaming_equals_batch(model, fast):
    """The per-frame path (GRU state carried frame to frame; numba kernels or the numpy reference) equals the torch
    network over the whole sequence at once."""
    if fast:
        pytest.importorskip("numba", reason="the kernels need numba (pip install 'smplik[fast]')")
    sig, *_ = synthetic_signals(40)
    tracker = Tracker.load(config=TrackerRuntimeConfig(foot_lock=False, tracker_fit=False, effector_fit=False,
                                                       fast=fast))
    res = track_sequence(tracker, sig)
    from smplik.rotations import quaternion_to_matrix_np

    x, yaw, origin = tracker_features(torch.as_tensor(sig.positions, dtype=torch.float32),
                                      torch.as_tensor(quaternion_to_matrix_np(sig.rotations), dtype=torch.float32),
                                      torch.ones(4, dtype=torch.bool), 60.0)
    body = body_vector(torch.zeros(10), torch.tensor(0))
    with torch.no_grad():
        out = model.net(x[None], body[None])[0]
    R, transl, _ = decode_pose(out, yaw, origin, torch.as_tensor(rest_joints(), dtype=torch.float32))
    np.testing.assert_allclose(res.R_local, R.numpy(), atol=2e-4)
    np.testing.assert_allclose(res.transl, transl.numpy(), atol=2e-4)


def test_tracker_fit_meets_wrists_and_pelvis(model):
    """With ``tracker_fit`` the pelvis lands on its tracker, the wrists on theirs wherever the arm can
    reach them, and the wrists and the head take the trackers' rotations."""
    from smplik.rotations import quaternion_to_matrix_np
    from smplik.tracking.fast import fk_np

    sig, *_ = synthetic_signals(30)
    tracker = Tracker.load(config=TrackerRuntimeConfig(foot_lock=False, tracker_fit=True, effector_fit=False))
    res = track_sequence(tracker, sig)
    G, p = fk_np(res.R_local.astype(np.float32), tracker.J_rest, res.transl.astype(np.float32))
    R_trk = quaternion_to_matrix_np(sig.rotations)
    np.testing.assert_allclose(p[:, 0], sig.positions[:, 3], atol=1e-4)
    np.testing.assert_allclose(G[:, 0], R_trk[:, 3], atol=1e-4)
    J = tracker.J_rest
    for k, (shoulder, elbow, wrist) in ((1, (16, 18, 20)), (2, (17, 19, 21))):
        arm = np.linalg.norm(J[elbow] - J[shoulder]) + np.linalg.norm(J[wrist] - J[elbow])
        reach = np.linalg.norm(sig.positions[:, k] - p[:, shoulder], axis=-1) < arm - 1e-3
        assert reach.sum() >= 5
        np.testing.assert_allclose(p[reach, wrist], sig.positions[reach, k], atol=1e-4)
        far = np.linalg.norm(p[:, wrist] - sig.positions[:, k], axis=-1)
        assert (far < 0.02).all()  # beyond reach: the straight arm points at the tracker
        np.testing.assert_allclose(G[:, wrist], R_trk[:, k], atol=1e-4)
    np.testing.assert_allclose(G[:, 15], R_trk[:, 0], atol=1e-4)


def test_samples_differ_and_deterministic_mode_is_deterministic(model):
    sig, *_ = synthetic_signals(40)
    a = track_sequence(Tracker.load(), sig)
    b = track_sequence(Tracker.load(), sig)
    np.testing.assert_array_equal(a.R_local, b.R_local)
    # the N samples of one frame differ (the latent is in use)
    tracker = Tracker.load(config=TrackerRuntimeConfig(samples=8))
    h = np.zeros(tracker.fast.H, np.float32)
    x = np.zeros(len(model.net.x_mean), np.float32)
    h = tracker.fast.condition_step(model.net.x_mean.numpy(), tracker.body, h)
    out = tracker.fast.sample(h, tracker.eps, tracker.body)
    from smplik.tracking.features import NUM_OUT_ROT

    spread = out[:, :NUM_OUT_ROT].std(0).max()
    assert spread > 1e-3, f"samples do not differ (max std {spread})"
    assert x.shape == model.net.x_mean.shape
    # the sampling mode is reproducible with a seed
    c = track_sequence(Tracker.load(config=TrackerRuntimeConfig(samples=8, seed=3)), sig)
    d = track_sequence(Tracker.load(config=TrackerRuntimeConfig(samples=8, seed=3)), sig)
    np.testing.assert_array_equal(c.R_local, d.R_local)


def test_contacts_lock_the_feet():
    """A body gliding forward 3 mm per frame (0.18 m/s) with the left foot in contact: the lock holds the foot still
    (within the lock's 8 cm drift limit)."""
    from smplik.tracking.fast import fk_np

    J = rest_joints().astype(np.float32)
    R = np.tile(np.eye(3, dtype=np.float32), (24, 1, 1))
    R[[1, 2]] = np.array([[1, 0, 0], [0, np.cos(0.2), -np.sin(0.2)], [0, np.sin(0.2), np.cos(0.2)]], np.float32)
    R[[4, 5]] = np.array([[1, 0, 0], [0, np.cos(-0.4), -np.sin(-0.4)], [0, np.sin(-0.4), np.cos(-0.4)]], np.float32)
    lock = _FootLock(threshold=0.5, release_frames=5)
    feet_raw, feet_locked = [], []
    for t in range(20):
        transl = np.array([[0.0, 0.0, 0.003 * t]], np.float32)
        Rw, p = fk_np(R[None], J, transl)
        R_out = lock.apply(R.astype(np.float64), Rw[0].astype(np.float64), p[0].astype(np.float64),
                           np.array([0.9, 0.1]))
        _, p2 = fk_np(R_out[None].astype(np.float32), J, transl)
        feet_raw.append(p[0, 10])
        feet_locked.append(p2[0, 10])
        np.testing.assert_allclose(p2[0, 11], p[0, 11], atol=1e-6)  # the free foot is untouched
    speed = lambda f: np.linalg.norm(np.diff(np.array(f), axis=0), axis=-1).mean()  # noqa: E731
    assert speed(feet_raw) > 2.5e-3
    assert speed(feet_locked) < 2e-4


def _angles(R: np.ndarray) -> np.ndarray:
    """Rotation angles (...) of matrices (..., 3, 3)."""
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))


SPINE = [3, 6, 9]  # spine1, spine2, spine3


def test_fresh_network_starts_near_the_rest_pose():
    """The decoder's 6D outputs start at the identity (:func:`smplik.tracking.network.init_identity_rotations`):
    an untrained network's local rotations are small, not arbitrary (random rotations average 2.1 rad). Without
    it a near-zero 6D column normalises to any direction, and the first model kept a spine joint twisted by pi."""
    torch.manual_seed(0)
    net = TrackingNet(TrackingNetConfig())
    x = torch.randn(2, 10, input_dim(net.cfg))
    body = body_vector(torch.zeros(2, 10), torch.tensor([0, 1]))
    with torch.no_grad():
        out = net(x, body)
    R, _, _ = decode_pose(out, torch.zeros(2, 10), torch.zeros(2, 10, 3), torch.zeros(24, 3))
    ang = _angles(R[..., 1:, :, :].numpy())
    assert ang.mean() < 0.5 and ang.max() < 1.5, (ang.mean(), ang.max())
    mlp = WindowMLP(TrackingNetConfig(kind="mlp"))
    with torch.no_grad():
        R, _, _ = decode_pose(mlp(x, body), torch.zeros(2, 10), torch.zeros(2, 10, 3), torch.zeros(24, 3))
    assert _angles(R[..., 1:, :, :].numpy()).mean() < 0.5


def test_shipped_model_keeps_the_spine_untwisted(model):
    """The spine-twist anomaly (the first shipped model turned spine1 by about -3 rad about its vertical axis and
    spine3 back by +3 rad on every frame; every frame was an anomaly): on a synthetic walk the spine joints stay
    within 0.8 rad of the rest pose, never jump more than 0.2 rad between frames, and few frames are anomalous."""
    from smplik.tracking.runtime import ANOMALY_THRESHOLD

    sig, *_ = synthetic_signals(120)
    res = track_sequence(Tracker.load(), sig)
    spine = res.R_local[:, SPINE]
    assert _angles(spine).max() < 0.8, _angles(spine).max(axis=0)
    step = _angles(np.swapaxes(spine[:-1], -1, -2) @ spine[1:])
    assert step.max() < 0.2, step.max()
    assert (res.anomaly > ANOMALY_THRESHOLD).mean() < 0.1


def test_kernels_equal_the_numpy_reference():
    """The numba kernels (smplik.tracking.kernels) against their numpy references: the two-bone IK against the
    animation pipeline's (bent, straight and out-of-reach chains), and a whole tracked sequence with samples,
    foot locks and the tracker fit."""
    kernels = pytest.importorskip("smplik.tracking.kernels", reason="the kernels need numba")
    from smplik.limb_ik import two_bone_ik

    rng = np.random.default_rng(0)
    a = rng.standard_normal((64, 3))
    b = a + 0.4 * rng.standard_normal((64, 3))
    c = b + 0.4 * rng.standard_normal((64, 3))
    b[:4], c[:4] = a[:4] + [0, -0.4, 0], a[:4] + [0, -0.8, 0]  # straight chains: the bend axis decides
    t = a + 0.5 * rng.standard_normal((64, 3))
    t[4:8] = a[4:8] + 3.0 * (c[4:8] - a[4:8])  # out of reach, along the chain
    t[8:12] = a[8:12] + 5.0 * rng.standard_normal((4, 3))  # out of reach
    bend = rng.standard_normal((64, 3))
    for got, want in zip(kernels.two_bone_ik(a, b, c, t, bend), two_bone_ik(a, b, c, t, bend), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    sig, *_ = synthetic_signals(60)
    for kw in ({}, {"samples": 6}, {"tracker_fit": True}):
        fast = track_sequence(Tracker.load(config=TrackerRuntimeConfig(fast=True, **kw)), sig)
        ref = track_sequence(Tracker.load(config=TrackerRuntimeConfig(fast=False, **kw)), sig)
        np.testing.assert_allclose(fast.R_local, ref.R_local, atol=1e-4)
        np.testing.assert_allclose(fast.transl, ref.transl, atol=1e-4)
        np.testing.assert_allclose(fast.anomaly, ref.anomaly, atol=1e-3)
        np.testing.assert_array_equal(fast.contacts, ref.contacts)
        np.testing.assert_array_equal(fast.sample, ref.sample)


def test_model_file_errors(tmp_path):
    with pytest.raises(TrackingModelError, match="not found"):
        load_model(tmp_path / "none.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(TrackingModelError, match="not a readable tracking model"):
        load_model(bad)
    torch.save({"info": {"format": "other"}}, tmp_path / "other.pt")
    with pytest.raises(TrackingModelError, match="format 'other'"):
        load_model(tmp_path / "other.pt")


def test_onnx_step_agrees_with_torch(model, tmp_path):
    ort = pytest.importorskip("onnxruntime", reason="onnxruntime missing: pip install -e '.[fast]'")
    from smplik.tracking.model_io import DEFAULT_CHECKPOINT
    from smplik.tracking.onnx_export import _Step, export_tracking_onnx

    shipped = DEFAULT_CHECKPOINT.with_suffix(".onnx")
    path = shipped if shipped.exists() else export_tracking_onnx(model.net, tmp_path / "t.onnx")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    x = (model.net.x_mean.numpy() + rng.normal(0, 1, model.net.x_mean.shape) * model.net.x_std.numpy())[None]
    feeds = {"x": x.astype(np.float32), "body": rng.normal(0, 1, (1, 13)).astype(np.float32),
             "h": rng.normal(0, 0.3, (1, model.cfg.hidden)).astype(np.float32),
             "eps": rng.normal(0, 1, (5, model.cfg.latent)).astype(np.float32)}
    h_next, out = sess.run(None, feeds)
    with torch.no_grad():
        th, to = _Step(model.net)(*(torch.from_numpy(feeds[k]) for k in ("x", "body", "h", "eps")))
    np.testing.assert_allclose(h_next, th.numpy(), atol=1e-4)
    np.testing.assert_allclose(out, to.numpy(), atol=1e-4)


# ----------------------------------------------------------------------------- command


def test_track_command_writes_an_animation(tmp_path):
    from typer.testing import CliRunner

    from smplik.cli.main import app
    from workflows.animation.files import load_animation

    sig, *_ = synthetic_signals(30)
    src = tmp_path / "trackers.json"
    src.write_text(json.dumps(sig.to_dict()))
    res = CliRunner().invoke(app, ["track", str(src), "--out", str(tmp_path / "out"), "--samples", "3",
                                   "--export", "bvh"])
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "out" / "animation.json")
    assert anim.tracks[0].num_frames == 30 and anim.fps == 60.0 and anim.space == "world"
    assert (tmp_path / "out" / "person_0.bvh").exists()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc(version=3)))
    res = CliRunner().invoke(app, ["track", str(bad), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 1
    assert res.output.strip().splitlines()[-1].startswith("error: ") and "version: is 3" in res.output
    assert not (tmp_path / "o2" / "animation.json").exists()


# ----------------------------------------------------------------------------- real held-out motion


def test_shipped_model_beats_a_trivial_baseline_on_held_out_cmu(shared_data, model):
    """CMU 02_01 (subject 02: test split): trackers from the motion; the model's MPJPE is far below the rest pose
    placed at the pelvis tracker, turned to the head's heading."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.dataset import find_sources, read_source, subsample_indices
    from smplik.kinematics import forward_kinematics
    from smplik.rotations import axis_angle_to_matrix
    from smplik.symmetry import rotation_about_y
    from smplik.tracking.features import heading_yaw

    path = shared_data.cmu("02_01.bvh")
    src = next(s for s in find_sources(path.parent, "bvh") if s.path.name == "02_01.bvh")
    seq = read_source(src, rig_mapper=auto_preset)
    idx = subsample_indices(seq.num_frames, seq.fps, 60.0)[:240]
    R = axis_angle_to_matrix(torch.as_tensor(seq.pose[idx], dtype=torch.float64)).numpy()
    transl = seq.transl[idx].astype(np.float64)
    J = rest_joints()
    sig = signals_from_motion(R, transl, J, TRACKERS, 60.0)
    res = track_sequence(Tracker.load(), sig)
    f64 = torch.float64
    _, p_true = forward_kinematics(torch.as_tensor(R), torch.as_tensor(J), torch.as_tensor(transl))
    _, p_ours = forward_kinematics(torch.as_tensor(res.R_local), torch.as_tensor(J), torch.as_tensor(res.transl))
    from smplik.rotations import quaternion_to_matrix_np

    yaw = heading_yaw(torch.as_tensor(quaternion_to_matrix_np(sig.rotations[:, 0]), dtype=f64))
    R_rest = torch.eye(3, dtype=f64).repeat(len(idx), 24, 1, 1)
    R_rest[:, 0] = rotation_about_y(yaw)
    t_rest = torch.as_tensor(sig.positions[:, 3]) - torch.as_tensor(J[0])
    _, p_rest = forward_kinematics(R_rest, torch.as_tensor(J), t_rest)
    ours = (p_ours - p_true).norm(dim=-1).mean().item()
    trivial = (p_rest - p_true).norm(dim=-1).mean().item()
    assert res.R_local.shape[0] == len(idx)
    assert ours < 0.6 * trivial, (ours, trivial)
    # no spine twist on real motion either (the first model's anomaly rate was 1.0)
    assert _angles(res.R_local[:, SPINE]).max() < 1.0
    from smplik.tracking.runtime import ANOMALY_THRESHOLD

    assert (res.anomaly > ANOMALY_THRESHOLD).mean() < 0.2


# ----------------------------------------------------------------------------- offline foot locks


def test_contact_segments_hysteresis_and_minimum_length():
    prob = np.array([0.1, 0.6, 0.45, 0.45, 0.2, 0.6, 0.1, 0.4, 0.55, 0.55, 0.55, 0.55])
    # starts above 0.5, ends at the first frame below 0.3; the 1-frame segment at 5 is too short
    assert contact_segments(prob, 0.5, 0.3, 2) == [(1, 4), (8, 12)]
    assert contact_segments(prob, 0.5, 0.3, 1) == [(1, 4), (5, 6), (8, 12)]
    assert contact_segments(prob, 0.35, 0.3, 2) == [(1, 4), (7, 12)]


def _gliding_legs(T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bent legs on a body gliding forward 3 mm per frame: R_local (T, 24, 3, 3), transl (T, 3), J (24, 3)."""
    J = rest_joints()
    R = np.tile(np.eye(3), (T, 24, 1, 1))
    bend = lambda a: np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])  # noqa: E731
    R[:, [1, 2]] = bend(0.2)
    R[:, [4, 5]] = bend(-0.4)
    transl = np.stack([np.zeros(T), np.zeros(T), 0.003 * np.arange(T)], -1)
    return R, transl, J


def test_offline_lock_holds_the_foot_over_a_predicted_contact_and_blends_smoothly():
    from smplik.tracking.fast import fk_np

    T = 110
    R, transl, J = _gliding_legs(T)
    prob = np.full((T, 2), 0.05)
    prob[40:70, 0] = 0.9  # the left foot in contact for 30 frames
    cfg = TrackerRuntimeConfig()
    R_out, locked = offline_foot_lock(R, transl, prob, J, cfg)
    assert locked[:, 0].tolist() == [40 <= t < 70 for t in range(T)] and not locked[:, 1].any()
    _, p_raw = fk_np(R, J, transl)
    _, p = fk_np(R_out, J, transl)
    foot = p[:, 10]
    step = np.linalg.norm(np.diff(foot, axis=0), axis=-1)
    assert np.linalg.norm(np.diff(p_raw[:, 10], axis=0), axis=-1).min() > 2.9e-3  # the network's foot skates
    assert step[40:69].max() < 1e-4  # still inside the segment
    # blended in and out: no jump, bounded acceleration (a hard release would jump by the ~4.5 cm drift)
    assert step.max() < 1e-2
    assert np.linalg.norm(np.diff(foot, 2, axis=0), axis=-1).max() < 2e-3
    far = 40 - cfg.lock_blend_frames - 6
    assert far > 10
    np.testing.assert_allclose(foot[:far], p_raw[:far, 10], atol=1e-6)  # far from the segment: the network's foot
    np.testing.assert_allclose(p[:, [2, 5, 8, 11]], p_raw[:, [2, 5, 8, 11]], atol=1e-9)  # the free leg untouched
    np.testing.assert_allclose(p[:, :1], p_raw[:, :1], atol=1e-9)


def test_offline_lock_lifts_the_heel_instead_of_overstretching():
    """A lock beyond the straight leg's reach: with ``lock_reach`` < 1 the foot pivots about its foot joint so the
    ankle stays within reach and the foot joint still meets the lock."""
    from dataclasses import replace

    from smplik.tracking.fast import fk_np

    T = 40
    R, transl, J = _gliding_legs(T)
    R[:, [1, 2, 4, 5]] = np.eye(3)  # straight legs: any drift from the lock is out of reach
    transl[:, 2] = 0.01 * np.arange(T)
    prob = np.full((T, 2), 0.05)
    prob[5:35, 0] = 0.9
    cfg = replace(TrackerRuntimeConfig(), lock_smooth_frames=0.0)
    _, p_raw = fk_np(R, J, transl)
    _, p_heel = fk_np(offline_foot_lock(R, transl, prob, J, cfg)[0], J, transl)
    _, p_flat = fk_np(offline_foot_lock(R, transl, prob, J, replace(cfg, lock_reach=1.0))[0], J, transl)
    lock = np.median(p_raw[5:35, 10], axis=0)
    err = lambda p: np.linalg.norm(p[5:35, 10] - lock, axis=-1).max()  # noqa: E731
    assert err(p_flat) > 0.01  # a straight leg cannot reach the lock at the segment's ends
    assert err(p_heel) < err(p_flat) / 2
    leg = np.linalg.norm(J[4] - J[1]) + np.linalg.norm(J[7] - J[4])
    assert (np.linalg.norm(p_heel[5:35, 7] - p_heel[5:35, 1], axis=-1) <= cfg.lock_reach * leg + 1e-6).all()


def standing_signals(T: int = 150) -> tuple:
    """Standing, the pelvis swaying a few centimetres, one forearm waving: trackers, rest joints."""
    from smplik.rotations import axis_angle_to_matrix

    t = np.arange(T) / 60.0
    aa = np.zeros((T, 24, 3))
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    aa[:, 18, 1], aa[:, 19, 1] = -0.8 - 0.5 * np.sin(2 * np.pi * 0.7 * t), 0.8
    transl = np.stack([0.04 * np.sin(2 * np.pi * 0.5 * t), np.zeros(T), 0.03 * np.sin(2 * np.pi * 0.3 * t)], -1)
    J = rest_joints()
    return signals_from_motion(axis_angle_to_matrix(torch.as_tensor(aa)).numpy(), transl, J, TRACKERS, 60.0), J


def test_track_command_locks_the_feet_offline(tmp_path, model):
    """``smplik track`` on a synthetic recording of a person standing and swaying: one pose per frame, and the
    feet still on their locked frames (the network alone moves them)."""
    from typer.testing import CliRunner

    from smplik.cli.main import app
    from smplik.kinematics import forward_kinematics
    from smplik.rotations import axis_angle_to_matrix
    from workflows.animation.files import load_animation

    sig, J = standing_signals(150)
    src = tmp_path / "trackers.json"
    src.write_text(json.dumps(sig.to_dict()))
    res = CliRunner().invoke(app, ["track", str(src), "--out", str(tmp_path / "out"), "--export", "bvh"])
    assert res.exit_code == 0, res.output
    track = load_animation(tmp_path / "out" / "animation.json").tracks[0]
    assert track.num_frames == 150
    aa = np.concatenate([track.global_orient[:, None], track.body_pose], axis=1)
    _, p = forward_kinematics(axis_angle_to_matrix(torch.as_tensor(aa)), torch.as_tensor(J),
                              torch.as_tensor(track.transl))
    p, contacts = p.numpy(), np.asarray(track.contacts, bool)
    free = track_sequence(Tracker.load(config=TrackerRuntimeConfig(foot_lock=False)), sig)
    _, p_free = forward_kinematics(torch.as_tensor(free.R_local), torch.as_tensor(J), torch.as_tensor(free.transl))
    p_free = p_free.numpy()
    held = 0
    for side, foot in enumerate((10, 11)):
        both = contacts[1:, side] & contacts[:-1, side]
        held += int(both.sum())
        if both.any():
            assert np.linalg.norm(np.diff(p[:, foot], axis=0), axis=-1)[both].max() < 1e-4
            assert np.linalg.norm(np.diff(p_free[:, foot], axis=0), axis=-1)[both].mean() > 5e-4
    assert held > 100  # standing: the feet are locked most of the time


@pytest.mark.parametrize(("change", "message"), [({"contact_off": 0.6}, "contact_off"),
                                                 ({"lock_centre": "mean"}, "lock_centre"),
                                                 ({"min_contact_frames": 0}, "min_contact_frames")])
def test_offline_lock_settings_are_checked(change, message):
    from dataclasses import replace

    with pytest.raises(ValueError, match=message):
        Tracker.load(config=replace(TrackerRuntimeConfig(), **change))


# ----------------------------------------------------------------------------- head and hands only


def test_shipped_model_follows_the_recordings_trackers():
    from smplik.tracking.model_io import DEFAULT_CHECKPOINT, THREE_TRACKER_CHECKPOINT, shipped_checkpoint

    assert shipped_checkpoint(TRACKER_SETS["4"]) == DEFAULT_CHECKPOINT
    assert shipped_checkpoint(("right_wrist", "head", "left_wrist", "left_ankle")) == THREE_TRACKER_CHECKPOINT
    assert shipped_checkpoint(("head", "left_wrist")) == DEFAULT_CHECKPOINT  # its error names right_wrist
    three = load_model(THREE_TRACKER_CHECKPOINT)
    assert three.cfg.trackers == TRACKER_SETS["3"] and three.cfg.kind == "cvae"


def test_track_command_with_head_and_hands_only(tmp_path):
    """A recording without a waist tracker runs through the shipped 3-tracker model: one pose per frame, the
    walk's forward progress followed, and the pelvis tracker really absent from what the model read."""
    from typer.testing import CliRunner

    from smplik.cli.main import app
    from workflows.animation.files import load_animation

    R, transl = walking_motion(90)
    sig = signals_from_motion(R, transl, rest_joints(), TRACKER_SETS["3"], 60.0)
    assert "pelvis" not in sig.names
    src = tmp_path / "quest.json"
    src.write_text(json.dumps(sig.to_dict()))
    res = CliRunner().invoke(app, ["track", str(src), "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    track = load_animation(tmp_path / "out" / "animation.json").tracks[0]
    assert track.num_frames == 90
    moved = track.transl[-1] - track.transl[0]
    assert 1.0 < moved[2] < 2.0 and abs(moved[0]) < 0.3  # 1.5 s at 1 m/s along +z
    # with the 4-tracker model forced, the same file is one line naming the missing tracker
    from smplik.tracking.model_io import DEFAULT_CHECKPOINT

    res = CliRunner().invoke(app, ["track", str(src), "--out", str(tmp_path / "o2"), "--checkpoint",
                                   str(DEFAULT_CHECKPOINT)])
    assert res.exit_code == 1 and "trackers.pelvis: missing" in res.output.strip().splitlines()[-1]
