"""The edit benchmark's pair selection and metrics on hand-made sequences, and the two-bone IK baseline."""

from __future__ import annotations

import math

import pytest
import torch

from smplik.conventions import JOINT_INDEX, NUM_JOINTS, PARENTS
from smplik.kinematics import forward_kinematics
from smplik.limb_ik import two_bone_ik_pose
from smplik.rotations import axis_angle_to_matrix
from workflows.edit_benchmark.pairs import (
    EditPairConfig,
    JointRanges,
    align_to_pelvis,
    edit_metrics,
    find_edit_pairs,
    pelvis_relative,
)

FPS = 30.0


def _yaw(angle: torch.Tensor) -> torch.Tensor:
    """(T,) radians about +y -> (T, 3, 3)."""
    return axis_angle_to_matrix(torch.stack([torch.zeros_like(angle), angle, torch.zeros_like(angle)], -1))


def _sequence(moves: dict[str, float], T: int = 60, start: int = 10, end: int = 40) -> tuple[torch.Tensor,
                                                                                                  torch.Tensor]:
    """World joints (T, 24, 3) and pelvis rotations (T, 3, 3): a body walking and turning while the named
    joints move linearly by the given distances (metres, pelvis frame) between frames ``start`` and ``end``."""
    g = torch.Generator().manual_seed(0)
    rest = torch.randn(NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.3
    rest[0] = 0
    s = ((torch.arange(T, dtype=torch.float64) - start) / (end - start)).clamp(0, 1)
    local = rest.expand(T, -1, -1).clone()
    for name, dist in moves.items():
        local[:, JOINT_INDEX[name], 0] += dist * s
    R = _yaw(torch.linspace(0, 1.5, T, dtype=torch.float64))  # the whole body turns ...
    transl = torch.stack([torch.linspace(0, 2, T), torch.zeros(T), torch.zeros(T)], -1).double()  # ... and walks
    return local @ R.transpose(-1, -2) + transl[:, None], R


def test_a_single_wrist_move_is_found_relative_to_the_pelvis():
    p, R = _sequence({"right_wrist": 0.30})
    rel = pelvis_relative(p, R)
    pairs = find_edit_pairs(rel, FPS)
    assert pairs and all(q.end == "right_wrist" for q in pairs)
    first = pairs[0]
    assert first.t0 == 0 and 40 <= first.t1 <= 45  # a partner where the wrist moved farthest (0.3 m, >= 1.33 s)
    assert first.move_m == pytest.approx(0.30, abs=1e-9)
    for q in pairs:
        assert 9 <= q.t1 - q.t0 <= 45 and q.move_m >= 0.15  # 0.3-1.5 s at 30 fps, >= 15 cm
    starts = [q.t0 for q in pairs]
    assert all(b - a >= 6 for a, b in zip(starts, starts[1:], strict=False))  # min_gap 0.2 s


@pytest.mark.parametrize("moves", [
    {"right_wrist": 0.30, "head": 0.10},          # the head moved too (>= 5 cm whenever the wrist moved 15)
    {"right_wrist": 0.30, "left_ankle": 0.10},     # another limb end moved along
    {"right_wrist": 0.30, "left_wrist": 0.30},     # two limbs moved
    {"right_wrist": 0.12},                         # too small a move
])
def test_moves_that_are_not_single_limb_edits_are_refused(moves):
    p, R = _sequence(moves)
    assert find_edit_pairs(pelvis_relative(p, R), FPS) == []


def test_pair_time_window_is_respected():
    p, R = _sequence({"left_ankle": 0.30}, T=120, start=10, end=100)  # 0.3 m over 3 s: 15 cm takes 1.5 s
    pairs = find_edit_pairs(pelvis_relative(p, R), FPS, EditPairConfig(max_dt=1.0))
    assert pairs == []
    pairs = find_edit_pairs(pelvis_relative(p, R), FPS, EditPairConfig(max_dt=1.5))
    assert pairs and all(q.t1 - q.t0 == 45 and q.end == "left_ankle" for q in pairs)


def test_align_to_pelvis_moves_the_skeleton_rigidly():
    g = torch.Generator().manual_seed(1)
    R_local = axis_angle_to_matrix(torch.randn(2, NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.4)
    J = torch.randn(NUM_JOINTS, 3, generator=g, dtype=torch.float64)
    R_w, p_w = forward_kinematics(R_local, J, torch.randn(2, 3, generator=g, dtype=torch.float64))
    R_a, p_a = align_to_pelvis(R_w[1], p_w[1], R_w[0, 0], p_w[0, 0])
    assert torch.allclose(R_a[0], R_w[0, 0]) and torch.allclose(p_a[0], p_w[0, 0])
    d = torch.cdist(p_a, p_a) - torch.cdist(p_w[1], p_w[1])
    assert d.abs().max() < 1e-12


def test_edit_metrics_known_answers():
    P = 1
    g = torch.Generator().manual_seed(2)
    p_true = torch.randn(P, NUM_JOINTS, 3, generator=g, dtype=torch.float64)
    p_pred = p_true.clone()
    p_pred[0, JOINT_INDEX["left_hip"], 0] += 0.024  # 24 mm off, outside the right arm
    eye = torch.eye(3, dtype=torch.float64).expand(P, NUM_JOINTS, 3, 3).clone()
    R_pred = eye.clone()
    R_pred[0, JOINT_INDEX["spine2"]] = _yaw(torch.tensor([math.radians(30.0)], dtype=torch.float64))[0]
    R_true = eye.clone()
    R_true[0, JOINT_INDEX["spine2"]] = _yaw(torch.tensor([math.radians(5.0)], dtype=torch.float64))[0]
    ranges = JointRanges(torch.full((NUM_JOINTS, 3), -1.0, dtype=torch.float64),
                         torch.full((NUM_JOINTS, 3), 1.0, dtype=torch.float64))
    aa_pred = torch.zeros(P, NUM_JOINTS, 3, dtype=torch.float64)
    aa_pred[0, JOINT_INDEX["right_elbow"], 2] = 1.5  # outside [-1, 1] + 5 degrees
    aa_pred[0, JOINT_INDEX["left_elbow"], 2] = 1.05  # inside the margin
    target = p_pred[0, JOINT_INDEX["right_wrist"]] + torch.tensor([0.003, 0.0, 0.0], dtype=torch.float64)
    m = edit_metrics(p_pred=p_pred, R_world_pred=R_pred, aa_local_pred=aa_pred, p_true=p_true, R_world_true=R_true,
                     aa_local_true=torch.zeros_like(aa_pred), R_world_before=eye,
                     aa_local_before=torch.zeros_like(aa_pred), R_world_start=eye, ends=["right_wrist"],
                     targets=target[None], ranges=ranges)
    assert float(m.mpjpe_mm[0]) == pytest.approx(1.0)
    assert float(m.collateral_mm[0]) == pytest.approx(24.0 / (NUM_JOINTS - 5))  # right arm: 5 joints
    assert float(m.limb_mm[0]) == pytest.approx(0.0)
    assert float(m.reach_mm[0]) == pytest.approx(3.0)
    assert int(m.out_of_range[0]) == 1
    assert int(m.torso_turned[0]) == 1 and float(m.torso_excess_deg[0]) == pytest.approx(25.0)
    assert int(m.contortions[0]) == 2
    # the same turn in the real motion is no contortion; a joint the starting pose already had out is not counted
    before = aa_pred.clone()
    m2 = edit_metrics(p_pred=p_pred, R_world_pred=R_pred, aa_local_pred=aa_pred, p_true=p_true, R_world_true=R_pred,
                      aa_local_true=torch.zeros_like(aa_pred), R_world_before=eye, aa_local_before=before,
                      R_world_start=eye, ends=["right_wrist"], targets=target[None], ranges=ranges)
    assert int(m2.contortions[0]) == 0


def test_joint_ranges_fit_and_outside():
    pose = torch.zeros(3, NUM_JOINTS, 3)
    pose[1, 5, 0] = 0.5
    pose[2, 5, 0] = -0.2
    r = JointRanges.fit(pose)
    assert float(r.hi[5, 0]) == pytest.approx(0.5) and float(r.lo[5, 0]) == pytest.approx(-0.2)
    probe = torch.zeros(2, NUM_JOINTS, 3)
    probe[0, 5, 0] = 0.5 + math.radians(6)
    probe[1, 5, 0] = 0.5 + math.radians(4)
    out = r.outside(probe)
    assert bool(out[0, 5]) and not bool(out[1, 5]) and int(out.sum()) == 1
    with pytest.raises(ValueError, match="shape"):
        JointRanges.fit(torch.zeros(0, NUM_JOINTS, 3))


def test_two_bone_ik_reaches_and_changes_only_the_chain(bodies):
    g = torch.Generator().manual_seed(3)
    B = 4
    J = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    R = axis_angle_to_matrix(torch.randn(B, NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.3)
    t = torch.zeros(B, 3, dtype=torch.float64)
    tip = torch.tensor([JOINT_INDEX[n] for n in ("left_wrist", "right_wrist", "left_ankle", "right_ankle")])
    _, p = forward_kinematics(R, J, t)
    rows = torch.arange(B)
    par = torch.tensor(PARENTS)
    root = p[rows, par[par[tip]]]
    target = root + 0.85 * (p[rows, tip] - root) + 0.03  # closer to the root: reachable
    R2 = two_bone_ik_pose(R, t, J, tip, target)
    _, p2 = forward_kinematics(R2, J, t)
    assert (p2[rows, tip] - target).norm(dim=-1).max() < 1e-6
    changed = (R2 - R).abs().amax((-1, -2)) > 1e-12
    for b in range(B):
        assert set(torch.nonzero(changed[b])[:, 0].tolist()) <= {int(par[tip[b]]), int(par[par[tip[b]]])}
    # beyond reach: the straight limb points at the target
    far = p[rows, par[par[tip]]] + torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64)
    _, p3 = forward_kinematics(two_bone_ik_pose(R, t, J, tip, far), J, t)
    root = p3[rows, par[par[tip]]]
    u = (p3[rows, tip] - root) / (p3[rows, tip] - root).norm(dim=-1, keepdim=True)
    assert torch.allclose(u, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(B, 3), atol=1e-6)


def test_turn_swivel_moves_only_the_middle_joint_about_the_reach_axis(bodies):
    """The elbow/knee pole: turning by swivel_angle towards a reference limb puts the middle joint in the
    reference's plane, keeps the root and the reached tip, and changes only the chain root's rotation."""
    from smplik.limb_ik import swivel_angle, turn_swivel

    g = torch.Generator().manual_seed(5)
    B = 4
    J = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    R = axis_angle_to_matrix(torch.randn(B, NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.3)
    R_ref = axis_angle_to_matrix(torch.randn(B, NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.3)
    t = torch.zeros(B, 3, dtype=torch.float64)
    tip = torch.tensor([JOINT_INDEX[n] for n in ("left_wrist", "right_wrist", "left_ankle", "right_ankle")])
    rows, par = torch.arange(B), torch.tensor(PARENTS)
    mid, root = par[tip], par[par[tip]]
    _, p = forward_kinematics(R, J, t)
    target = p[rows, root] + 0.8 * (p[rows, tip] - p[rows, root])
    R = two_bone_ik_pose(R, t, J, tip, target)
    _, p = forward_kinematics(R, J, t)
    _, p_ref = forward_kinematics(R_ref, J, t)
    angle = swivel_angle(p[rows, root], p[rows, mid], target, p_ref[rows, root], p_ref[rows, mid])
    assert angle.abs().min() > 1e-3  # the random reference has another pole
    R2 = turn_swivel(R, t, J, tip, target, angle)
    _, p2 = forward_kinematics(R2, J, t)
    assert (p2[rows, tip] - target).norm(dim=-1).max() < 1e-9 and (p2[rows, root] - p[rows, root]).abs().max() < 1e-12
    # now in the reference's plane: no turn left
    left = swivel_angle(p2[rows, root], p2[rows, mid], target, p_ref[rows, root], p_ref[rows, mid])
    assert left.abs().max() < 1e-6
    changed = (R2 - R).abs().amax((-1, -2)) > 1e-12
    for b in range(B):
        assert set(torch.nonzero(changed[b])[:, 0].tolist()) == {int(root[b])}
    # a straight limb has no pole: no turn
    zero = swivel_angle(p[rows, root], target, target, p_ref[rows, root], p_ref[rows, mid])
    assert zero.abs().max() == 0.0


def test_cli_edits_refuses_bad_input_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    missing = tmp_path / "nope.npz"
    res = CliRunner().invoke(app, ["benchmark", "edits", "--data", str(missing), "--out", str(tmp_path / "r.json")])
    assert res.exit_code == 1 and "nope.npz" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["benchmark", "edits", "--data", str(missing), "--out", str(tmp_path / "r.json"),
                                   "--methods", "smplik,magic"])
    assert res.exit_code != 0 and "magic" in res.output
    assert not (tmp_path / "r.json").exists()
    # a held-out folder: missing, or an unknown retarget preset, refused before any work
    res = CliRunner().invoke(app, ["benchmark", "edits", "--out", str(tmp_path / "r.json"), "--clips",
                                   str(tmp_path / "no_clips")])
    assert res.exit_code == 1 and "no_clips" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["benchmark", "edits", "--out", str(tmp_path / "r.json"), "--clips", str(tmp_path),
                                   "--clips-preset", "not_a_rig"])
    assert res.exit_code == 1 and "not_a_rig" in res.output and "Traceback" not in res.output


def test_benchmark_on_a_cache_without_edits_says_so(tiny_cache, tmp_path):
    """The synthetic clips of the tiny cache move every limb at once: no single-limb edit, a clear error."""
    from typer.testing import CliRunner

    from smplik.cli.main import app

    res = CliRunner().invoke(app, ["benchmark", "edits", "--data", str(tiny_cache), "--split", "train",
                                   "--out", str(tmp_path / "r.json"), "--methods", "two_bone"])
    assert res.exit_code == 1, res.output
    assert "single-limb edit pairs" in res.output and "Traceback" not in res.output


def test_run_edit_benchmark_on_a_hand_made_clip(shipped_solver):
    """A clip whose only motion is the right elbow bending 90 degrees: every pair is a right-wrist edit, the
    drag meets its target, and the results document is JSON."""
    import json

    import numpy as np

    from workflows.edit_benchmark.run import EditBenchmarkConfig, EditClip, run_edit_benchmark

    T = 40
    pose = torch.zeros(T, NUM_JOINTS, 3)
    pose[:, JOINT_INDEX["left_shoulder"], 2] = -1.2  # arms down
    pose[:, JOINT_INDEX["right_shoulder"], 2] = 1.2
    bend = torch.linspace(0, 1, T).sub(5 / T).clamp(0, 1) * (math.pi / 2)
    pose[:, JOINT_INDEX["right_elbow"], 1] = bend
    clip = EditClip("hand_made", "x", FPS, pose, torch.zeros(T, 3))
    solver = shipped_solver
    ranges = JointRanges.fit(pose.double())
    doc = run_edit_benchmark([clip], solver, ranges, methods=("smplik", "two_bone"),
                             cfg=EditBenchmarkConfig(max_pairs=2))
    json.dumps(doc)
    assert doc["counts"]["right_wrist"] == len(doc["pairs"]) >= 1
    for name in ("smplik", "two_bone"):
        s = doc["methods"][name]
        assert s["pairs"] == len(doc["pairs"]) and np.isfinite(s["mpjpe_mm"])
        assert s["reach_mm_median"] < 10.0
    assert doc["methods"]["two_bone"]["reach_mm_median"] < 1e-3
    # the default drag: only the arm moves (no collateral change from the recovered pose), nothing contorts
    assert doc["methods"]["smplik"]["contorted_pairs"] == 0
    assert abs(doc["methods"]["smplik"]["collateral_mm"] - doc["methods"]["two_bone"]["collateral_mm"]) < 1e-3


def test_held_out_folder_clips_are_read_and_searched(shared_data, tmp_path):
    """``--clips DIR``: BVH clips of a folder (here two CMU test clips copied), retargeted and resampled."""
    import shutil

    from smplik.body_model import BodyModelSet
    from workflows.edit_benchmark.run import EDIT_FPS, EditBenchmarkConfig, clips_from_folder, select_pairs

    for name in ("02_05.bvh", "02_06.bvh"):
        shutil.copy(shared_data.cmu(name), tmp_path / name)
    clips = clips_from_folder(tmp_path)
    auto = clips_from_folder(tmp_path, preset="auto")  # the CLI's default: the rig mapper
    assert all(torch.allclose(a.pose, c.pose, atol=1e-5) for a, c in zip(auto, clips, strict=True))
    assert [c.name for c in clips] == ["02_05.bvh", "02_06.bvh"] and all(c.subject == "02" for c in clips)
    assert all(c.fps == EDIT_FPS and c.pose.shape[1:] == (NUM_JOINTS, 3) for c in clips)
    J = BodyModelSet.load().rest_joints(torch.zeros(10), torch.tensor(0))
    pairs = select_pairs(clips, J, EditBenchmarkConfig())
    assert pairs and all(p.end == "right_wrist" for p in pairs)  # the test split's right-hand edits of 02_05/06


def test_joint_drags_on_real_motion_meet_reachable_targets_and_hold_the_rest(shipped_solver, shared_data):
    """The edit benchmark's joint drags (workflows.edit_benchmark.joints) on a real CMU clip: every joint's drag
    meets its reachable targets within 1 cm and moves nothing outside its chain by 5 mm; every case is reported."""
    from smplik.data.dataset import find_sources
    from workflows.edit_benchmark.joints import JOINTS, joint_drag_benchmark
    from workflows.edit_benchmark.run import clips_from_folder

    if shared_data.cmu_dir is None or not any(s.name.startswith("02_01") for s in find_sources(shared_data.cmu_dir,
                                                                                               "bvh")):
        pytest.skip("CMU 02_01.bvh is not in the shared data")
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        shutil.copy(shared_data.cmu_dir / "02_01.bvh", folder)
        clips = clips_from_folder(folder, preset="cmu")
    out = joint_drag_benchmark(clips, shipped_solver, pairs_per_joint=3, before=False)
    assert set(out["joints"]) == set(JOINTS)
    assert len(out["pairs"]) == sum(v["smplik"]["pairs"] for v in out["joints"].values())
    for joint, figures in out["joints"].items():
        s = figures["smplik"]
        assert s["outside_mm_max"] < 5.0, joint
        if s["reachable"]:
            assert s["reachable_target_mm_max"] < 10.0, joint
    for row in out["pairs"]:
        assert {"joint", "clip", "t0", "t1", "move_mm", "reachable", "smplik"} <= set(row)
