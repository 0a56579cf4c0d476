"""Issue 44 items 1-2 through the editor's model (:class:`workflows.editor.state.EditorState`), on a real CMU pose
with the hands and feet pinned: adding, re-tolerancing and deleting an effector never moves the body; any joint
(elbows, knees, head, neck, spine, pelvis) drags 10 cm to within 1 cm of its target while the joints outside the
moved chain stay within 5 mm; the conflict report names only the effectors that pull against a drag."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, NUM_BETAS, Gender
from smplik.effectors import Effector
from smplik.pose import Pose
from workflows.editor.state import EditorState
from workflows.scene import Scene, SceneCharacter

PINNED = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")
ARM = {s: (f"{s}_shoulder", f"{s}_elbow", f"{s}_wrist", f"{s}_hand") for s in ("left", "right")}
LEG = {s: (f"{s}_knee", f"{s}_ankle", f"{s}_foot") for s in ("left", "right")}
UPPER = ("spine2", "spine3", "neck", "head", "left_collar", "right_collar", "left_shoulder", "right_shoulder",
         "left_elbow", "right_elbow")
MOVED: dict[str, tuple[str, ...]] = {
    # joints a drag may move; every other joint (the pinned hands and feet included) must stay within 5 mm
    "left_elbow": ARM["left"], "right_elbow": ARM["right"], "left_knee": LEG["left"], "right_knee": LEG["right"],
    "head": UPPER, "neck": UPPER,
    "spine3": ("pelvis", "spine1", "left_hip", "right_hip", "left_knee", "right_knee", *UPPER),
    "spine2": ("pelvis", "spine1", "left_hip", "right_hip", "left_knee", "right_knee", *UPPER),
    "spine1": ("pelvis", "spine1", "left_hip", "right_hip", "left_knee", "right_knee", *UPPER),
    "pelvis": ("pelvis", "spine1", "left_hip", "right_hip", "left_knee", "right_knee", *UPPER),
}
ANCHOR = {"left_elbow": "left_shoulder", "right_elbow": "right_shoulder", "left_knee": "left_hip",
          "right_knee": "right_hip", "head": "spine1", "neck": "spine1"}


@pytest.fixture(scope="module")
def solver(shipped_solver):

    return shipped_solver


@pytest.fixture(scope="module", params=["cmu_02_01", "example_walk"])
def real_pose(request):
    """Frame 200 of CMU 02_01 (a walk) on the neutral body (skipped without the shared data), and the built-in
    example walk (:func:`workflows.examples_gen.example_poses`, always there)."""
    from smplik.data.dataset import find_sources, read_source

    if request.param == "example_walk":
        from workflows.examples_gen import example_poses

        p = example_poses()[0].pose
        return Pose(np.asarray(p.global_orient, np.float64), np.asarray(p.body_pose, np.float64),
                    np.asarray(p.transl, np.float64), np.zeros(NUM_BETAS), Gender.NEUTRAL)
    shared_data = request.getfixturevalue("shared_data")
    if shared_data.cmu_dir is None:
        pytest.skip("no CMU BVH folder in the shared data")
    src = [s for s in find_sources(shared_data.cmu_dir, "bvh") if s.name.startswith("02_01")]
    if not src:
        pytest.skip("CMU 02_01.bvh is not in the shared data")
    seq = read_source(src[0], preset="cmu")
    t = 200
    return Pose(np.asarray(seq.global_orient[t], np.float64), np.asarray(seq.body_pose[t], np.float64),
                np.asarray(seq.transl[t], np.float64), np.zeros(NUM_BETAS), Gender.NEUTRAL)


def _state(solver, pose: Pose, pinned=PINNED) -> EditorState:
    c = SceneCharacter("walker", Gender.NEUTRAL, np.zeros(NUM_BETAS), pose=pose)
    state = EditorState(Scene((c,)), solver)
    joints = state.view().joints
    effs = tuple(Effector.position(n, joints[JOINT_INDEX[n]]) for n in pinned)
    state = EditorState(Scene((SceneCharacter("walker", Gender.NEUTRAL, np.zeros(NUM_BETAS), effectors=effs,
                                              pose=pose),)), solver)
    return state


def _target(joints: np.ndarray, joint: str, pose: Pose) -> np.ndarray:
    """A reachable 10 cm drag: limb joints and the head/neck turn about their anchor (a bow forward for the
    torso, up-and-forward for an elbow/knee); the pelvis and spine go 10 cm down-forward (knees bend)."""
    R_body = Rotation.from_rotvec(pose.global_orient).as_matrix()
    forward, left = R_body[:, 2], R_body[:, 0]
    p = joints[JOINT_INDEX[joint]]
    if joint not in ANCHOR:
        return p + 0.1 * (forward - np.array([0.0, 1.0, 0.0])) / np.sqrt(2.0)
    a = joints[JOINT_INDEX[ANCHOR[joint]]]
    r = np.linalg.norm(p - a)
    angle = 2 * np.arcsin(0.05 / r)  # a 10 cm chord
    axis = left if joint in ("head", "neck") else np.cross(p - a, forward)
    axis = axis / np.linalg.norm(axis)
    return a + Rotation.from_rotvec(angle * axis).apply(p - a)


def _moved_mm(a: np.ndarray, b: np.ndarray, names=None) -> float:
    idx = [JOINT_INDEX[n] for n in names] if names is not None else slice(None)
    return 1000.0 * float(np.linalg.norm(a[idx] - b[idx], axis=-1).max())


@pytest.mark.parametrize("joint", list(MOVED))
def test_add_retolerance_drag_delete_per_joint(solver, real_pose, joint):
    state = _state(solver, real_pose)
    start = state.view().joints.copy()
    k = state.add_effector(joint)
    assert _moved_mm(state.view().joints, start) < 0.1  # adding holds the body where it is
    state.set_tolerance(0.5, k)
    state.end_gesture()
    state.set_tolerance(0.0, k)
    state.end_gesture()
    assert _moved_mm(state.view().joints, start) < 0.1  # so does re-tolerancing
    target = _target(start, joint, real_pose)
    assert 0.095 < np.linalg.norm(target - start[JOINT_INDEX[joint]]) < 0.105
    state.move_effector(k, position=target)
    state.end_gesture()
    after = state.view().joints
    assert 1000 * np.linalg.norm(after[JOINT_INDEX[joint]] - target) < 10.0
    outside = [n for n in JOINT_INDEX if n not in MOVED[joint] and n != joint]
    assert _moved_mm(after, start, outside) < 5.0, outside
    report = state.conflicts()
    assert not report.conflicts, report.lines()  # the target is reachable: nothing pulls
    dragged = after.copy()
    state.delete_effector(k)
    assert _moved_mm(state.view().joints, dragged) < 0.1  # deleting holds the body too
    state.undo()
    state.set_tolerance(1.0, k)
    assert _moved_mm(state.view().joints, dragged) < 0.1


def test_adding_to_a_fresh_t_pose_keeps_it(solver):
    from workflows.editor.state import fresh_scene

    state = EditorState(fresh_scene(), solver)
    start = state.view().joints.copy()
    for joint in ("right_wrist", "left_ankle", "left_elbow", "head"):
        state.add_effector(joint)
        assert _moved_mm(state.view().joints, start) < 0.1


def test_lowering_a_missed_effectors_tolerance_solves_only_it(solver, real_pose):
    """An effector the pose does not meet, made exact: the pose starts from where it is, only its chain moves."""
    state = _state(solver, real_pose)
    start = state.view().joints.copy()
    k = state.add_effector("head", tolerance=1.0)
    target = _target(start, "head", real_pose)
    c = state.character()
    moved = dataclasses.replace(c, effectors=c.effectors[:k] + (Effector.position("head", target, 1.0),))
    state.replace_scene(Scene((moved,)))  # a scene file whose loose head effector was moved outside the editor
    assert _moved_mm(state.view().joints, start) < 0.1
    state.set_tolerance(0.0, k)
    after = state.view().joints
    assert 1000 * np.linalg.norm(after[JOINT_INDEX["head"]] - target) < 10.0
    assert _moved_mm(after, start, [n for n in JOINT_INDEX if n not in UPPER]) < 5.0


def test_conflict_report_names_only_the_effectors_that_pull(solver, real_pose):
    """The head dragged 35 cm forward cannot be met while the hands stay pinned; the feet do not pull (a head
    drag moves no leg), so only hand effectors are named."""
    state = _state(solver, real_pose)
    start = state.view().joints.copy()
    k = state.add_effector("head")
    R_body = Rotation.from_rotvec(real_pose.global_orient).as_matrix()
    state.move_effector(k, position=start[JOINT_INDEX["head"]] + 0.35 * R_body[:, 2])
    state.end_gesture()
    report = state.conflicts()
    entry = report.entries[k]
    assert not entry.met
    names = {report.entries[j].effector.joint_name for j in entry.conflicts_with}
    assert names and names <= {"left_wrist", "right_wrist"}, report.lines()
    for e in report.entries:  # no other entry names anything but the dragged effector
        assert set(e.conflicts_with) <= ({k} if e.index != k else set(entry.conflicts_with))
    assert "left_ankle" not in state.drag_summary() and "right_ankle" not in state.drag_summary()


def test_add_effector_on_the_demo_scenes_moves_nothing(solver, tmp_path_factory):
    """Issue 44's reproduction: on the demo's two scenes, adding a position effector (right wrist, left ankle, left
    elbow, head) for each person moved the body by 9-104 mm; now by nothing."""
    from workflows.demo import run_demo

    out = run_demo(tmp_path_factory.mktemp("demo"), solver, previews=False)
    for scene_path in (out.smpl.scene, out.character.scene):
        state = EditorState.open(scene_path, solver)
        for person in range(len(state.scene.characters)):
            state.select_character(person)
            for joint in ("right_wrist", "left_ankle", "left_elbow", "head"):
                before = state.view().joints.copy()
                state.add_effector(joint)
                assert _moved_mm(state.view().joints, before) < 0.1, (scene_path.name, person, joint)
