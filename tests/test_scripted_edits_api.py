"""Scripted edits from Python (workflows.scene.edits: solve_scripted, solve_scene_edits, drag_scene_effector;
Scene.drag) and the keyframe merge (workflows.animation.keyframe_edit.merge_effectors). The journeys through the
commands are in tests/journeys/test_scripted_edits.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import demo_scene

from smplik.conventions import JOINT_INDEX
from smplik.effectors import Effector, EffectorError
from workflows.animation.keyframe_edit import merge_effectors
from workflows.scene import SceneError, character_joints
from workflows.scene.edits import RELAXED_TOLERANCE, drag_scene_effector, solve_scene_edits

UP = np.array([0.0, 0.25, 0.0])


@pytest.fixture(scope="module")
def scene(shipped_solver):
    """The demo's two people, recovered (4 effectors each) as ``scene from-estimate`` does."""
    return demo_scene(shipped_solver)


def _rel(J: np.ndarray, joint: str) -> np.ndarray:
    return J[JOINT_INDEX[joint]] - J[0]


def test_merge_replaces_named_joints_and_keeps_the_others():
    a = Effector.position("left_wrist", (0.1, 1.0, 0.0))
    b = Effector.rotation("left_elbow", np.eye(3))
    c = Effector.position("right_ankle", (0.1, 0.1, 0.0))
    new_a = Effector.position("left_wrist", (0.1, 1.3, 0.0))
    head = Effector.look_at("head", (0.0, 1.6, 2.0))
    merged, given, replaced = merge_effectors((a, b, c), (new_a, head))
    assert merged == (b, c, new_a, head) and given == (2, 3) and replaced == 1
    merged, given, replaced = merge_effectors((), (new_a,))  # a frame that is no keyframe
    assert merged == (new_a,) and given == (0,) and replaced == 0
    # a rotation on the wrist does not replace its position (joint and type name an effector)
    merged, _, replaced = merge_effectors((a, b), (Effector.rotation("left_wrist", np.eye(3)),))
    assert merged[:2] == (a, b) and replaced == 0


def test_both_wrists_moved_at_once_are_solved_one_drag_after_the_other(scene, shipped_solver):
    c = scene.characters[0]
    J0 = character_joints(c)
    targets = [Effector.position(w, J0[JOINT_INDEX[w]] + UP) for w in ("left_wrist", "right_wrist")]
    kept = [e for e in c.effectors if not any(e.joint == t.joint and e.type == t.type for t in targets)]
    edited = dataclasses.replace(scene, characters=(dataclasses.replace(c, effectors=(*kept, *targets)),
                                                    *scene.characters[1:]))
    solved, reports = solve_scene_edits(edited, shipped_solver)
    J1 = character_joints(solved.characters[0])
    for t in targets:
        assert np.linalg.norm(J1[t.joint] - t.value) < 0.01
    assert np.linalg.norm(_rel(J1, "head") - _rel(J0, "head")) < 0.02
    assert [reports[0].effectors[i].joint_name for i in reports[0].moved] == ["left_wrist", "right_wrist"]
    assert reports[0].mode == "drag" and reports[1].mode == "kept"
    np.testing.assert_array_equal(solved.characters[1].pose.body_pose, scene.characters[1].pose.body_pose)
    # solving the result again changes nothing: every effector it holds exactly is met
    again, reports = solve_scene_edits(solved, shipped_solver)
    assert [r.mode for r in reports] == ["kept", "kept"]
    np.testing.assert_array_equal(again.characters[0].pose.body_pose, solved.characters[0].pose.body_pose)
    # --exact re-solves everything from scratch and relaxes nothing
    exact, reports = solve_scene_edits(edited, shipped_solver, exact=True)
    assert [r.mode for r in reports] == ["exact", "exact"] and all(not r.relaxed for r in reports)
    assert [e.tolerance for e in exact.characters[0].effectors] == [e.tolerance for e in edited.characters[0].effectors]


def test_scene_drag_moves_the_joint_and_relaxes_its_chain(scene, shipped_solver):
    c = scene.characters[1]
    J0 = character_joints(c)
    raised = scene.drag(c.name, "left_wrist", offset=UP, solver=shipped_solver)
    J1 = character_joints(raised.characters[1])
    assert np.linalg.norm(J1[JOINT_INDEX["left_wrist"]] - J0[JOINT_INDEX["left_wrist"]] - UP) < 0.01
    for joint in ("head", "right_wrist", "left_ankle", "right_ankle"):
        assert np.linalg.norm(_rel(J1, joint) - _rel(J0, joint)) < 0.02, joint
    assert raised.characters[0] is scene.characters[0]
    edited, report = drag_scene_effector(scene, c.name, "left_wrist", position=J0[JOINT_INDEX["left_wrist"]] + UP,
                                         solver=shipped_solver)
    np.testing.assert_allclose(character_joints(edited.characters[1]), J1, atol=1e-6)  # position= is the same drag
    for i in report.relaxed:  # the relaxed ones are stored relaxed and named in the line
        assert edited.characters[1].effectors[i].tolerance == RELAXED_TOLERANCE
        assert edited.characters[1].effectors[i].joint_name in report.line()
    assert report.line().startswith(f"{c.name}: moved left_wrist position (250 mm from the stored pose)")


def test_scene_drag_of_a_rotation(scene, shipped_solver):
    import torch

    from smplik.rotations import axis_angle_to_matrix
    from workflows.scene.recovery import TargetPose

    c = scene.characters[0]
    before = TargetPose.from_pose(dataclasses.replace(c.pose, joints=None))
    turn = axis_angle_to_matrix(torch.tensor([0.0, 0.5, 0.0], dtype=torch.float64)).numpy()
    R_target = turn @ before.R_world[JOINT_INDEX["head"]].double().numpy()
    edited = scene.drag(c.name, "head", rotation=R_target, solver=shipped_solver)
    after = TargetPose.from_pose(dataclasses.replace(edited.characters[0].pose, joints=None))
    R = after.R_world[JOINT_INDEX["head"]].double().numpy()
    angle = np.degrees(np.arccos(np.clip((np.trace(R @ R_target.T) - 1) / 2, -1, 1)))
    assert angle < 5.0
    p0, p1 = before.p_world.double().numpy(), after.p_world.double().numpy()
    assert np.linalg.norm(p1[0] - p0[0]) < 0.02  # a head turn does not move the pelvis


def test_scene_drag_errors_name_the_problem(scene):
    with pytest.raises(SceneError, match=r"no character 'nobody' in the scene \(characters: person_0, person_1\)"):
        scene.drag("nobody", "left_wrist", offset=UP)
    with pytest.raises(SceneError, match="exactly one of position=, offset= or rotation="):
        scene.drag("person_0", "left_wrist", offset=UP, position=(0, 1, 0))
    with pytest.raises(SceneError, match="exactly one of"):
        scene.drag("person_0", "left_wrist")
    with pytest.raises(EffectorError, match="left_wirst"):
        scene.drag("person_0", "left_wirst", position=(0, 1, 0))
    bare = dataclasses.replace(scene, characters=(dataclasses.replace(scene.characters[0], pose=None),))
    with pytest.raises(SceneError, match="person_0: has no solved pose to move a joint from"):
        bare.drag("person_0", "left_wrist", offset=UP)
