"""Estimator readers on fixtures in each producer's exact layout: placement in pixels, frames, errors.

Placement (issue 12): a person with known SMPL parameters in the producer's convention must project,
through the scene's overlay camera, to the pixels the producer's own formula gives
(:func:`estimator_fixtures.producer_pixels`: published SMPL rest joints, the producer's camera),
within 2 px for the pelvis and the head.
"""

from __future__ import annotations

import json
import os
import pickle

import joblib
import numpy as np
import pytest
import torch
from estimator_fixtures import (
    CAMERA_WRITERS,
    IMAGE_H,
    IMAGE_W,
    SINGLE_PERSON,
    framing,
    our_joints,
    overlay_pixels,
    people,
    producer_pixels,
    write_aist,
    write_amass,
    write_hybrik,
    write_phalp,
    write_romp,
    write_wham,
)

from smplik.conventions import Gender
from smplik.safe_pickle import UnsafePickleError, load_pickle
from workflows.estimators import EstimateFormatError, detect_format, read_estimate
from workflows.estimators.base import (
    M_WORLD_CAMERA,
    SMPL_NEUTRAL_REST_JOINTS,
    SMPLX_NEUTRAL_REST_PELVIS,
    rest_pelvis,
)
from workflows.scene import GroundRecord


@pytest.mark.parametrize("fmt", sorted(CAMERA_WRITERS))
def test_placement_matches_the_producers_pixels(tmp_path, fmt):
    n = 1 if fmt in SINGLE_PERSON else 2
    # people 200 px tall: the head error is the built-in body's proportions (~1 cm between pelvis and head,
    # under 1% of the person's height in pixels; benchmarks/estimator_placement.py), the pelvis is exact
    aa, transl, betas = people(seed=3, n=n, **framing(fmt, 200))
    written = CAMERA_WRITERS[fmt](tmp_path, aa, transl, betas)
    found = read_estimate(written.path, format="auto", space="camera")
    assert detect_format(_raw(written.path)) == {"bev": "romp", "gvhmr_flat": "gvhmr"}.get(fmt, fmt)
    assert len(found) == n
    expected = producer_pixels(written, aa[:n], transl[:n])
    got = overlay_pixels(found)
    err = np.linalg.norm(got - expected, axis=-1)  # (N, 2): pelvis, head
    assert err[:, 0].max() < 2.0, (fmt, err)
    if written.family == "smpl":  # SMPL-X: only the pelvis of the producer's body is known here
        assert err[:, 1].max() < 2.0, (fmt, err)
    # the placement is the producer's pelvis, not the built-in body's rest pelvis (the 1.16 m bug)
    pelvis_cam = (SMPL_NEUTRAL_REST_JOINTS[0] if written.family == "smpl" else SMPLX_NEUTRAL_REST_PELVIS) + transl[0]
    np.testing.assert_allclose(our_joints(found[0])[0], M_WORLD_CAMERA @ pelvis_cam, atol=1e-4)


def _raw(path):
    from workflows.estimators import _load_raw

    return _load_raw(path, False, 1 << 30)


def test_body_rotations_are_kept(tmp_path):
    aa, transl, betas = people(seed=1)
    betas = np.random.default_rng(0).normal(0, 1, betas.shape)
    found = read_estimate(write_romp(tmp_path, aa, transl, betas).path)
    for i, p in enumerate(found):
        np.testing.assert_allclose(p.body_pose, aa[i, 1:], atol=1e-5)
        np.testing.assert_allclose(p.betas, betas[i], atol=1e-6)
        # the root: M @ R_camera
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(p.global_orient).as_matrix()
        np.testing.assert_allclose(R, M_WORLD_CAMERA @ Rotation.from_rotvec(aa[i, 0]).as_matrix(), atol=1e-5)


