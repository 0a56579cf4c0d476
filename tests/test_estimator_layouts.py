"""Four more estimator layouts, each fixture written in its producer's exact layout (the producer's code named):
AGORA prediction pickles, mmhuman3d HumanData, SMPL-X sequences in smplx-layer keys, SMPLify-X results with their
camera; SMPLer-X folders of one person over consecutive frames as one track; the closest-format hint."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from estimator_fixtures import (
    HEAD,
    PELVIS,
    people,
    producer_joints,
    project,
    write_agora,
    write_humandata,
    write_smplerx,
    write_smplifyx,
)

from workflows.estimators import EstimateFormatError, read_estimate
from workflows.estimators.base import M_WORLD_CAMERA
from workflows.estimators.reading import closest_format


def _pelvis_world(p) -> np.ndarray:
    from workflows.estimators.reading import pelvis_of

    return pelvis_of(p)


@pytest.mark.parametrize("smplx,pose2rot", [(False, True), (True, True), (False, False)])
def test_agora_people_of_an_image(tmp_path, smplx, pose2rot):
    aa, transl, betas = people(seed=1, n=3, depth=6.0)
    paths = write_agora(tmp_path, aa, transl, betas, smplx=smplx, pose2rot=pose2rot)
    found = read_estimate(paths[1])
    assert [p.person_id for p in found] == ["0", "1", "2"]
    family = "smplx" if smplx else "smpl"
    for k, p in enumerate(found):  # each pelvis where AGORA's body puts it (camera frame -> y-up world)
        assert np.allclose(_pelvis_world(p), M_WORLD_CAMERA @ producer_joints(aa[k:k + 1], transl[k:k + 1],
                                                                               family)[0, PELVIS], atol=2e-3)
        head_above = M_WORLD_CAMERA @ producer_joints(aa[k:k + 1], transl[k:k + 1])[0, HEAD]
        assert head_above[1] > _pelvis_world(p)[1]  # upright


def test_humandata_frames_and_people(tmp_path):
    """mmhuman3d HumanData.dump: np.savez_compressed(path, **{'smpl': dict, 'image_path': ..., ...})."""
    aa, transl, betas = people(seed=2, n=3, depth=5.0)
    write_humandata(tmp_path / "hd.npz", aa, transl, betas, rows=[0, 1, 2, 0, 1],
                    images=["a.jpg", "a.jpg", "b.jpg", "c.jpg", "c.jpg"])  # images a: 2 people, b: 1, c: 2
    assert len(read_estimate(tmp_path / "hd.npz", frame=0)) == 2
    (only,) = read_estimate(tmp_path / "hd.npz", frame=1)
    assert np.allclose(_pelvis_world(only), M_WORLD_CAMERA @ producer_joints(aa[2:3], transl[2:3])[0, PELVIS],
                       atol=2e-3)
    assert len(read_estimate(tmp_path / "hd.npz", frame=2)) == 2
    with pytest.raises(EstimateFormatError, match="out of range"):
        read_estimate(tmp_path / "hd.npz", frame=3)
    from workflows.animation.clips import read_clip

    clip = read_clip(tmp_path / "hd.npz")  # scene animate: the images are the clip's frames
    assert clip.length == 3 and [f for f, _ in clip.tracks["0"]] == [0, 1, 2]


def test_smplx_sequence_in_layer_keys_is_one_person_over_frames(tmp_path):
    """smplx.SMPLX layer keys for T frames (global_orient (T, 3), one betas row): not SMPLer-X's one person."""
    T = 6
    aa, transl, _ = people(seed=3, n=T, depth=4.0)
    np.savez(tmp_path / "seq.npz", global_orient=aa[:, 0], body_pose=aa[:, 1:22].reshape(T, 63),
             jaw_pose=np.zeros((T, 3)), leye_pose=np.zeros((T, 3)), reye_pose=np.zeros((T, 3)),
             left_hand_pose=np.zeros((T, 45)), right_hand_pose=np.zeros((T, 45)), expression=np.zeros((T, 10)),
             transl=transl, betas=np.zeros((1, 10)))
    for f in (0, 5):
        (p,) = read_estimate(tmp_path / "seq.npz", frame=f)
        assert p.person_id == "0"
        assert np.allclose(p.global_orient, aa[f, 0])


