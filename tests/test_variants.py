"""Variants: K alternative poses for one effector set, in the API (IKSolver.sample), ``smplik scene variants`` and
the editor state (generate, preview, keep, undo), on the shipped model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from typer.testing import CliRunner

from smplik.effectors import Effector
from smplik.solver import effector_residuals
from smplik.variants import MIN_DISTANCE_M, farthest_points

# reachable, exact: both hands placed and the pelvis held; the legs, elbows and head are free
EFFECTORS = (Effector.position("left_wrist", (0.5, 1.3, 0.1)), Effector.position("right_wrist", (-0.4, 1.0, 0.3)),
             Effector.position("pelvis", (0.0, 0.95, 0.0)))
MET_MM = 10.0  # what the scene's conflict report counts as met for an exact position effector


def _dicts(effectors) -> list[dict]:
    return [e.to_dict() for e in effectors]


def _mean_joint_distance(a, b) -> float:
    return float(np.linalg.norm(a.joints - b.joints, axis=1).mean())


def test_sample_gives_k_diverse_poses_meeting_the_effectors(shipped_solver):
    solver = shipped_solver
    betas = np.linspace(-1.0, 1.0, 10)
    poses = solver.sample(EFFECTORS, 4, betas=betas, gender="female", seed=0)
    assert len(poses) == 4
    plain = solver.solve(EFFECTORS, betas=betas, gender="female")
    assert np.array_equal(poses[0].joints, plain.joints) and np.array_equal(poses[0].body_pose, plain.body_pose)
    for p in poses:
        assert max(r.value for r in effector_residuals(p, EFFECTORS, solver.bodies)) <= MET_MM
        assert np.allclose(p.betas, betas) and p.gender.value == "female"
    for a in range(4):
        for b in range(a + 1, 4):
            assert _mean_joint_distance(poses[a], poses[b]) >= MIN_DISTANCE_M, (a, b)
    # variants are not tiny: each is several centimetres away from the plain solve on average
    assert min(_mean_joint_distance(p, poses[0]) for p in poses[1:]) > 0.03


def test_sample_is_deterministic_for_a_seed(shipped_solver):
    one = shipped_solver.sample(EFFECTORS, 3, seed=7)
    two = shipped_solver.sample(EFFECTORS, 3, seed=7)
    other = shipped_solver.sample(EFFECTORS, 3, seed=8)
    assert all(np.array_equal(a.joints, b.joints) for a, b in zip(one, two, strict=True))
    assert np.array_equal(one[0].joints, other[0].joints)  # variant 0 is the solve whatever the seed
    assert not np.allclose(one[1].joints, other[1].joints)


def test_variant_effectors_re_solve_to_the_variant(shipped_solver):
    """A variant is persistent: the user's effectors + its guides solve (one pose at a time) to its pose."""
    variants = shipped_solver.sample_variants([e.to_dict() for e in EFFECTORS], 4, seed=1)
    assert variants[0].guides == () and variants[0].distance_m == 0.0
    for v in variants[1:]:
        assert 1 <= len(v.guides) <= 3 and _dicts(v.effectors[:3]) == _dicts(EFFECTORS) \
            and _dicts(v.effectors[3:]) == _dicts(v.guides)
        assert {g.joint for g in v.guides}.isdisjoint({e.joint for e in EFFECTORS})
        again = shipped_solver.solve(v.effectors)
        assert _mean_joint_distance(again, v.pose) < 0.002
        assert v.distance_m == pytest.approx(_mean_joint_distance(v.pose, variants[0].pose))


def test_sample_keeps_joints_above_a_floor(shipped_solver):
    effectors = [Effector.position("left_wrist", (0.3, 0.9, 0.2)), Effector.position("pelvis", (0.0, 0.92, 0.0))]
    floor = float(shipped_solver.solve(effectors).joints[:, 1].min()) - 0.01
    poses = shipped_solver.sample(effectors, 4, seed=0, floor=floor)
    assert len(poses) >= 2
    for p in poses[1:]:
        assert p.joints[:, 1].min() >= floor - 0.02  # the tracking runtime's tolerance below a floor


