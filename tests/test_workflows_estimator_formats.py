"""Readers added for issue 26: VIBE / PARE, EasyMocap SMPL json, bare pose arrays, TRAM, SMPLer-X; the closest-format
hint; demos that save only meshes; pickled torch tensors in ``.npy``."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from estimator_fixtures import (
    FOCAL,
    our_joints,
    overlay_pixels,
    people,
    producer_joints,
    weak_perspective_pixels,
    write_easymocap,
    write_vibe,
)
from scipy.spatial.transform import Rotation

from workflows.estimators import EstimateFormatError, closest_format, detect_format, read_estimate
from workflows.estimators.easymocap import R_YUP_ZUP
from workflows.estimators.pose_array import EstimateNote


@pytest.mark.parametrize("pare", [False, True])
def test_vibe_and_pare_land_where_their_renderer_draws(tmp_path, pare):
    depth = FOCAL["vibe"] * 1.7 / 200.0  # people 200 px tall
    aa, transl, betas = people(seed=4, n=2, depth=depth, focal=FOCAL["vibe"])
    w = write_vibe(tmp_path, aa, transl, betas, pare=pare)
    from workflows.estimators import _load_raw

    assert detect_format(_load_raw(w.path, False, 1 << 30)) == "vibe"
    first = read_estimate(w.path, frame=0)
    assert [p.person_id for p in first] == ["1"]  # person 2's track starts at frame 1
    both = read_estimate(w.path, frame=1)
    assert [p.person_id for p in both] == ["1", "2"]
    err = np.linalg.norm(overlay_pixels(both) - weak_perspective_pixels(w, aa, transl), axis=-1)
    # pelvis: weak perspective ignores the pelvis's own depth (a few cm at 4-6 m); head: that plus the head's
    # depth off the pelvis (a leaning body) and body proportions: within 3 % of the body's 200 px
    assert err[:, 0].max() < 2.0 and err[:, 1].max() < 0.03 * 200, err
    np.testing.assert_allclose(both[0].body_pose, aa[0, 1:], atol=1e-5)


def test_vibe_frame_without_people_is_one_line(tmp_path):
    aa, transl, betas = people(seed=4, n=1)
    w = write_vibe(tmp_path, aa, transl, betas)
    with pytest.raises(EstimateFormatError, match="no person in frame 7"):
        read_estimate(w.path, frame=7)


def test_easymocap_json_follows_its_body_model(tmp_path):
    """EasyMocap poses the body with ``poses``, rotates it by Rh about the origin and adds Th (z-up world)."""
    rng = np.random.default_rng(0)
    aa = rng.normal(0, 0.2, (2, 24, 3))
    Rh = np.array([[0.1, -0.2, 1.4], [1.5, 0.0, 0.3]])
    Th = np.array([[0.4, 1.2, 0.9], [-0.8, 0.1, 1.0]])
    path = write_easymocap(tmp_path, [{"id": 3 + i, "Rh": Rh[i], "Th": Th[i], "poses": aa[i].reshape(72),
                                       "shapes": np.zeros(10)} for i in range(2)])
    found = read_estimate(path)
    assert [p.person_id for p in found] == ["3", "4"] and found[0].camera is None
    for i, p in enumerate(found):
        lbs = producer_joints(aa[i:i + 1], np.zeros((1, 3)))[0]  # SMPL's joints, no translation
        world_zup = Rotation.from_rotvec(Rh[i]).apply(lbs) + Th[i]
        ours = our_joints(p)
        np.testing.assert_allclose(ours[0], R_YUP_ZUP.apply(world_zup[0]), atol=1e-4)  # the pelvis exactly
        assert np.linalg.norm(ours[15] - R_YUP_ZUP.apply(world_zup[15])) < 0.03  # the head: body proportions
    with pytest.raises(EstimateFormatError, match="one frame"):
        read_estimate(path, frame=1)


@pytest.mark.parametrize(("width", "model"), [(72, "SMPL"), (156, "SMPL-H"), (165, "SMPL-X")])
def test_bare_pose_arrays_say_what_they_assume(tmp_path, width, model):
    rng = np.random.default_rng(width)
    poses = rng.normal(0, 0.2, (4, width))
    path = tmp_path / "poses.npy"
    np.save(path, poses)
    with pytest.warns(EstimateNote, match=f"{width} columns, read as {model} axis-angle"):
        found = read_estimate(path, frame=2)
    np.testing.assert_allclose(found[0].global_orient, poses[2, :3], atol=1e-9)
    np.testing.assert_allclose(found[0].body_pose[:21], poses[2, 3:66].reshape(21, 3), atol=1e-9)
    np.testing.assert_allclose(our_joints(found[0])[0], 0.0, atol=1e-6)  # pelvis at the origin
    npz = tmp_path / "one.npz"
    np.savez(npz, full_pose=poses)
    with pytest.warns(EstimateNote):
        assert read_estimate(npz, frame=1)[0].body_pose.shape == (23, 3)


def test_pose_array_without_a_root_and_pickled_npy_are_one_line(tmp_path):
    path = tmp_path / "body.npy"
    np.save(path, np.zeros((3, 69)))
    with pytest.raises(EstimateFormatError, match=r"\(3, 69\).*72 \| 156 \| 165"):
        read_estimate(path)
    with pytest.raises(EstimateFormatError, match="root rotation is missing"):
        read_estimate(path, format="pose_array")
    obj = tmp_path / "dict.npy"  # a saved dict goes through the restricted unpickler, then the closest-format hint
    np.save(obj, {"pose": np.zeros(3)}, allow_pickle=True)
    with pytest.raises(EstimateFormatError, match=r"top-level keys: pose\); closest: wham"):
        read_estimate(obj)


def test_no_reader_fits_names_the_closest_format_and_its_missing_keys(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, pose=np.zeros((2, 72)), betas=np.zeros((2, 10)))  # WHAM-like keys without 'trans', flat
    with pytest.raises(EstimateFormatError) as exc:
        read_estimate(path)
    message = str(exc.value)
    assert "\n" not in message and "closest: wham" in message and "'trans'" in message, message
    assert closest_format({"Rh": 1, "Th": 2, "poses": 3}).startswith("closest: easymocap")
    assert "known formats" in closest_format({"nothing": 1})



def test_glamr_camera_and_world_spaces(tmp_path):
    from estimator_fixtures import FOCAL, producer_pixels, write_glamr

    aa, transl, betas = people(seed=6, n=2, depth=FOCAL["hybrik"] * 1.7 / 200.0, focal=FOCAL["hybrik"])
    w, T_wc = write_glamr(tmp_path, aa, transl, betas)
    cam = read_estimate(w.path, space="camera", frame=2)
    assert [p.person_id for p in cam] == ["0", "1"] and cam[0].camera.focal_px == pytest.approx(w.f)
    err = np.linalg.norm(overlay_pixels(cam) - producer_pixels(w, aa, transl), axis=-1)
    assert err[:, 0].max() < 1e-3 and err[:, 1].max() < 2.0, err  # the pelvis exactly (root_trans is the pelvis)
    world = read_estimate(w.path)  # GLAMR's point: the world trajectory, z-up -> y-up
    assert world[0].camera is None
    pelvis_w = T_wc[:3, :3] @ producer_joints(aa, transl)[:, 0].T + T_wc[:3, 3:]
    for i, p in enumerate(world):
        np.testing.assert_allclose(our_joints(p)[0], R_YUP_ZUP.apply(pelvis_w[:, i]), atol=1e-4)
    with pytest.raises(EstimateFormatError, match="no person has frame 5"):
        read_estimate(w.path, frame=5)


def test_tram_tracks_and_camera_are_read_through_the_restricted_loader(tmp_path):
    from estimator_fixtures import producer_pixels, write_tram

    aa, transl, betas = people(seed=7, n=2, depth=900.0 * 1.7 / 200.0, focal=900.0)
    w, paths = write_tram(tmp_path, aa, transl, betas)
    from workflows.estimators import _load_raw

    assert detect_format(_load_raw(paths[1], False, 1 << 30)) == "tram"  # np.save of a dict of torch tensors
    first = read_estimate(paths[1], frame=0)  # any track file of the folder gives every track of the frame
    assert [p.person_id for p in first] == ["0"]
    both = read_estimate(w.path, frame=1)
    assert [p.person_id for p in both] == ["0", "1"]
    cam = both[0].camera
    assert cam.focal_px == pytest.approx(900.0) and cam.image_size == (640, 480) and cam.focal_rule == "intrinsics"
    err = np.linalg.norm(overlay_pixels(both) - producer_pixels(w, aa, transl), axis=-1)
    assert err[:, 0].max() < 1e-3 and err[:, 1].max() < 2.0, err  # pelvis exactly, head within the body's proportions
    np.testing.assert_allclose(both[1].body_pose, aa[1, 1:], atol=1e-4)
    with pytest.raises(EstimateFormatError, match="no TRAM track .* has frame 9"):
        read_estimate(w.path, frame=9)
    (w.path.parent.parent / "camera.npy").unlink()
    with pytest.warns(EstimateNote, match="no TRAM camera.npy"):
        assert read_estimate(w.path, frame=1)[0].camera.focal_px is None


def test_tram_world_follows_its_slam_trajectory(tmp_path):
    """``--space world``: TRAM's renderer puts a body at ``pred_cam_R[f] @ x + pred_cam_T[f]`` (OpenCV axes), turned
    y-up here like every camera frame."""
    from estimator_fixtures import write_tram

    from workflows.estimators.base import M_WORLD_CAMERA

    aa, transl, betas = people(seed=10, n=2, depth=4.0, focal=900.0)
    cam_R = Rotation.from_rotvec(np.random.default_rng(3).normal(0, 0.6, (4, 3))).as_matrix()
    cam_T = np.random.default_rng(4).normal(0, 2.0, (4, 3))
    w, _ = write_tram(tmp_path, aa, transl, betas, cam_R=cam_R, cam_T=cam_T)
    world = read_estimate(w.path, frame=2, space="world")
    assert [p.person_id for p in world] == ["0", "1"] and world[0].camera is None
    pelvis_cam = producer_joints(aa, transl)[:, 0]
    for i, p in enumerate(world):
        np.testing.assert_allclose(our_joints(p)[0], M_WORLD_CAMERA @ (cam_R[2] @ pelvis_cam[i] + cam_T[2]), atol=1e-4)
        R_root = Rotation.from_rotvec(p.global_orient).as_matrix()
        np.testing.assert_allclose(R_root, M_WORLD_CAMERA @ cam_R[2] @ Rotation.from_rotvec(aa[i, 0]).as_matrix(),
                                   atol=1e-5)
    (w.path.parent.parent / "camera.npy").unlink()
    with pytest.raises(EstimateFormatError, match="--space world needs TRAM's camera.npy"), pytest.warns(EstimateNote):
        read_estimate(w.path, frame=2, space="world")


def test_npy_pickles_still_refuse_code(tmp_path):
    from smplik.safe_pickle import UnsafePickleError

    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    path = tmp_path / "hps_track_0.npy"
    np.save(path, {"pred_rotmat": Evil()}, allow_pickle=True)
    with pytest.raises(UnsafePickleError, match="builtins.print"):
        read_estimate(path)


@pytest.mark.parametrize("meta", [True, False])
def test_smplerx_people_of_a_frame_share_the_first_persons_camera(tmp_path, meta):
    from estimator_fixtures import producer_pixels, write_smplerx

    boxes = [(100.0, 80.0, 180.0, 240.0), (380.0, 60.0, 210.0, 280.0)]  # each person's own camera (its box)
    focals = [5000.0 / 256.0 * h for *_, h in boxes]
    aa, transl, betas = people(seed=8, n=2)
    for i, f in enumerate(focals):  # 200 px tall, near its box centre
        transl[i] = [0.05 * (-1) ** i, 0.1, f * 1.7 / 200.0]
    betas[1, :3] = [0.5, -0.3, 0.2]
    paths, cams = write_smplerx(tmp_path, aa, transl, betas, boxes, meta=meta)
    from workflows.estimators import _load_raw

    assert detect_format(_load_raw(paths[1], False, 1 << 30)) == "smplerx"
    if not meta:
        with pytest.warns(EstimateNote, match="no SMPLer-X meta json"):
            found = read_estimate(paths[1])
        assert found[0].camera.focal_px is None
        return
    found = read_estimate(paths[1])  # any person's file gives every person of its frame
    assert [p.person_id for p in found] == ["0", "1"] and found[0].frame == "1"
    assert found[0].camera.focal_px == pytest.approx(cams[0].f)
    for i, p in enumerate(found):  # each person where its own camera draws it, through the scene's one camera
        own = producer_pixels(cams[i], aa[i:i + 1], transl[i:i + 1])[0]
        err = np.linalg.norm(overlay_pixels([found[0], p])[1] - own, axis=-1)
        assert err[0] < 1e-3 and err[1] < 0.03 * 200, (i, err)
    assert [p.person_id for p in read_estimate(paths[0], frame=1)] == ["0", "1"]
    with pytest.raises(EstimateFormatError, match="no SMPLer-X file 00004"):
        read_estimate(paths[0], frame=4)


def test_meshes_from_demos_that_save_only_meshes_say_so(tmp_path):
    obj = tmp_path / "img_0.obj"
    obj.write_text("v 0 0 0\n")
    with pytest.raises(EstimateFormatError, match="no SMPL parameters.*CameraHMR"):
        read_estimate(obj)
    verts = tmp_path / "img.npy"  # Multi-HMR demo.py --save_mesh: np.save of the people's SMPL-X vertices
    np.save(verts, np.zeros((2, 10475, 3), np.float32))
    with pytest.raises(EstimateFormatError, match=r"\(2, 10475, 3\) holds SMPL-X mesh vertices"):
        read_estimate(verts)


REAL_LAYOUTS = {"vibe": ("vibe_output.pkl", "pare_output.pkl"), "easymocap": ("smpl/*.json",),
                "glamr": ("*.pkl",), "phalp": ("*.pkl",), "tram": ("hps/hps_track_*.npy",), "smplerx": ("smplx/*.npz",)}
"""Where each producer's real outputs sit under ``real_estimators_dir()/<format>*/`` (any depth)."""