def test_smplifyx_upright_and_on_its_photo(tmp_path):
    """The body stands upright and its pelvis and head land where SMPLify-X's own camera (focal 5000, image centre,
    model frame = OpenCV camera frame) draws them, within 3 % of the body's image height."""
    W, H = 1000, 1200
    aa, transl, _ = people(seed=4, n=1, depth=25.0, focal=5000.0)
    t = transl[0]  # camera_translation: the model frame is the camera frame (no transl)
    write_smplifyx(tmp_path / "000.pkl", aa[0], t)
    (p,) = read_estimate(tmp_path / "000.pkl")
    assert p.camera is not None and p.camera.focal_px == 5000.0
    from estimator_fixtures import our_joints

    J = our_joints(p)  # world (y-up), camera at the origin looking down -z
    assert J[HEAD, 1] - J[PELVIS, 1] > 0.3  # upright: head above the pelvis
    assert J[PELVIS, 2] < 0  # in front of the camera
    ours = project(J[[PELVIS, HEAD]] @ M_WORLD_CAMERA.T, 5000.0, W / 2, H / 2)
    theirs = project(producer_joints(aa, t[None], "smplx")[0, [PELVIS, HEAD]], 5000.0, W / 2, H / 2)
    height_px = 5000.0 * 1.7 / 25.0
    assert np.abs(ours[0] - theirs[0]).max() < 0.03 * height_px  # the pelvis: exact in the producer's model
    assert np.abs(ours[1] - theirs[1]).max() < 0.03 * height_px * 3  # the head: our skeleton vs SMPL's published one


def test_smplifyx_vposer_embedding_is_named(tmp_path):
    aa, transl, _ = people(seed=4, n=1)
    write_smplifyx(tmp_path / "r.pkl", aa[0], transl[0])
    with open(tmp_path / "r.pkl", "rb") as fh:
        data = pickle.load(fh)
    data["body_pose"] = np.zeros((1, 32), np.float32)
    with open(tmp_path / "v.pkl", "wb") as fh:
        pickle.dump(data, fh, protocol=2)
    with pytest.raises(EstimateFormatError, match="VPoser"):
        read_estimate(tmp_path / "v.pkl")


def test_smplerx_folder_one_person_is_one_track(tmp_path):
    """SMPLer-X main/inference.py over 3 consecutive frames of one person whose detection box jitters (each frame's
    crop camera scales with its box, so the depth moved into frame 1's camera jumps by 0.6 m): one track."""
    from workflows.animation.clips import read_clip

    aa, transl, betas = people(seed=5, n=1, depth=5.0, focal=5000.0)
    for f, h in zip((1, 2, 3), (240.0, 270.0, 236.0), strict=True):
        write_smplerx(tmp_path, aa, transl + [0.01 * f, 0, 0], betas, [(100.0 + 2 * f, 80.0, h * 0.75, h)], frame=f)
    clip = read_clip(tmp_path)
    assert {k: [f for f, _ in v] for k, v in clip.tracks.items()} == {"0": [0, 1, 2]}


def test_closest_hint_names_real_missing_keys():
    nested = {"params": {"global_orient": 1, "body_pose": 2, "transl": 3, "betas": 4}}
    assert "needs ." not in closest_format(nested)
    hint = closest_format({"smpl": {"global_orient": 1}, "meta": {}})  # mmhuman3d HumanData without its row keys
    assert "closest: humandata, which also needs '__data_len__', 'image_path'" in hint
    assert "closest: wham, which also needs 'betas'" in closest_format({"pose": 1, "trans": 2})


def test_from_estimate_smplifyx_with_its_photo(tmp_path, monkeypatch, best_solver):
    """The issue's run: `scene from-estimate result.pkl --image photo --focal 5000`: the body in front of the camera,
    upright, its pelvis on the producer's projection (within 3 % of its image height)."""
    from estimator_fixtures import our_joints
    from PIL import Image
    from typer.testing import CliRunner

    import workflows.cli as cli_module
    from workflows.scene import load_scene

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    W, H = 1000, 1200
    aa, transl, _ = people(seed=6, n=1, depth=25.0, focal=5000.0)
    write_smplifyx(tmp_path / "result.pkl", aa[0], transl[0])
    Image.new("RGB", (W, H)).save(tmp_path / "photo.png")
    result = CliRunner().invoke(cli_module.scene_app, ["from-estimate", str(tmp_path / "result.pkl"), "--image",
                                                       str(tmp_path / "photo.png"), "--focal", "5000", "--out",
                                                       str(tmp_path / "out"), "--no-previews", "--max-effectors", "3"])
    assert result.exit_code == 0, result.output
    scene = load_scene(tmp_path / "out" / "scene.json")
    assert scene.camera.focal_px == pytest.approx(5000.0)
    (person,) = read_estimate(tmp_path / "result.pkl")
    J = our_joints(person)
    assert J[PELVIS, 2] < -20 and J[HEAD, 1] > J[PELVIS, 1] + 0.3
    ours = project((J[PELVIS] @ M_WORLD_CAMERA.T)[None], 5000.0, W / 2, H / 2)[0]
    theirs = project(producer_joints(aa, transl, "smplx")[0, PELVIS][None], 5000.0, W / 2, H / 2)[0]
    assert np.abs(ours - theirs).max() < 0.03 * 5000.0 * 1.7 / 25.0