def test_bev_age_component_is_dropped(tmp_path):
    aa, transl, betas = people(seed=2)
    found = read_estimate(write_romp(tmp_path, aa, transl, betas, bev=True).path, format="bev")
    assert all(p.betas.shape == (10,) and abs(p.betas).max() == 0 for p in found)
    assert found[0].camera.default_fov_deg == 60.0


@pytest.mark.parametrize("quaternions", [False, True])
def test_hybrik_video_one_person_per_frame(tmp_path, quaternions):
    aa, transl, betas = people(seed=4, n=3)
    w = write_hybrik(tmp_path, aa, transl, betas, quaternions=quaternions)
    first = read_estimate(w.path)
    assert len(first) == 1 and first[0].person_id == "0" and first[0].frame == "0"  # not 3 "people"
    second = read_estimate(w.path, frame=2)
    np.testing.assert_allclose(second[0].body_pose, aa[2, 1:], atol=1e-4)
    assert first[0].camera.image_size == (IMAGE_W, IMAGE_H)
    assert first[0].camera.focal_px == pytest.approx(1000 / 256 * 250)
    with pytest.raises(EstimateFormatError, match=r"frame 3 out of range \(0\.\.2\)"):
        read_estimate(w.path, frame=3)


def test_romp_video_frames_and_track_ids(tmp_path):
    aa, transl, betas = people(seed=5)
    w = write_romp(tmp_path, aa, transl, betas, video=True)
    found = read_estimate(w.path, frame=1)
    assert [p.person_id for p in found] == ["5", "6"] and found[0].frame == "00000001.jpg"
    with pytest.raises(EstimateFormatError, match="out of range"):
        read_estimate(w.path, frame=2)
    single = write_romp(tmp_path, aa, transl, betas)
    with pytest.raises(EstimateFormatError, match="only frame 0"):
        read_estimate(single.path, frame=1)


def test_phalp_frame_rule_and_track_ids(tmp_path):
    aa, transl, betas = people(seed=6)
    w = write_phalp(tmp_path, aa, transl, betas)
    found = read_estimate(w.path)
    assert [p.person_id for p in found] == ["3", "4"]
    assert found[0].camera.focal_px == pytest.approx(5000 / 256 * IMAGE_W)
    with pytest.raises(EstimateFormatError, match="no people in this frame"):
        read_estimate(w.path, frame=1)


def test_wham_tracks_at_a_frame_and_world_space(tmp_path):
    aa, transl, betas = people(seed=7)
    w = write_wham(tmp_path, aa, transl, betas)
    cam = read_estimate(w.path, space="camera", frame=2)
    assert [p.person_id for p in cam] == ["0", "1"] and cam[0].camera.focal_rule == "diagonal"
    world = read_estimate(w.path, frame=1)  # WHAM's y-up world: no camera, pelvis = J0_smpl + trans
    assert world[0].camera is None
    np.testing.assert_allclose(our_joints(world[0])[0], SMPL_NEUTRAL_REST_JOINTS[0] + transl[0], atol=1e-4)
    with pytest.raises(EstimateFormatError, match=r"no track covers frame 9 \(tracks cover frames 0\.\.2\)"):
        read_estimate(w.path, frame=9)


def test_gvhmr_world_and_npz(tmp_path):
    aa, transl, betas = people(seed=8, n=1)
    w = CAMERA_WRITERS["gvhmr"](tmp_path, aa, transl, betas)
    world = read_estimate(w.path, space="world", frame=1)
    np.testing.assert_allclose(our_joints(world[0])[0], SMPLX_NEUTRAL_REST_PELVIS + transl[0], atol=1e-4)
    data = torch.load(w.path, weights_only=True)
    flat = {f"{k}/{kk}": vv.numpy() for k in ("smpl_params_incam", "smpl_params_global")
            for kk, vv in data[k].items()}
    npz = tmp_path / "hmr4d_results.npz"
    np.savez(npz, K_fullimg=data["K_fullimg"].numpy(), **flat)
    a, b = read_estimate(npz)[0], read_estimate(w.path)[0]
    np.testing.assert_allclose(a.transl, b.transl, atol=1e-6)
    assert a.camera.principal_px == pytest.approx((IMAGE_W / 2, IMAGE_H / 2))
    # GVHMR's K_fullimg = estimate_K(width, height): the image size is twice the principal point
    assert a.camera.image_size == (IMAGE_W, IMAGE_H) and a.camera.focal_rule == "intrinsics"
    assert a.camera.focal_px == pytest.approx(np.hypot(IMAGE_W, IMAGE_H), rel=1e-6)


