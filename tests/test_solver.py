"""IKSolver API, validation messages, smplx agreement, effector files and the `smplik solve` CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from smplik.conventions import Gender
from smplik.effector_schema import (
    EFFECTORS_FORMAT,
    EffectorFile,
    json_schema,
    load_effector_file,
    parse_effector_document,
    save_effector_file,
)
from smplik.effectors import Effector, pack_effectors
from smplik.pose import Pose
from smplik.refine import RefineConfig
from smplik.solver import IKSolver, packaged_model_path


@pytest.fixture(scope="module")
def model_path(tiny_model):
    return tiny_model


@pytest.fixture(scope="module")
def solver(model_path):
    return IKSolver.load(model_path)


EFFECTOR_DICTS = [
    {"joint": "left_wrist", "type": "position", "value": [0.5, 1.2, 0.1], "tolerance": 0.0},
    {"joint": "right_ankle", "type": "position", "value": [-0.1, 0.05, 0.0]},
    {"joint": "pelvis", "type": "rotation", "value": [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]},
    {"joint": "head", "type": "look_at", "target": [0.0, 1.6, 2.0], "direction": [0, 0, 1], "tolerance": 0.5},
]


def effector_objects():
    return [Effector.from_dict(d) for d in EFFECTOR_DICTS]


# ----------------------------------------------------------------------------- loading


def test_load_missing_and_non_model_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        IKSolver.load(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    torch.save({"hello": 1}, bad)
    with pytest.raises(ValueError, match="not an smplik model"):
        IKSolver.load(bad)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="not a readable smplik model"):
        IKSolver.load(junk)


def test_default_model_is_the_packaged_file(monkeypatch, tmp_path, model_path, solver):
    """Without a path, load() reads packaged_model_path(); when that file is missing it says so."""
    import smplik.solver as solver_module

    assert packaged_model_path().name == "smplik_cmu.pt" and packaged_model_path().parent.name == "checkpoints"
    monkeypatch.setattr(solver_module, "packaged_model_path", lambda: model_path)
    default = IKSolver.load()
    assert default.source == str(model_path)
    eff = [Effector.position("left_wrist", [0.4, 1.1, 0.2]), Effector.position("pelvis", [0.0, 0.9, 0.0])]
    np.testing.assert_array_equal(default.solve(eff).joints, solver.solve(eff).joints)
    monkeypatch.setattr(solver_module, "packaged_model_path", lambda: tmp_path / "absent.pt")
    with pytest.raises(FileNotFoundError, match=f"No packaged model at {tmp_path / 'absent.pt'}"):
        IKSolver.load()


def test_fingerprint_mismatch_warns(tmp_path, bodies, model_path):
    """A file trained on other body models (another fingerprint and other rest skeletons) warns; one whose
    fingerprint differs but whose skeletons are those in use (a file from before the grid hashing) does not."""
    import warnings

    state = torch.load(model_path, weights_only=True)
    state["body_fingerprint"] = "0123456789abcdef"
    same = tmp_path / "same_skeletons.pt"
    torch.save(state, same)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        IKSolver.load(same, runtime="torch")
    state["model"]["J_template"] = state["model"]["J_template"] + 0.01  # 1 cm: other bodies
    other = tmp_path / "other.pt"
    torch.save(state, other)
    with pytest.warns(UserWarning, match="fingerprint 0123456789abcdef"):
        IKSolver.load(other, runtime="torch")


# ----------------------------------------------------------------------------- validation


@pytest.mark.parametrize(("effectors", "kwargs", "message"), [
    ([{"joint": "left_wirst", "type": "position", "value": [0, 0, 0]}], {},
         r"effectors\[0\].joint: unknown joint 'left_wirst' \(did you mean 'left_wrist'\?\); valid names"),
    ([{"joint": "head", "type": "position", "value": [0, float("nan"), 0]}], {}, "NaN or inf"),
    ([{"joint": "head", "type": "position", "value": [0, float("inf"), 0]}], {}, "NaN or inf"),
    ([{"joint": "head", "type": "position", "value": [0, 0]}], {}, r"shape \(2,\); expected \(3,\)"),
    ([{"joint": "head", "type": "position", "value": [0, 0, 0], "tolerance": 1.5}], {}, r"outside \[0, 1\]"),
    ([{"joint": "head", "type": "position", "value": [0, 0, 0], "tolerance": -0.1}], {}, r"outside \[0, 1\]"),
    ([{"joint": "head", "type": "rotation", "value": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}], {}, "not a rotation matrix"),
    ([{"joint": "head", "type": "rotation", "value": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}], {}, "not a rotation matrix"),
    ([{"joint": "head", "type": "look_at", "target": [0, 1, 1], "direction": [0, 0, 0]}], {}, "zero vector"),
    ([{"joint": "head", "type": "wiggle", "value": [0, 0, 0]}], {},
         "type: must be one of position, rotation, look_at, got \"wiggle\""),
    (EFFECTOR_DICTS, {"betas": np.zeros(9)}, "Wrong number of betas: got 9, need exactly 10"),
    (EFFECTOR_DICTS, {"betas": np.zeros(11)}, "Wrong number of betas: got 11"),
    (EFFECTOR_DICTS, {"betas": [0.0] * 9 + [float("nan")]}, "betas: contains NaN"),
    (EFFECTOR_DICTS, {"gender": "robot"}, "Unknown gender 'robot'; expected one of: neutral, male, female"),
    ([], {}, "effector list is empty"),
    ([42], {}, r"effectors\[0\]: expected an Effector or a dict"),
])
def test_bad_inputs_raise_named_errors(solver, effectors, kwargs, message):
    with pytest.raises(ValueError, match=message):
        solver.solve(effectors, **kwargs)


def test_effector_index_is_named_for_dicts(solver):
    bad = EFFECTOR_DICTS[:2] + [{"joint": "head", "type": "position", "value": [0, 0]}]
    with pytest.raises(ValueError, match=r"effectors\[2\]"):
        solver.solve(bad)


def test_batch_validation(solver):
    with pytest.raises(ValueError, match=r"betas: has shape \(3, 10\); expected \(10,\) or \(2, 10\)"):
        solver.solve_batch([EFFECTOR_DICTS, EFFECTOR_DICTS], betas=np.zeros((3, 10)))
    with pytest.raises(ValueError, match="gender has 1 entries for 2 poses"):
        solver.solve_batch([EFFECTOR_DICTS, EFFECTOR_DICTS], gender=["male"])
    with pytest.raises(ValueError, match="pose 1: The effector list is empty"):
        solver.solve_batch([EFFECTOR_DICTS, []])
    with pytest.raises(ValueError, match="effector_lists is empty"):
        solver.solve_batch([])


# ----------------------------------------------------------------------------- results


def test_dicts_and_effectors_give_identical_results(solver):
    betas = np.linspace(-1, 1, 10)
    a = solver.solve(EFFECTOR_DICTS, betas=betas, gender="female")
    b = solver.solve(effector_objects(), betas=betas, gender=Gender.FEMALE)
    for key in ("global_orient", "body_pose", "transl", "betas", "joints"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    assert a.gender == b.gender == Gender.FEMALE
    assert a.body_pose.shape == (23, 3) and a.joints.shape == (24, 3)


def test_pack_effectors_packs_data6_and_pads_with_a_mask():
    rows = [effector_objects(), effector_objects()[:2]]
    packed = pack_effectors(rows)
    assert packed.shape == (2, len(rows[0]))
    for b, row in enumerate(rows):
        assert packed.mask[b].tolist() == [True] * len(row) + [False] * (len(rows[0]) - len(row))
        for i, e in enumerate(row):
            assert int(packed.joint[b, i]) == e.joint and int(packed.type[b, i]) == int(e.type)
            np.testing.assert_allclose(packed.data[b, i].numpy(), e.data6(), atol=1e-6)
            assert float(packed.tolerance[b, i]) == pytest.approx(e.tolerance)


def test_batch_equals_single(solver):
    lists = [EFFECTOR_DICTS, EFFECTOR_DICTS[:2], EFFECTOR_DICTS[1:]]
    betas = np.random.default_rng(0).normal(size=(3, 10))
    genders = ["neutral", "male", "female"]
    batch = solver.solve_batch(lists, betas=betas, gender=genders)
    for effs, b, g, pose in zip(lists, betas, genders, batch, strict=True):
        single = solver.solve(effs, betas=b, gender=g)
        np.testing.assert_allclose(pose.joints, single.joints, atol=1e-5)
        np.testing.assert_allclose(pose.body_pose, single.body_pose, atol=1e-4)
        assert pose.gender == single.gender


def test_solve_tensors_runs_in_inference_mode(solver):
    eff = pack_effectors([effector_objects()])
    out = solver.solve_tensors(eff, torch.zeros(1, 10), torch.zeros(1, dtype=torch.long))
    assert out.p_world.is_inference() and out.R_local.shape == (1, 24, 3, 3)


@pytest.mark.parametrize("gender", ["male", "female"])
def test_joints_equal_plain_smplx_on_exported_model(tmp_path, solver, gender):
    import smplx
    from smplx.vertex_ids import vertex_ids

    from smplik.cli.main import app

    out = tmp_path / f"SMPL_{gender.upper()}.npz"
    res = CliRunner().invoke(app, ["body", "export", "--gender", gender, "--out", str(out)])
    assert res.exit_code == 0, res.output
    layer = smplx.SMPL(model_path="", data_struct=smplx.utils.Struct(**dict(np.load(out))),
                       vertex_ids={k: 0 for k in vertex_ids["smplh"]}, use_hands=False, use_feet_keypoints=False)
    pose = solver.solve(EFFECTOR_DICTS, betas=np.random.default_rng(3).normal(size=10), gender=gender)
    joints = layer(**pose.to_smplx_kwargs()).joints[0, :24].detach().numpy()
    np.testing.assert_allclose(pose.joints, joints, atol=2e-5)


# ----------------------------------------------------------------------------- effector files


def test_schema_round_trip(tmp_path):
    path = tmp_path / "e.json"
    save_effector_file(path, effector_objects(), betas=np.arange(10) / 10, gender="male")
    data = json.loads(path.read_text())
    assert data["format"] == EFFECTORS_FORMAT and data["version"] == 1
    doc = load_effector_file(path)
    assert doc.gender == Gender.MALE and np.allclose(doc.betas, np.arange(10) / 10)
    assert [e.to_dict() for e in doc.effectors] == [e.to_dict() for e in effector_objects()]
    again = parse_effector_document(doc.to_dict())
    assert [e.to_dict() for e in again.effectors] == [e.to_dict() for e in doc.effectors]


def test_minimal_document_defaults():
    doc = parse_effector_document({"effectors": [{"joint": "head", "type": "position", "value": [0, 1.6, 0]}]})
    assert doc == EffectorFile(doc.effectors, None, None)
    assert doc.effectors[0].tolerance == 0.0
    bare = parse_effector_document([{"joint": "head", "type": "look_at", "target": [0, 1.6, 1]}])
    np.testing.assert_array_equal(bare.effectors[0].direction, [0, 0, 1])


@pytest.mark.parametrize(("doc", "message"), [
    ({"effectors": EFFECTOR_DICTS[:2] + [{"joint": "head", "type": "position", "value": [1, 2]}]},
     r"effectors\[2\]\.value: has shape \(2,\)"),
    ({"effectors": [{"joint": "nose", "type": "position", "value": [1, 2, 3]}]}, r"effectors\[0\]\.joint: unknown"),
    ({"effectors": [{"joint": "head", "type": "spin", "value": [1, 2, 3]}]}, r"effectors\[0\]\.type"),
    ({"effectors": [{"joint": "head", "type": "position", "value": [1, 2, 3], "tolerance": 2}]},
     r"effectors\[0\]\.tolerance: 2 is outside"),
    ({"effectors": [{"joint": "head", "type": "position", "value": [1, 2, 3], "color": 1}]},
     r"effectors\[0\]: unknown key\(s\) \['color'\]"),
    ({"effectors": [{"joint": "head", "type": "rotation", "value": [[1, 0, 0], [0, 1, 0], [0, 1, 0]]}]},
     r"effectors\[0\]\.value: value is not a rotation matrix"),
    ({"effectors": [{"joint": "head", "type": "look_at", "target": [1, 2, 3], "direction": [0, 0, 0]}]},
     r"effectors\[0\]\.direction: look-at direction is the zero vector"),
    ({"effectors": [{"joint": "head", "type": "look_at", "value": [1, 2, 3]}]}, r"effectors\[0\]: unknown key"),
    ({"betas": [0] * 9, "effectors": EFFECTOR_DICTS}, "betas: has 9 values; expected exactly 10"),
    ({"gender": "x", "effectors": EFFECTOR_DICTS}, "gender: unknown gender 'x'"),
    ({"version": 2, "effectors": EFFECTOR_DICTS}, "version: unsupported version 2"),
    ({"format": "other", "effectors": EFFECTOR_DICTS}, "format: expected 'smplik-effectors'"),
    ({"effectors": []}, "effectors: is empty"),
    ({"effector": []}, r"unknown key\(s\) \['effector'\]"),
    ({"effectors": EFFECTOR_DICTS[:1] * 2}, r"effectors\[1\]: duplicate position effector on 'left_wrist'"),
])
def test_schema_errors_name_file_and_json_path(tmp_path, doc, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as info:
        load_effector_file(path)
    assert str(info.value).startswith(f"{path}: ")


def test_invalid_json_and_missing_file(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text("{ not json")
    with pytest.raises(ValueError, match=f"{path}: invalid JSON"):
        load_effector_file(path)
    with pytest.raises(ValueError, match="Effector file not found"):
        load_effector_file(tmp_path / "none.json")


def test_docs_schema_file_is_current():
    from pathlib import Path

    doc = Path(__file__).resolve().parents[1] / "docs" / "effectors.schema.json"
    assert json.loads(doc.read_text()) == json_schema(), "regenerate docs/effectors.schema.json from json_schema()"


def test_schema_validates_example_when_jsonschema_is_installed():
    jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is not installed (pip install -e '.[dev]')")
    doc = {"format": "smplik-effectors", "version": 1, "betas": [0.0] * 10, "gender": "female",
           "effectors": EFFECTOR_DICTS}
    jsonschema.validate(doc, json_schema())


# ----------------------------------------------------------------------------- CLI


@pytest.fixture(scope="module")
def cli():
    from smplik.cli import solve as solver_cli

    root = typer.Typer()
    root.command("solve")(solver_cli.solve_command)
    root.command("noop")(lambda: None)  # two commands keep typer from collapsing the group
    return root


def test_cli_solve_writes_pose(tmp_path, cli, model_path, solver):
    eff = tmp_path / "effectors.json"
    save_effector_file(eff, effector_objects(), betas=np.full(10, 0.5), gender="female")
    out = tmp_path / "pose.json"
    res = CliRunner().invoke(cli, ["solve", str(eff), "--checkpoint", str(model_path), "--out", str(out)])
    assert res.exit_code == 0, res.output
    pose = Pose.load(out)
    assert pose.gender == Gender.FEMALE and np.allclose(pose.betas, 0.5)
    expected = solver.solve(effector_objects(), betas=np.full(10, 0.5), gender="female")
    np.testing.assert_allclose(pose.joints, expected.joints, atol=1e-9)
    res = CliRunner().invoke(cli, ["solve", str(eff), "--checkpoint", str(model_path), "--out", str(out),
                                   "--gender", "male", "--betas", "1,2"])
    assert res.exit_code == 0, res.output
    pose = Pose.load(out)
    assert pose.gender == Gender.MALE and list(pose.betas[:3]) == [1.0, 2.0, 0.0]
    res = CliRunner().invoke(cli, ["solve", str(eff), "--checkpoint", str(model_path), "--out", str(out),
                                   "--refine-steps", "0"])
    assert res.exit_code == 0, res.output
    network_only = IKSolver.load(model_path, refine=RefineConfig(iterations=0))
    expected_raw = network_only.solve(effector_objects(), betas=np.full(10, 0.5), gender="female")
    np.testing.assert_allclose(Pose.load(out).joints, expected_raw.joints, atol=1e-9)
    assert np.abs(expected_raw.joints - expected.joints).max() > 1e-3  # the refinement did move the pose


def test_cli_solve_reports_file_errors(tmp_path, cli, model_path):
    eff = tmp_path / "bad.json"
    eff.write_text(json.dumps({"effectors": [{"joint": "head", "type": "position", "value": [1, 2]}]}))
    res = CliRunner().invoke(cli, ["solve", str(eff), "--checkpoint", str(model_path), "--out",
                                   str(tmp_path / "p.json")])
    assert res.exit_code == 1
    assert "effectors[0].value" in res.output and "bad.json" in res.output
    res = CliRunner().invoke(cli, ["solve", str(eff), "--checkpoint", str(tmp_path / "missing.pt"), "--out",
                                   str(tmp_path / "p.json")])
    assert res.exit_code == 1


def test_numpy_axis_angle_matches_scipy():
    from scipy.spatial.transform import Rotation

    from smplik.rotations import matrix_to_axis_angle_np

    rng = np.random.default_rng(0)
    rv = rng.normal(size=(500, 3))
    rv = rv / np.linalg.norm(rv, axis=-1, keepdims=True) * rng.uniform(0, np.pi, size=(500, 1))
    rv[:5] = [[0, 0, 0], [1e-9, 0, 0], [np.pi, 0, 0], [0, np.pi - 1e-7, 0], [0, 0, 1e-4]]
    R = Rotation.from_rotvec(rv).as_matrix()
    out = matrix_to_axis_angle_np(R)
    np.testing.assert_allclose(Rotation.from_rotvec(out).as_matrix(), R, atol=1e-9)
    np.testing.assert_allclose(out[5:], rv[5:], atol=1e-9)
    assert matrix_to_axis_angle_np(R.reshape(10, 50, 3, 3)).shape == (10, 50, 3)
    # both branches (the trace/vee formula up to 120 degrees, Shepperd's beyond) agree with Shepperd's
    from smplik.rotations import _axis_angle_shepperd

    angle = np.linalg.norm(rv, axis=-1)
    assert (angle < 2.0).sum() > 100 and (angle > 2.2).sum() > 100
    below_pi = angle < np.pi - 1e-3
    np.testing.assert_allclose(out[below_pi], _axis_angle_shepperd(R[below_pi]), atol=1e-12)
