"""SAM-3D-Body / MHR reader: fixtures in the producer's layout hold MHR joints placed at the joints of a
known SMPL pose of our body in the camera, so the SMPL-IK fit must give that pose's joints back and the
overlay must match the producer's own projection (``u = f x / z + cx`` of ``pred_joint_coords + pred_cam_t``).
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from estimator_fixtures import (
    IMAGE_H,
    IMAGE_W,
    our_joints,
    overlay_pixels,
    people,
    project,
    sam3d_joints_cam,
    sam3d_person,
    write_sam3d,
)

from smplik.conventions import JOINT_NAMES
from workflows.estimators import EstimateFormatError, _load_raw, detect_format, people_from_data, read_estimate
from workflows.estimators.base import M_WORLD_CAMERA
from workflows.estimators.sam3d import MHR_JOINTS, SMPL_TARGETS, intrinsics_from_keypoints

TARGETS = [JOINT_NAMES.index(j) for j in SMPL_TARGETS]


def _people(n: int = 2, seed: int = 3):
    # 1.7 m people about 300 px tall in the 640x480 fixture camera (f = 700 px)
    return people(seed=seed, n=n, depth=4.0, focal=700.0)[:2]


@pytest.mark.parametrize("layout", ["pkl", "npz", "pt", "npz_list"])
def test_fit_recovers_the_joints_and_the_producers_pixels(tmp_path, layout, shipped_solver):
    aa, transl = _people(1 if layout == "npz" else 2)
    written, J_cam = write_sam3d(tmp_path, aa, transl, layout=layout)
    assert detect_format(_load_raw(written.path, False, 1 << 30)) == "sam3d"
    found = read_estimate(written.path, solver=shipped_solver)
    assert [p.person_id for p in found] == [str(i) for i in range(aa.shape[0])]
    for i, p in enumerate(found):
        err = np.linalg.norm(our_joints(p) - J_cam[i] @ M_WORLD_CAMERA.T, axis=-1)
        assert err[TARGETS].mean() < 0.01 and err.max() < 0.04, err  # all 24 joints, spine3 has no target
        assert np.abs(p.betas).max() == 0.0
    cam = found[0].camera
    assert cam.image_size == (IMAGE_W, IMAGE_H)  # npz: recovered from the keypoints, as the producer projects
    assert cam.focal_px == pytest.approx(written.f, rel=1e-4)
    expected = project(J_cam[:, [0, 15]], written.f, written.cx, written.cy)  # the producer's formula
    err_px = np.linalg.norm(overlay_pixels(found) - expected, axis=-1)
    assert err_px.max() < 2.0, err_px


def test_intrinsics_least_squares_and_fallbacks(tmp_path, best_solver):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (70, 3)) + [0, 0, 5]
    f, cx, cy, res = intrinsics_from_keypoints(pts, project(pts, 1234.0, 400.0, 300.0))
    assert (f, cx, cy) == pytest.approx((1234.0, 400.0, 300.0)) and res < 1e-6
    aa, transl = _people(1)
    person = sam3d_person(sam3d_joints_cam(aa, transl)[0])
    no_kp = {k: v for k, v in person.items() if k not in ("pred_keypoints_2d",)}
    cam = people_from_data([no_kp], source="x", format="sam3d", solver=best_solver)[0].camera
    assert cam.focal_px == pytest.approx(700.0) and cam.image_size is None
    bare = {k: v for k, v in no_kp.items() if k != "focal_length"}
    cam = people_from_data(bare, source="x", solver=best_solver)[0].camera
    assert cam.focal_px is None and cam.focal_rule == "diagonal"  # the producer's default intrinsics


def test_mapping_is_the_mhr_rig_order():
    # indices checked against the SAM-3D-Body sources (lower arms 76/40, wrist twists 77/41) and MHR's rig table
    assert (MHR_JOINTS["l_lowarm"], MHR_JOINTS["r_lowarm"], MHR_JOINTS["l_wrist_twist"]) == (76, 40, 77)
    assert len(SMPL_TARGETS) == 23 and "spine3" not in SMPL_TARGETS


def _bad(person: dict, key: str, value) -> dict:
    out = copy.deepcopy(person)
    if value is KeyError:
        del out[key]
    else:
        out[key] = value
    return out


@pytest.mark.parametrize("key,value,message", [
    ("pred_joint_coords", np.zeros((70, 3), np.float32),
     r"'pred_joint_coords' has shape \(70, 3\); expected \(127, 3\)"),
    ("pred_joint_coords", np.full((127, 3), np.nan, np.float32), "'pred_joint_coords' contains NaN"),
    ("pred_joint_coords", np.full((127, 3), 1e6, np.float32), "'pred_joint_coords' reach"),
    ("pred_joint_coords", "abc", "'pred_joint_coords' must be numbers"),
    ("pred_cam_t", np.zeros(2, np.float32), "'pred_cam_t' has 2 numbers; expected 3"),
    ("pred_cam_t", np.array([0, 0, np.inf], np.float32), "'pred_cam_t' contains NaN or inf"),
    ("pred_cam_t", KeyError, "missing key 'pred_cam_t'"),
    ("pred_cam_t", np.array([0, 0, 2e3], np.float32), r"'pred_cam_t' of 2e\+03 m is outside the physical range"),
    ("focal_length", np.float32(-5), "'focal_length' -5.0 must be positive"),
])
def test_bad_inputs_give_one_line_errors(tmp_path, key, value, message):
    aa, transl = _people(2)
    J = sam3d_joints_cam(aa, transl)
    good = sam3d_person(J[0])
    data = [sam3d_person(J[1]), _bad(good, key, value)]
    path = tmp_path / "bad.pkl"
    path.write_bytes(pickle.dumps(data))
    with pytest.raises(EstimateFormatError, match=message) as info:
        read_estimate(path, format="sam3d")
    assert "\n" not in str(info.value) and "bad.pkl[1]" in str(info.value)


def test_frames_people_cap_and_non_dicts(tmp_path):
    aa, transl = _people(2)
    written, _ = write_sam3d(tmp_path, aa, transl)
    with pytest.raises(EstimateFormatError, match="only frame 0, got --frame 1"):
        read_estimate(written.path, frame=1)
    with pytest.raises(EstimateFormatError, match="--max-people 2"):
        read_estimate(written.path, max_people=1)
    with pytest.raises(EstimateFormatError, match="person 1 is a str"):
        people_from_data([sam3d_person(sam3d_joints_cam(aa, transl)[0]), "x"], source="s", format="sam3d")
    with pytest.raises(EstimateFormatError, match="no people found"):
        people_from_data([], source="s", format="sam3d")


def test_the_given_solver_fits(tmp_path, shipped_solver):
    from dataclasses import replace

    from smplik.refine import RefineConfig

    aa, transl = _people(1)
    written, J_cam = write_sam3d(tmp_path, aa, transl)
    network_only = replace(shipped_solver, refine=RefineConfig(iterations=0))
    a = read_estimate(written.path)[0]  # the default: the shipped model, with its refinement
    b = read_estimate(written.path, solver=network_only)[0]
    target = J_cam[0] @ M_WORLD_CAMERA.T
    err_a = np.linalg.norm(our_joints(a) - target, axis=-1)[TARGETS].mean()
    err_b = np.linalg.norm(our_joints(b) - target, axis=-1)[TARGETS].mean()
    assert err_b > err_a + 1e-3  # the network alone, without the refinement: a different, looser fit


def test_scene_from_estimate_fits_with_the_commands_solver(tmp_path, monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app
    from workflows.scene import load_scene

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    aa, transl = _people(2)
    written, _ = write_sam3d(tmp_path, aa, transl)
    result = CliRunner().invoke(scene_app, ["from-estimate", str(written.path), "--out", str(tmp_path / "out"),
                                            "--no-previews", "--max-effectors", "3", "--format", "sam3d"])
    assert result.exit_code == 0, result.output
    scene = load_scene(tmp_path / "out" / "scene.json")
    assert [c.name for c in scene.characters] == ["person_0", "person_1"]
    assert all(len(c.effectors) == 3 and c.pose is not None for c in scene.characters)
    assert scene.camera.focal_px == pytest.approx(700.0) and scene.camera.image_size == (IMAGE_W, IMAGE_H)
    bad = CliRunner().invoke(scene_app, ["from-estimate", str(written.path), "--out", str(tmp_path / "o2"),
                                         "--no-previews", "--frame", "1"])
    assert bad.exit_code == 1 and "only frame 0" in bad.output.replace("\n", "")