def test_gvhmr_flat_underscore_keys_of_an_amass_style_conversion(tmp_path):
    """video2smpl's pt2npz/Converter.py: AMASS keys (poses, trans) beside K_fullimg and smpl_params_incam_*:
    auto-detection reads it as GVHMR with its camera; --format amass reads the AMASS keys, without one."""
    from estimator_fixtures import write_gvhmr_flat_npz

    aa, transl, betas = people(seed=8, n=1)
    w = write_gvhmr_flat_npz(tmp_path, aa, transl, betas)
    assert "smpl_params_incam_body_pose" in np.load(w.path).files
    a = read_estimate(w.path)[0]
    b = read_estimate(CAMERA_WRITERS["gvhmr"](tmp_path / "pt" if (tmp_path / "pt").mkdir() is None else tmp_path,
                                              aa, transl, betas).path)[0]
    np.testing.assert_allclose(a.transl, b.transl, atol=1e-6)
    np.testing.assert_allclose(a.body_pose, b.body_pose, atol=1e-6)
    assert a.camera == b.camera and a.camera.image_size == (IMAGE_W, IMAGE_H)
    assert read_estimate(w.path, format="amass")[0].camera is None


def test_aist_world_frame(tmp_path):
    aa, transl, _ = people(seed=9, n=3)
    path = write_aist(tmp_path, aa, transl)
    found = read_estimate(path, frame=2)
    assert found[0].gender == Gender.MALE and found[0].camera is None
    np.testing.assert_allclose(our_joints(found[0])[0], SMPL_NEUTRAL_REST_JOINTS[0] + transl[2], atol=1e-4)


@pytest.mark.parametrize("smplx", [False, True])
def test_amass_smplh_smplx_parameter_files(tmp_path, smplx):
    aa, transl, _ = people(seed=10, n=2)
    path = write_amass(tmp_path, aa, transl, smplx=smplx)
    found = read_estimate(path, frame=1)
    J0 = SMPLX_NEUTRAL_REST_PELVIS if smplx else SMPL_NEUTRAL_REST_JOINTS[0]
    R = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # AMASS z-up -> y-up
    np.testing.assert_allclose(our_joints(found[0])[0], R @ (J0 + transl[1]), atol=1e-4)
    np.testing.assert_allclose(found[0].body_pose[21:], 0.0)  # SMPL's hands: no SMPL-H/X counterpart


def test_plain_formats_and_intrinsics(tmp_path):
    aa, transl, betas = people(seed=11)
    js = tmp_path / "smpl.json"
    js.write_text(json.dumps([{"global_orient": aa[i, 0].tolist(), "body_pose": aa[i, 1:].tolist(),
                               "transl": transl[i].tolist(), "betas": betas[i].tolist(), "gender": "female",
                               "frame": "camera", "focal_length": 900, "image_size": [IMAGE_W, IMAGE_H]}
                              for i in range(2)]))
    found = read_estimate(js)
    assert [p.gender for p in found] == [Gender.FEMALE, Gender.FEMALE]
    assert found[1].camera.focal_px == 900 and [p.person_id for p in found] == ["0", "1"]
    x = tmp_path / "smplx.npz"
    np.savez(x, global_orient=aa[:1, 0], body_pose=aa[:1, 1:22].reshape(1, 63), transl=transl[:1])
    p = read_estimate(x)[0]  # SMPL-X body: SMPL-X's rest pelvis, world frame
    np.testing.assert_allclose(our_joints(p)[0], SMPLX_NEUTRAL_REST_PELVIS + transl[0], atol=1e-4)
    pt = tmp_path / "smpl.pt"
    torch.save({"global_orient": torch.tensor(aa[:, 0]), "body_pose": torch.tensor(aa[:, 1:])}, pt)
    assert len(read_estimate(pt)) == 2