def test_sample_without_free_joints_gives_only_the_solve(shipped_solver):
    plain = shipped_solver.solve(EFFECTORS)
    names = ("head", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_knee", "right_knee",
             "left_ankle", "right_ankle")
    effectors = [Effector.position(n, plain.joints[Effector.position(n, (0, 0, 0)).joint]) for n in names]
    poses = shipped_solver.sample(effectors, 4)
    assert len(poses) == 1


@pytest.mark.parametrize(("kwargs", "message"), [({"k": 0}, "k must be an integer >= 1"),
                                                 ({"k": 2.5}, "k must be an integer >= 1"),
                                                 ({"seed": -1}, "seed must be an integer >= 0"),
                                                 ({"candidates": 0}, "candidates must be an integer >= 1"),
                                                 ({"floor": float("nan")}, "floor must be a finite height")])
def test_sample_refuses_bad_arguments_in_one_line(shipped_solver, kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        shipped_solver.sample(EFFECTORS, **kwargs)
    assert "\n" not in str(info.value)


def test_farthest_points_picks_far_rows_first_and_stops_at_the_minimum():
    x = np.array([0.0, 1.0, 5.0, 5.01, 2.5])
    d = np.abs(x[:, None] - x[None])
    assert farthest_points(d, 3, 0.1) == [0, 3, 4]
    assert farthest_points(d, 5, 0.1) == [0, 3, 4, 1]  # 5.0 is within 0.1 of 5.01: never picked


# ----------------------------------------------------------------------------- the command


def _scene_file(path):
    from workflows.editor.state import fresh_scene
    from workflows.scene import save_scene

    scene = fresh_scene()
    c = dataclasses.replace(scene.characters[0], effectors=EFFECTORS, scale=1.1)
    return save_scene(dataclasses.replace(scene, characters=(c,)), path)


def test_scene_variants_writes_k_loadable_scenes_that_re_solve(shipped_solver, tmp_path):
    from smplik.cli.main import app
    from workflows.scene import load_scene, scale_effector, solve_scene

    scene = _scene_file(tmp_path / "scene.json")
    res = CliRunner().invoke(app, ["scene", "variants", str(scene), "--k", "3", "--out", str(tmp_path / "v")])
    assert res.exit_code == 0, res.output
    lines = [line for line in res.output.splitlines() if line.startswith("wrote")]
    assert len(lines) == 3
    joints = []
    for i in range(3):
        loaded = load_scene(tmp_path / "v" / f"variant_{i}.json")
        c = loaded.characters[0]
        assert _dicts(c.effectors[:3]) == _dicts(EFFECTORS) and c.pose is not None
        assert (len(c.effectors) == 3) == (i == 0)
        again = solve_scene(loaded, shipped_solver).characters[0]
        user = [scale_effector(e, 1.0 / c.scale) for e in EFFECTORS]
        assert max(r.value for r in effector_residuals(again.pose, user, shipped_solver.bodies)) <= MET_MM
        assert _mean_joint_distance(again.pose, c.pose) < 0.002
        joints.append(c.pose.joints)
    assert min(np.linalg.norm(joints[a] - joints[b], axis=1).mean() for a, b in ((0, 1), (0, 2), (1, 2))) \
        >= MIN_DISTANCE_M


def test_scene_variants_errors_are_one_line(shipped_solver, tmp_path):
    from smplik.cli.main import app

    scene = _scene_file(tmp_path / "scene.json")
    res = CliRunner().invoke(app, ["scene", "variants", str(scene), "--character", "bob", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "no character named 'bob'; the scene has body" in res.output
    assert len(res.output.strip().splitlines()) == 1
    (tmp_path / "file").write_text("x")
    res = CliRunner().invoke(app, ["scene", "variants", str(scene), "--out", str(tmp_path / "file")])
    assert res.exit_code == 1 and "exists and is not a folder" in res.output


# ----------------------------------------------------------------------------- the editor


@pytest.fixture()
def state(shipped_solver, tmp_path):
    from workflows.editor.state import EditorState

    st = EditorState.open(_scene_file(tmp_path / "scene.json"), shipped_solver)
    st._edit(st.character())  # solve the stored effectors (the file has no pose yet)
    st._undo.clear()
    return st


def test_editor_generate_preview_keep_and_undo(state, tmp_path):
    from workflows.editor.state import EditorError
    from workflows.scene import load_scene

    base = state.view().joints.copy()
    assert state.generate_variants(4) == 4 and state.variant_index == 0 and not state.can_undo
    assert np.allclose(state.view().joints, base)
    state.preview_variant(2)
    shown = state.view().joints.copy()
    assert np.linalg.norm(shown - base, axis=1).mean() >= MIN_DISTANCE_M * state.character().scale
    assert len(state.character().effectors) == 3  # previewing is no edit
    with pytest.raises(EditorError, match="No variant 4: there are 4"):
        state.preview_variant(4)
    guides = state.variants[2].guides
    assert state.keep_variant() == len(guides)
    c = state.character()
    assert len(c.effectors) == 3 + len(guides) and _dicts(c.effectors[:3]) == _dicts(EFFECTORS)
    assert state.variants == () and state.variant_index == 0  # the edit dropped them
    assert np.linalg.norm(state.view().joints - shown, axis=1).mean() < 0.003  # the kept pose is the one shown
    saved = load_scene(state.save(tmp_path / "kept.json"))
    assert len(saved.characters[0].effectors) == 3 + len(guides)
    assert state.undo()
    assert _dicts(state.character().effectors) == _dicts(EFFECTORS)
    assert np.allclose(state.view().joints, base)


def test_editor_variants_drop_on_edit_and_variant_0_keeps_nothing(state):
    from workflows.editor.state import EditorError

    with pytest.raises(EditorError, match="generate them first"):
        state.preview_variant(0)
    state.generate_variants(3)
    assert state.keep_variant(0) == 0 and not state.can_undo
    state.generate_variants(3)
    state.preview_variant(1)
    state.set_tolerance(0.2, 0)
    assert state.variants == () and state.variant_index == 0


def test_editor_app_wires_the_variants_control(state):
    pytest.importorskip("viser")
    from workflows.editor.app import NO_VARIANT, EditorApp

    app = EditorApp(state, host="127.0.0.1", port=0)
    try:
        assert app.keep_variant_button.disabled
        before = np.asarray(app._meshes[0].vertices).copy()
        app._run(app._generate_variants)
        assert len(app.variant_dropdown.options) == 4 and not app.keep_variant_button.disabled
        app._run(lambda: state.preview_variant(3))
        assert app.variant_dropdown.value.startswith("3: ")
        assert np.allclose(np.asarray(app._meshes[0].vertices), state.view().vertices)
        assert np.abs(np.asarray(app._meshes[0].vertices) - before).max() > 0.02
        app._run(app._keep_variant)
        assert len(state.character().effectors) > 3 and tuple(app.variant_dropdown.options) == (NO_VARIANT,)
    finally:
        app.stop()


def test_scene_variants_says_when_fewer_than_k_exist(shipped_solver, tmp_path):
    """Every guide joint constrained: only the plain solve, and a notice saying so."""
    from smplik.cli.main import app
    from workflows.editor.state import fresh_scene
    from workflows.scene import save_scene

    plain = shipped_solver.solve(EFFECTORS)
    names = ("head", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_knee", "right_knee",
             "left_ankle", "right_ankle")
    effectors = tuple(Effector.position(n, plain.joints[Effector.position(n, (0, 0, 0)).joint]) for n in names)
    scene = fresh_scene()
    scene = dataclasses.replace(scene, characters=(dataclasses.replace(scene.characters[0], effectors=effectors),))
    path = save_scene(scene, tmp_path / "scene.json")
    res = CliRunner().invoke(app, ["scene", "variants", str(path), "--out", str(tmp_path / "v")])
    assert res.exit_code == 0, res.output
    assert "room for only 1 distinct plausible variant(s) of 4" in res.output
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["variant_0.json"]