def _first_frame(data, fmt: str) -> int:
    if fmt == "tram":
        return int(np.asarray(data["frame"]).reshape(-1)[0])
    if fmt == "vibe":
        return int(np.asarray(next(iter(data.values()))["frame_ids"]).reshape(-1)[0])
    if fmt == "phalp":  # frames in name order; a real run may start on frames with nobody in them
        names = sorted(data, key=str)
        return next((i for i, n in enumerate(names) if len(data[n].get("smpl") or ()) > 0), 0)
    return 0


@pytest.mark.parametrize("fmt", sorted(REAL_LAYOUTS))
def test_real_outputs_are_detected_and_read_when_present(fmt):
    """Real files kept outside the repository (``$SMPLIK_REAL_ESTIMATORS/<format>*/``): detected with no
    --format, read at their first frame, every person placed finitely."""
    from smplik.paths import real_estimators_dir
    from workflows.estimators import _load_raw

    root = real_estimators_dir()
    files = sorted({p for d in root.glob(f"{fmt}*") if d.is_dir() for pat in REAL_LAYOUTS[fmt]
                    for p in d.rglob(pat)})[:5]
    if not files:
        pytest.skip(f"no real {fmt} output under {root}/{fmt}*/ (set $SMPLIK_REAL_ESTIMATORS)")
    for path in files:
        data = _load_raw(path, False, 1 << 30)
        assert detect_format(data) == fmt, path
        found = read_estimate(path, frame=_first_frame(data, fmt))
        assert found and all(np.isfinite(p.transl).all() and np.isfinite(p.body_pose).all() for p in found), path


