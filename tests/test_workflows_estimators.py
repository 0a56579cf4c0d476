"""Estimator readers: one fixture per layout, the camera-to-world rule, and refused pickles."""

from __future__ import annotations

import json
import os
import pickle

import joblib
import numpy as np
import pytest
import torch

from smplik.conventions import Gender
from smplik.rotations import axis_angle_to_matrix
from workflows.estimators import EstimateFormatError, detect_format, read_estimate
from workflows.estimators.base import M_WORLD_CAMERA, rest_pelvis
from workflows.safe_pickle import UnsafePickleError, load_pickle


@pytest.fixture(scope="module")
def people_cam():
    """Two people in the camera frame: axis-angle (2, 24, 3), smplx transl (2, 3), betas (2, 10)."""
    rng = np.random.default_rng(1)
    aa = rng.normal(0, 0.3, (2, 24, 3))
    transl = np.array([[-0.5, 0.2, 4.0], [0.7, 0.1, 5.0]])
    betas = rng.normal(0, 1, (2, 10))
    return aa, transl, betas


def _joints(aa, transl, betas):
    from smplik.body_model import load_body_model

    m = load_body_model("neutral")
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float32)  # noqa: E731
    return m.joints(t(aa[..., 0, :]), t(aa[..., 1:, :]), t(transl), t(betas)).double().numpy()


def _check(people, aa, transl, betas, tol=1e-4):
    """World joints must be the camera joints rotated by M (and the body pose unchanged)."""
    assert len(people) == aa.shape[0]
    cam_joints = _joints(aa, transl, betas)
    for i, p in enumerate(people):
        world = _joints(np.concatenate([p.global_orient[None], p.body_pose])[None], p.transl[None], p.betas[None])[0]
        np.testing.assert_allclose(world, cam_joints[i] @ M_WORLD_CAMERA.T, atol=tol)
        np.testing.assert_allclose(p.body_pose, aa[i, 1:], atol=1e-5)
        np.testing.assert_allclose(p.betas, betas[i], atol=1e-6)


def _R(aa):
    return axis_angle_to_matrix(torch.as_tensor(aa)).numpy()


def test_camera_to_world_rule_keeps_the_pelvis():
    betas = np.zeros((1, 10))
    J0 = rest_pelvis(betas, Gender.NEUTRAL)[0]
    t = np.array([0.3, -0.2, 3.0])
    from workflows.estimators.base import camera_to_world

    go, transl = camera_to_world(np.array([[0.1, 0.2, 0.3]]), (J0 + t)[None], J0[None])
    np.testing.assert_allclose(transl[0] + J0, M_WORLD_CAMERA @ (J0 + t), atol=1e-9)
    R = axis_angle_to_matrix(torch.as_tensor(go[0])).numpy()
    np.testing.assert_allclose(R, M_WORLD_CAMERA @ _R(np.array([0.1, 0.2, 0.3])), atol=1e-9)


@pytest.mark.parametrize("bev", [False, True])
def test_romp_bev_npz(tmp_path, people_cam, bev):
    aa, transl, betas = people_cam
    b = np.concatenate([betas, np.full((2, 1), 0.3)], 1) if bev else betas
    path = tmp_path / "romp.npz"
    np.savez(path, results={"smpl_thetas": aa.reshape(2, 72), "smpl_betas": b, "cam_trans": transl})
    people = read_estimate(path)
    _check(people, aa, transl, betas)
    assert people[0].camera is not None and people[0].camera.default_fov_deg == 60.0


@pytest.mark.parametrize("flat", [False, True])
def test_hybrik_pk(tmp_path, people_cam, flat):
    aa, transl, betas = people_cam
    R = _R(aa)
    J0 = rest_pelvis(betas, Gender.NEUTRAL)
    pelvis = J0 + transl  # HybrIK stores the pelvis position
    data = {"pred_thetas": R.reshape(2, 216) if flat else R, "pred_betas": betas, "transl": pelvis,
            "width": 640, "height": 480}
    path = tmp_path / "res.pk"
    with open(path, "wb") as fh:
        pickle.dump(data, fh)
    people = read_estimate(path)
    _check(people, aa, transl, betas)
    assert people[0].camera.image_size == (640, 480)


def test_phalp_joblib(tmp_path, people_cam):
    aa, transl, betas = people_cam
    R = _R(aa).astype(np.float32)
    frame = {"smpl": [{"global_orient": R[i, :1], "body_pose": R[i, 1:], "betas": betas[i].astype(np.float32)}
                      for i in range(2)],
             "camera": [transl[i].astype(np.float32) for i in range(2)], "tid": [3, 7], "size": [[1280, 720]] * 2,
             "time": 0}
    empty = {"smpl": [], "camera": [], "tid": [], "size": [], "time": 1}
    path = tmp_path / "demo.pkl"
    joblib.dump({"frame_000.jpg": frame, "frame_001.jpg": empty}, path)
    people = read_estimate(path)
    _check(people, aa, transl, betas, tol=2e-4)
    assert [p.person_id for p in people] == ["3", "7"]
    assert people[0].camera.focal_px == pytest.approx(5000 / 256 * 1280)


