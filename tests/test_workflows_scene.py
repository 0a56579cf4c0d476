"""Editable scene: JSON round trip, validation errors with JSON paths, re-solve to the same pose; CLI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from helpers import demo_scene

from workflows.scene import SceneError, load_scene, save_scene, scene_from_dict, solve_scene


@pytest.fixture(scope="module")
def solver(best_solver):
    return best_solver


@pytest.fixture(scope="module")
def scene(solver):
    return demo_scene(solver)


def _assert_same(a, b, where="scene"):
    """Equal structure and strings; numbers equal to 1e-12 (rotations are re-projected on load)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert abs(a - b) < 1e-12, where
    else:
        assert a == b, where


def test_scene_round_trips_through_json(scene, tmp_path):
    path = save_scene(scene, tmp_path / "scene.json")
    loaded = load_scene(path)
    _assert_same(loaded.to_dict(), json.loads(path.read_text()))
    _assert_same(loaded.to_dict(), scene.to_dict())
    assert [len(c.effectors) for c in loaded.characters] == [4, 4]


def test_scene_re_solves_to_the_same_pose(scene, solver, tmp_path):
    loaded = load_scene(save_scene(scene, tmp_path / "scene.json"))
    solved = solve_scene(loaded, solver)
    for before, after in zip(scene.characters, solved.characters, strict=True):
        np.testing.assert_allclose(after.pose.joints, before.pose.joints, atol=1e-4)
        np.testing.assert_allclose(after.pose.body_pose, before.pose.body_pose, atol=1e-3)


def test_scaled_character_re_solves_in_smpl_space(scene, solver):
    from workflows.scene import scale_effector

    c = scene.characters[0]
    big = dataclasses.replace(c, scale=1.3, effectors=tuple(scale_effector(e, 1.3) for e in c.effectors))
    solved = solve_scene(dataclasses.replace(scene, characters=(big,)), solver).characters[0]
    np.testing.assert_allclose(solved.pose.joints, c.pose.joints, atol=1e-4)


def test_validation_errors_name_the_json_path(scene):
    data = scene.to_dict()
    data["characters"][1]["effectors"][0]["value"] = [1.0, 2.0]
    with pytest.raises(SceneError, match=r"characters\[1\]\.effectors\[0\]\.value"):
        scene_from_dict(data, "s.json")
    data = scene.to_dict()
    data["characters"][0]["betas"] = [0.0] * 3
    with pytest.raises(SceneError, match=r"characters\[0\]\.betas: Wrong number of betas: got 3, need exactly 10"):
        scene_from_dict(data, "s.json")
    data = scene.to_dict()
    data["version"] = 99
    with pytest.raises(SceneError, match="version"):
        scene_from_dict(data, "s.json")
    data = scene.to_dict()
    data["characters"][0]["scale"] = -1
    with pytest.raises(SceneError, match=r"characters\[0\]\.scale"):
        scene_from_dict(data, "s.json")


def test_scene_solve_cli(scene, solver, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    path = save_scene(scene, tmp_path / "scene.json")
    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: solver)
    result = CliRunner().invoke(scene_app, ["solve", str(path), "--out", str(tmp_path / "out.json")])
    assert result.exit_code == 0, result.output
    assert load_scene(tmp_path / "out.json").characters[0].pose is not None
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "smplik-scene", "version": 1, "characters": [{"effectors": 3}]}))
    result = CliRunner().invoke(scene_app, ["solve", str(bad)])
    assert result.exit_code == 1 and "characters[0].effectors" in result.output.replace("\n", "")
