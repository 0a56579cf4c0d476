"""Drags that do not fight the user (workflows.scene.edits): the stale-effector rule, the conflict report, and a
drag on a recovered-style scene that must not contort the torso."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from smplik.conventions import JOINT_INDEX, NUM_BETAS, PARENTS, Gender
from smplik.effectors import Effector
from smplik.pose import Pose
from smplik.rotations import geodesic_distance
from workflows.editor.state import EditorState
from workflows.scene import Scene, SceneCharacter, solve_character
from workflows.scene.edits import RELAXED_TOLERANCE, conflict_report, drag_effector, relax_stale, stale_effectors
from workflows.scene.recovery import TargetPose

TORSO = [JOINT_INDEX[n] for n in ("spine1", "spine2", "spine3", "neck", "head")]


@pytest.fixture(scope="module")
def solver(shipped_solver):

    return shipped_solver  # the shipped model


def _eff(joint: str, kind: str) -> Effector:
    if kind == "position":
        return Effector.position(joint, (0.1, 1.0, 0.0))
    if kind == "rotation":
        return Effector.rotation(joint, np.eye(3))
    return Effector.look_at(joint, (0.0, 1.5, 1.0), (0.0, 0.0, 1.0))


def test_stale_effectors_follow_the_chain():
    effs = [_eff("left_wrist", "position"), _eff("left_elbow", "rotation"), _eff("left_shoulder", "rotation"),
            _eff("left_hand", "position"), _eff("left_elbow", "position"), _eff("left_wrist", "rotation"),
            _eff("spine3", "rotation"), _eff("right_wrist", "position"), _eff("left_collar", "rotation"),
            _eff("head", "look_at"), _eff("head", "rotation")]
    # a moved wrist position: every other effector of the arm (its own rotation included: the hand follows the
    # forearm, as in real reaches)
    assert stale_effectors(effs, 0) == (1, 2, 3, 4, 5, 8)
    # two position handles on one wrist: moving one makes the other stale
    assert stale_effectors(effs + [_eff("left_wrist", "position")], 0) == (1, 2, 3, 4, 5, 8, 11)
    # a moved elbow rotation: the positions below it in the arm
    assert stale_effectors(effs, 1) == (0, 3)
    # a moved look-at on the head: the head's own rotation
    assert stale_effectors(effs, 9) == (10,)
    relaxed, idx = relax_stale(effs, 0)
    assert idx == (1, 2, 3, 4, 5, 8)
    assert [e.tolerance for e in relaxed] == [RELAXED_TOLERANCE if i in idx else 0.0 for i in range(len(effs))]
    dropped, idx = relax_stale(effs, 0, tolerance=None)
    assert len(dropped) == len(effs) - 6 and dropped[0] is effs[0]


def test_drag_effector_replaces_or_appends():
    effs = (_eff("left_elbow", "rotation"), _eff("left_wrist", "position"), _eff("pelvis", "position"))
    new = Effector.position("left_wrist", (0.3, 1.4, 0.0))
    out, k, relaxed = drag_effector(effs, new)
    assert k == 1 and out[1] is new and relaxed == (0,) and out[0].tolerance == RELAXED_TOLERANCE
    out, k, relaxed = drag_effector(effs, Effector.position("right_wrist", (0.3, 1.4, 0.0)))
    assert k == 3 and len(out) == 4 and relaxed == ()
    out, k, relaxed = drag_effector(effs, new, tolerance=None)
    assert [e.joint_name for e in out] == ["left_wrist", "pelvis"] and k == 0 and relaxed == (0,)


def _arms_down_pose() -> Pose:
    body = np.zeros((23, 3))
    body[JOINT_INDEX["left_shoulder"] - 1] = (0.0, 0.0, -1.2)   # arms down along the body
    body[JOINT_INDEX["right_shoulder"] - 1] = (0.0, 0.0, 1.2)
    body[JOINT_INDEX["left_elbow"] - 1] = (0.0, -0.4, 0.0)
    body[JOINT_INDEX["right_elbow"] - 1] = (0.0, 0.4, 0.0)
    return Pose(np.zeros(3), body, np.zeros(3), np.zeros(NUM_BETAS), Gender.NEUTRAL)


def _recovered_style_character(solver) -> SceneCharacter:
    """Exact effectors of a standing pose, as recovery leaves them: one arm has its wrist free but its elbow
    rotation pinned (the issue's scene: left_elbow rotation + a new left_wrist handle)."""
    fk = TargetPose.from_pose(_arms_down_pose())
    p, R = fk.p_world.double().numpy(), fk.R_world.double().numpy()
    effs = (Effector.position("left_hip", p[JOINT_INDEX["left_hip"]]),
            Effector.rotation("left_elbow", R[JOINT_INDEX["left_elbow"]]),
            Effector.rotation("left_knee", R[JOINT_INDEX["left_knee"]]),
            Effector.position("right_ankle", p[JOINT_INDEX["right_ankle"]]),
            Effector.rotation("pelvis", R[0]),
            Effector.position("right_wrist", p[JOINT_INDEX["right_wrist"]]),
            Effector.position("head", p[JOINT_INDEX["head"]]))
    return solve_character(SceneCharacter("person", Gender.NEUTRAL, np.zeros(NUM_BETAS), effectors=effs), solver)


def _torso_turn_deg(before: SceneCharacter, after: SceneCharacter) -> np.ndarray:
    R0 = TargetPose.from_pose(dataclasses.replace(before.pose, joints=None)).R_world
    R1 = TargetPose.from_pose(dataclasses.replace(after.pose, joints=None)).R_world
    return np.degrees(geodesic_distance(R0[TORSO].double(), R1[TORSO].double()).numpy())


def test_a_raised_wrist_does_not_contort_the_torso(solver):
    """The issue's edit: a new left-wrist handle dragged up 40 cm on a scene whose left elbow rotation is
    pinned. The torso and head must stay within a few degrees, the wrist must reach its target, and the
    editor must say which effector it relaxed."""
    character = _recovered_style_character(solver)
    state = EditorState(Scene((character,)), solver)
    k = state.add_effector("left_wrist", "position")
    start = state.view().joints[JOINT_INDEX["left_wrist"]].copy()
    for dy in np.linspace(0.1, 0.4, 4):  # one drag gesture
        state.move_effector(k, position=start + np.array([0.0, dy, 0.0]))
    state.end_gesture()
    after = state.character()
    assert state.relaxed == ("1: left_elbow rotation",)
    assert after.effectors[1].tolerance == RELAXED_TOLERANCE and after.effectors[0].tolerance == 0.0
    turn = _torso_turn_deg(character, after)
    assert turn.max() < 8.0, turn
    reach = np.linalg.norm(state.view().joints[JOINT_INDEX["left_wrist"]] - (start + [0.0, 0.4, 0.0]))
    assert reach < 0.01
    # the raised wrist is far above the old one: the arm moved, the rest of the body did not
    right = JOINT_INDEX["right_wrist"]
    before_joints = TargetPose.from_pose(dataclasses.replace(character.pose, joints=None)).p_world.numpy()
    assert np.linalg.norm(state.view().joints[right] - before_joints[right]) < 0.02
    # one undo step restores the pose and the exact elbow effector
    assert state.undo() and state.undo()
    assert state.character().effectors[1].tolerance == 0.0


def test_conflict_report_names_the_contradicting_effectors(solver):
    character = _recovered_style_character(solver)
    report = conflict_report(character, solver)
    assert len(report.entries) == len(character.effectors)
    assert report.conflicts == ()  # effectors of one pose agree
    assert "no conflicting effectors" in report.lines()[0]
    # a wrist target 45 cm above the pose while the elbow rotation stays exact: they contradict each other
    wrist = TargetPose.from_pose(dataclasses.replace(character.pose, joints=None)).p_world.numpy()[
        JOINT_INDEX["left_wrist"]]
    edited = dataclasses.replace(character, effectors=character.effectors + (
        Effector.position("left_wrist", wrist + [0.0, 0.45, 0.0]),))
    edited = solve_character(edited, solver)
    report = conflict_report(edited, solver)
    by_label = {e.label(): e for e in report.entries}
    wrist_entry = by_label["7: left_wrist position"]
    elbow_entry = by_label["1: left_elbow rotation"]
    assert wrist_entry.in_conflict and elbow_entry.in_conflict
    assert 1 in wrist_entry.conflicts_with and 7 in elbow_entry.conflicts_with
    assert wrist_entry.unit == "mm" and elbow_entry.unit == "deg"
    text = "\n".join(report.lines())
    assert "left_elbow rotation" in text and ("NOT MET" in text or "FORCED" in text)
    d = report.to_dict()
    assert d["effectors"][7]["conflicts_with"] and d["effectors"][7]["joint"] == "left_wrist"
    # relaxing the stale elbow: the wrist is met, and only the relaxed elbow still disagrees with it
    relaxed, _ = relax_stale(edited.effectors, 7)
    fixed = solve_character(dataclasses.replace(edited, effectors=relaxed), solver)
    entries = conflict_report(fixed, solver).entries
    assert entries[7].met and set(entries[7].conflicts_with) <= {1}


def test_conflict_report_without_pose_is_empty(solver):
    c = SceneCharacter("x", Gender.NEUTRAL, np.zeros(NUM_BETAS))
    assert conflict_report(c, solver).entries == ()


def test_editor_drag_summary_lists_relaxed_and_conflicts(solver):
    state = EditorState(Scene((_recovered_style_character(solver),)), solver)
    k = state.add_effector("left_wrist", "position")
    start = state.view().joints[JOINT_INDEX["left_wrist"]].copy()
    state.move_effector(k, position=start + np.array([0.0, 0.4, 0.0]))
    state.end_gesture()
    text = state.drag_summary()
    assert "Relaxed (tolerance raised): 1: left_elbow rotation" in text
    assert state.conflicts() is state.conflicts()  # cached until the character changes


def test_hinge_twist_moves_to_the_parent_and_keeps_the_joints(bodies):
    from smplik.kinematics import forward_kinematics
    from smplik.rotations import axis_angle_to_matrix, matrix_to_quaternion
    from workflows.scene.edits import hinge_twist_to_parent

    g = torch.Generator().manual_seed(4)
    R = axis_angle_to_matrix(torch.randn(3, 24, 3, generator=g, dtype=torch.float64) * 0.5)
    J = bodies.rest_joints(torch.zeros(3, NUM_BETAS), torch.zeros(3, dtype=torch.long)).double()
    elbow, knee = JOINT_INDEX["left_elbow"], JOINT_INDEX["right_knee"]
    R2 = hinge_twist_to_parent(R, J, [elbow, knee])
    Rw, p = forward_kinematics(R, J)
    Rw2, p2 = forward_kinematics(R2, J)
    assert (p2 - p).abs().max() < 1e-9  # every joint stays
    assert (Rw2[:, elbow] - Rw[:, elbow]).abs().max() < 1e-9 and (Rw2[:, knee] - Rw[:, knee]).abs().max() < 1e-9
    for j in (elbow, knee):  # no turn left about the parent bone
        a = J[:, j] - J[:, PARENTS[j]]
        q = matrix_to_quaternion(R2[:, j])
        assert ((q[:, 1:] * a).sum(-1)).abs().max() < 1e-9
    assert not torch.allclose(R2[:, elbow], R[:, elbow])  # there was a twist to move


def _dragged(character: SceneCharacter, joint: str, offset) -> tuple[list[Effector], Pose, np.ndarray]:
    """The character's effectors after a drag of ``joint``'s position by ``offset`` (relaxed), its pose, the
    pose's joints."""
    before = TargetPose.from_pose(dataclasses.replace(character.pose, joints=None)).p_world.double().numpy()
    target = before[JOINT_INDEX[joint]] + np.asarray(offset)
    effs, _, _ = drag_effector(character.effectors, Effector.position(joint, target))
    return list(effs), dataclasses.replace(character.pose, joints=None), before


def test_a_dragged_wrist_moves_only_its_arm_and_takes_the_priors_swivel(solver):
    """The default drag: the wrist reaches its target, every joint outside shoulder-elbow-wrist-hand stays
    exactly where it was (collar included), and the elbow's pole turns SWIVEL_SHARE of the way from the
    scene's to the network's."""
    from smplik.effectors import pack_effectors
    from smplik.kinematics import forward_kinematics
    from smplik.limb_ik import swivel_angle, two_bone_ik_pose
    from smplik.refine import NO_REFINEMENT
    from smplik.rotations import axis_angle_to_matrix
    from workflows.scene.edits import SWIVEL_SHARE, solve_edit

    character = _recovered_style_character(solver)
    wrist = JOINT_INDEX["left_wrist"]
    effs, previous, before = _dragged(character, "left_wrist", (0.15, 0.3, 0.1))
    target = effs[-1].value
    pose = solve_edit(solver, [effs], [previous], [wrist])[0]
    after = TargetPose.from_pose(dataclasses.replace(pose, joints=None)).p_world.double().numpy()
    assert np.linalg.norm(after[wrist] - target) < 1e-4
    arm = [JOINT_INDEX[n] for n in ("left_elbow", "left_wrist", "left_hand")]
    rest = [j for j in range(len(PARENTS)) if j not in arm]
    assert np.abs(after[rest] - before[rest]).max() < 1e-5
    assert np.linalg.norm(after[arm[0]] - before[arm[0]]) > 0.05  # the elbow did move
    # the pole: plain two-bone on the old pose vs the network's elbow for the same effectors
    aa = torch.from_numpy(np.concatenate([previous.global_orient[None], previous.body_pose]))[None]
    J = solver.bodies.rest_joints(torch.zeros(1, NUM_BETAS), torch.zeros(1, dtype=torch.long)).double()
    tr, tip, tgt = torch.from_numpy(previous.transl)[None], torch.tensor([wrist]), torch.from_numpy(target)[None]
    _, p_plain = forward_kinematics(two_bone_ik_pose(axis_angle_to_matrix(aa), tr, J, tip, tgt), J, tr)
    net = solver.solve_tensors(pack_effectors([effs]), torch.zeros(1, NUM_BETAS), torch.zeros(1, dtype=torch.long),
                               refine=NO_REFINEMENT)
    sh, el = JOINT_INDEX["left_shoulder"], JOINT_INDEX["left_elbow"]
    to_net = swivel_angle(p_plain[:, sh], p_plain[:, el], tgt, net.p_world[:, sh].double(), net.p_world[:, el].double())
    taken = swivel_angle(p_plain[:, sh], p_plain[:, el], tgt, torch.from_numpy(after[sh])[None],
                         torch.from_numpy(after[el])[None])
    assert abs(float(to_net)) > 5e-3  # the network does prefer another pole here
    assert abs(float(taken) - SWIVEL_SHARE * float(to_net)) < 1e-4
    # the elbow bends without turning about the upper arm (that twist is the shoulder's): the plain
    # two-bone bend about the chain's plane does turn it here
    from smplik.rotations import matrix_to_quaternion

    bone = (J[0, el] - J[0, sh]) / (J[0, el] - J[0, sh]).norm()
    def twist(R_elbow):
        q = matrix_to_quaternion(R_elbow)
        return float((q[1:] * bone).sum().abs())
    assert twist(axis_angle_to_matrix(torch.from_numpy(pose.body_pose[el - 1]))) < 1e-6
    assert twist(two_bone_ik_pose(axis_angle_to_matrix(aa), tr, J, tip, tgt)[0, el]) > 1e-3
    # the previous release's solve (analytic=False) re-poses the chain with the network instead
    chain_pose = solve_edit(solver, [effs], [previous], [wrist], analytic=False)[0]
    assert not np.allclose(chain_pose.body_pose, pose.body_pose)


def test_an_out_of_reach_drag_lets_the_body_help_and_a_pinned_hand_keeps_its_turn(solver):
    """Beyond the arm's reach the analytic limb cannot meet the exact target: the held refinement starts from
    it and brings the wrist closer than the straight arm reaches (collar/spine take a share). An exact hand
    rotation the user holds (tolerance 0 after the drag) keeps the hand's world orientation."""
    from workflows.scene.edits import solve_edit

    character = _recovered_style_character(solver)
    wrist, hand = JOINT_INDEX["left_wrist"], JOINT_INDEX["left_hand"]
    effs, previous, before = _dragged(character, "left_wrist", (0.0, 0.0, 0.0))
    shoulder = before[JOINT_INDEX["left_shoulder"]]
    arm = (np.linalg.norm(before[JOINT_INDEX["left_elbow"]] - shoulder)
           + np.linalg.norm(before[wrist] - before[JOINT_INDEX["left_elbow"]]))
    far = shoulder + np.array([arm + 0.08, 0.0, 0.0])
    effs[-1] = Effector.position("left_wrist", far)
    pose = solve_edit(solver, [effs], [previous], [wrist])[0]
    after = TargetPose.from_pose(dataclasses.replace(pose, joints=None)).p_world.double().numpy()
    assert np.linalg.norm(after[wrist] - far) < 0.08 - 0.02
    # a reachable drag with the hand's rotation pinned again
    R_before = TargetPose.from_pose(previous).R_world.double().numpy()
    effs, previous, _ = _dragged(character, "left_wrist", (0.1, 0.25, 0.0))
    effs.append(Effector.rotation("left_wrist", R_before[wrist]))
    pose = solve_edit(solver, [effs], [previous], [wrist])[0]
    fk = TargetPose.from_pose(dataclasses.replace(pose, joints=None))
    assert np.linalg.norm(fk.p_world.double().numpy()[wrist] - effs[-2].value) < 1e-3
    cos = (np.trace(fk.R_world.double().numpy()[wrist] @ R_before[wrist].T) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 0.5
    # the hand rides on the kept wrist rotation: its offset from the wrist is turned by the same world rotation
    offset = fk.p_world.double().numpy()[hand] - fk.p_world.double().numpy()[wrist]
    assert np.linalg.norm(offset - (TargetPose.from_pose(previous).p_world.double().numpy()[hand]
                                    - TargetPose.from_pose(previous).p_world.double().numpy()[wrist])) < 1e-3