def test_unknown_format_lists_keys_and_formats(tmp_path):
    other = tmp_path / "other.npz"
    np.savez(other, foo=np.zeros(3), bar=np.ones(2))
    with pytest.raises(EstimateFormatError, match=r"top-level keys: (foo, bar|bar, foo).*romp, bev, hybrik.*gvhmr"):
        read_estimate(other)
    bad = tmp_path / "bad.npz"
    np.savez(bad, results={"smpl_thetas": np.zeros((1, 72)), "cam_trans": np.zeros((1, 3))})
    with pytest.raises(EstimateFormatError, match="smpl_betas"):
        read_estimate(bad)


def test_ground_moves_people_and_camera_together(tmp_path):
    from workflows.scene.pipeline import lowest_point, put_on_ground

    aa, transl, betas = people(seed=12)
    found = read_estimate(CAMERA_WRITERS["romp"](tmp_path, aa, transl, betas).path)
    moved, record = put_on_ground(found)
    assert abs(lowest_point(moved)) < 1e-5 and record.camera_height_m > 0.5
    # the overlay is unchanged: the camera moved up with the people
    np.testing.assert_allclose(overlay_pixels(moved, ground=record), overlay_pixels(found), atol=1e-3)
    assert GroundRecord(1.2).to_dict() == {"camera_height_m": 1.2}


def test_nan_focal_never_reaches_a_scene(tmp_path):
    from workflows.scene import SceneError, scene_from_dict

    aa, transl, betas = people(seed=13)
    js = tmp_path / "nan.json"
    js.write_text(json.dumps({"global_orient": aa[0, 0].tolist(), "body_pose": aa[0, 1:].tolist(), "frame": "camera",
                              "focal_length": float("nan"), "image_size": [640, 480]}).replace("NaN", "NaN"))
    with pytest.raises(EstimateFormatError, match="focal_length"):
        read_estimate(js)
    scene = {"format": "smplik-scene", "version": 1, "characters": [], "camera": {"focal_px": float("nan")}}
    with pytest.raises(SceneError, match="focal"):
        scene_from_dict(scene)


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


def test_malicious_pt_is_refused(tmp_path):
    marker = tmp_path / "ran"
    path = tmp_path / "hmr4d_results.pt"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    torch.save({"smpl_params_incam": Payload()}, path)
    with pytest.raises(EstimateFormatError, match="weights_only"):
        read_estimate(path)
    assert not marker.exists()


def test_trust_pickle_opt_in_loads_plain_objects(tmp_path):
    from collections import Counter

    path = tmp_path / "counter.pkl"
    joblib.dump({"c": Counter("ab")}, path)
    with pytest.raises(UnsafePickleError, match="collections.Counter"):
        load_pickle(path)
    assert load_pickle(path, trust_pickle=True)["c"]["a"] == 1


def test_rotation_round_trip_helper():
    from scipy.spatial.transform import Rotation

    from workflows.estimators.base import rotations_to_axis_angle

    aa = np.array([[0.2, -0.1, 0.4]])
    np.testing.assert_allclose(rotations_to_axis_angle(Rotation.from_rotvec(aa).as_matrix()), aa, atol=1e-9)


def test_our_rest_pelvis_differs_from_smpls():
    """The built-in body's rest pelvis is ~1.16 m above SMPL's: why J0 must be the producer's."""
    ours = rest_pelvis(np.zeros((1, 10)), Gender.NEUTRAL)[0]
    assert ours[1] - SMPL_NEUTRAL_REST_JOINTS[0, 1] > 1.0