def test_pickled_torch_tensors_are_checked_before_anything_is_allocated(tmp_path):
    """A pickled tensor is rebuilt from its own bytes: a size/stride reaching outside its storage, a size
    beyond the input limits (stride 0) or a storage holding fewer bytes than it declares is refused."""
    import collections
    import warnings

    from smplik.safe_pickle import UnsafePickleError
    from workflows.estimators import _load_raw

    with warnings.catch_warnings():  # TypedStorage's deprecation: the pickle format torch itself writes
        warnings.simplefilter("ignore")
        storage_bytes = torch.arange(4.0).storage().__reduce__()[1][0]

    class Storage:
        def __reduce__(self):
            return (torch.storage._load_from_bytes, (self.data,))

    class Tensor:
        def __init__(self, data, size, stride):
            storage = Storage()
            storage.data = data
            self.args = (storage, 0, size, stride, False, collections.OrderedDict())

        def __reduce__(self):
            return (torch._utils._rebuild_tensor_v2, self.args)

    def read(size, stride, data=storage_bytes):
        path = tmp_path / "x.npy"
        np.save(path, {"t": Tensor(data, size, stride)}, allow_pickle=True)
        return _load_raw(path, False, 1 << 30)["t"]

    np.testing.assert_array_equal(read((2, 2), (1, 2)), [[0.0, 2.0], [1.0, 3.0]])  # a transposed view, copied
    with pytest.raises(UnsafePickleError, match="reaching element 7 of a storage of 4"):
        read((8,), (1,))
    with pytest.raises(UnsafePickleError):
        read((10**10,), (0,))
    with pytest.raises(UnsafePickleError, match="declaring 4 elements but holding 8 bytes"):
        read((2,), (1,), storage_bytes[:-8])
    import joblib  # the same tensors inside a joblib pickle (e.g. a results dict dumped without .numpy())

    joblib.dump({"t": torch.arange(6.0).reshape(2, 3)}, tmp_path / "x.pkl", compress=3)
    np.testing.assert_array_equal(_load_raw(tmp_path / "x.pkl", False, 1 << 30)["t"], np.arange(6.0).reshape(2, 3))