@pytest.mark.parametrize("space", ["camera", "world"])
def test_wham_joblib(tmp_path, people_cam, space):
    aa, transl, betas = people_cam
    T = 3
    out = {}
    for i in range(2):
        track = {"pose": np.repeat(aa[i].reshape(1, 72), T, 0), "trans": np.repeat(transl[i][None], T, 0),
                 "betas": np.repeat(betas[i][None], T, 0), "frame_ids": np.arange(T) + 10}
        if space == "world":
            track["pose_world"] = track["pose"].copy()
            track["trans_world"] = track["trans"].copy()
        out[i] = track
    path = tmp_path / "wham_output.pkl"
    joblib.dump(out, path, compress=3)
    people = read_estimate(path, format="wham")
    if space == "camera":
        _check(people, aa, transl, betas)
    else:  # y-up world already: taken as is
        for i, p in enumerate(people):
            np.testing.assert_allclose(p.global_orient, aa[i, 0], atol=1e-6)
            np.testing.assert_allclose(p.transl, transl[i], atol=1e-6)
            assert p.camera is None


def test_pymafx_joblib(tmp_path, people_cam):
    aa, transl, betas = people_cam
    data = {"pose": aa.reshape(2, 72), "betas": betas, "orig_cam_t": transl, "frame_ids": np.array([0, 0]),
            "person_ids": np.array([1, 2])}
    path = tmp_path / "output.pkl"
    joblib.dump(data, path)
    people = read_estimate(path)
    _check(people, aa, transl, betas)
    assert detect_format(load_pickle(path)) == "pymafx"


def test_plain_npz_and_json(tmp_path, people_cam):
    aa, transl, betas = people_cam
    path = tmp_path / "smpl.npz"
    np.savez(path, global_orient=aa[:, 0], body_pose=aa[:, 1:], transl=transl, betas=betas, frame="camera")
    _check(read_estimate(path), aa, transl, betas)
    js = tmp_path / "smpl.json"
    js.write_text(json.dumps([{"global_orient": aa[i, 0].tolist(), "body_pose": aa[i, 1:].tolist(),
                               "transl": transl[i].tolist(), "betas": betas[i].tolist(), "gender": "female"}
                              for i in range(2)]))
    people = read_estimate(js)
    assert [p.gender for p in people] == [Gender.FEMALE, Gender.FEMALE]
    np.testing.assert_allclose(people[1].transl, transl[1], atol=1e-9)  # world frame: unchanged


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


@pytest.mark.parametrize("writer", ["pickle", "joblib"])
def test_malicious_pickle_is_refused(tmp_path, writer):
    path = tmp_path / "evil.pkl"
    payload = {"pred_thetas": np.zeros((1, 24, 3, 3)), "x": _Evil()}
    if writer == "pickle":
        path.write_bytes(pickle.dumps(payload))
    else:
        joblib.dump(payload, path)
    with pytest.raises(UnsafePickleError, match=r"system.*--trust-pickle"):
        read_estimate(path)


def test_trust_pickle_opt_in_loads_plain_objects(tmp_path):
    from collections import Counter

    path = tmp_path / "counter.pkl"
    joblib.dump({"c": Counter("ab")}, path)
    with pytest.raises(UnsafePickleError, match="collections.Counter"):
        load_pickle(path)
    assert load_pickle(path, trust_pickle=True)["c"]["a"] == 1


def test_layout_errors_name_the_key(tmp_path):
    path = tmp_path / "bad.npz"
    np.savez(path, results={"smpl_thetas": np.zeros((1, 72)), "cam_trans": np.zeros((1, 3))})
    with pytest.raises(EstimateFormatError, match="smpl_betas"):
        read_estimate(path)
    other = tmp_path / "other.npz"
    np.savez(other, foo=np.zeros(3))
    with pytest.raises(EstimateFormatError, match="--format"):
        read_estimate(other)


def test_rotation_round_trip_helper():
    aa = np.array([[0.2, -0.1, 0.4]])
    from workflows.estimators.base import rotations_to_axis_angle

    np.testing.assert_allclose(rotations_to_axis_angle(_R(aa)), aa, atol=1e-9)


def test_hybrik_video_lists_and_frame(tmp_path, people_cam):
    aa, transl, betas = people_cam
    R = _R(aa)
    J0 = rest_pelvis(betas, Gender.NEUTRAL)
    data = {"pred_thetas": [R[i:i + 1] for i in range(2)], "pred_betas": [betas[i] for i in range(2)],
            "transl": [J0[i] + transl[i] for i in range(2)]}
    path = tmp_path / "video.pk"
    path.write_bytes(pickle.dumps(data))
    people = read_estimate(path, frame=1)
    _check(people, aa[1:], transl[1:], betas[1:])