def test_cli_format_choices_are_the_readers():
    from workflows.cli import FORMATS as CLI_FORMATS
    from workflows.estimators import FORMATS

    assert CLI_FORMATS == ("auto", *FORMATS)


def test_from_estimate_reads_tram_and_smplerx_as_a_new_user_would(tmp_path, monkeypatch, best_solver):
    """No options: detected, one character per person, the producer's camera recorded; --format forces;
    a mesh is one line with exit code 1."""
    from estimator_fixtures import write_smplerx, write_tram
    from typer.testing import CliRunner

    import workflows.cli as cli_module
    from workflows.scene import load_scene

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)

    def run(*args):
        return CliRunner().invoke(cli_module.scene_app, ["from-estimate", *map(str, args), "--no-previews",
                                                         "--max-effectors", "3"])

    aa, transl, betas = people(seed=9, n=2, depth=900.0 * 1.7 / 200.0, focal=900.0)
    _, paths = write_tram(tmp_path / "tram", aa, transl, betas)
    result = run(paths[0], "--frame", 1, "--out", tmp_path / "o_tram")
    assert result.exit_code == 0, result.output
    scene = load_scene(tmp_path / "o_tram" / "scene.json")
    assert [c.name for c in scene.characters] == ["person_0", "person_1"]
    assert scene.camera.focal_px == pytest.approx(900.0) and scene.camera.focal_rule == "intrinsics"
    smplerx_paths, _ = write_smplerx(tmp_path / "sx", aa, transl, betas, [(100.0, 80.0, 180.0, 240.0),
                                                                          (380.0, 60.0, 210.0, 280.0)])
    for args in ((), ("--format", "smplerx")):
        result = run(smplerx_paths[0], *args, "--out", tmp_path / f"o_sx{len(args)}")
        assert result.exit_code == 0, result.output
        assert len(load_scene(tmp_path / f"o_sx{len(args)}" / "scene.json").characters) == 2
    result = run(paths[0], "--format", "smplerx", "--out", tmp_path / "o_bad")
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert result.exit_code == 1 and len(lines) == 1 and "SMPLer-X" in lines[0], result.output
    (tmp_path / "m.obj").write_text("v 0 0 0\n")
    result = run(tmp_path / "m.obj", "--out", tmp_path / "o_obj")
    assert result.exit_code == 1 and "no SMPL parameters" in result.output, result.output
