"""Effector recovery: greedy order, threshold stop, one batched solve per step, real-model quality."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from smplik.conventions import EffectorType
from workflows.scene.recovery import RecoveryConfig, TargetPose, recover_effectors


def test_greedy_lowers_the_error_with_each_effector_and_stops_at_the_threshold(synthetic_pose, oracle_solver):
    target = TargetPose.from_pose(synthetic_pose(0))
    solver = oracle_solver(target.p_world)
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=6, threshold=0.0))
    # one batched solve per greedy step; full above the threshold and polish_above: the greedy search again
    # (the solver's refinement), the restart's 6 prefixes (one solve per width), one swap round that finds
    # nothing better; the final pose (every path holds 6: one batched solve)
    assert len(res.effectors) == 6 and solver.calls == 6 + 6 + 6 + 1 + 1
    assert res.final_error == pytest.approx(res.errors[-1], rel=1e-6)
    assert all(b < a for a, b in zip(res.errors, res.errors[1:], strict=False))
    # the oracle rewards rotations of joints with many children: spine3 (4 joints) first
    assert res.effectors[0].type == EffectorType.ROTATION and res.effectors[0].joint_name == "spine3"
    threshold = (res.errors[2] + res.errors[3]) / 2
    stopped = recover_effectors(oracle_solver(target.p_world), target, RecoveryConfig(max_effectors=10,
                                                                                      threshold=threshold))
    assert len(stopped.effectors) == 4 and stopped.errors[-1] < threshold <= stopped.errors[-2]


def test_character_scale_scales_errors_and_effectors(synthetic_pose, oracle_solver):
    target = TargetPose.from_pose(synthetic_pose(1))
    a = recover_effectors(oracle_solver(target.p_world), target, RecoveryConfig(max_effectors=3, threshold=0))
    b = recover_effectors(oracle_solver(target.p_world), target, RecoveryConfig(max_effectors=3, threshold=0),
                          scale=1.5)
    np.testing.assert_allclose(np.array(b.errors), 1.5 * np.array(a.errors), rtol=1e-5)
    for ea, eb in zip(a.effectors, b.effectors, strict=True):
        factor = 1.0 if ea.type == EffectorType.ROTATION else 1.5
        np.testing.assert_allclose(eb.value, factor * ea.value, atol=1e-5)


def _check_quality(res):
    errs = np.array(res.errors)
    # the full set is the closest of its prefixes (kept effectors lower the error; after the restart set's
    # prefixes or swaps, an intermediate count may be above the one before it)
    assert len(errs) >= 3 and errs[-1] <= errs.min() + 1e-6 and errs[1] < errs[0], errs
    assert errs[-1] < 0.6 * errs[0], errs
    # the final pose (full refinement of the chosen set) is at least about as close as the search's
    assert res.final_error < errs[-1] + 0.002, (res.final_error, errs[-1])


def test_real_model_on_a_synthetic_pose_is_fast_and_improves(shipped_solver, torch_threads):
    torch_threads(1)
    from workflows.examples_gen import example_poses

    target = TargetPose.from_pose(example_poses()[1].pose)
    res = recover_effectors(shipped_solver, target, RecoveryConfig(max_effectors=8, threshold=0.0))
    _check_quality(res)


def test_real_model_on_a_cmu_test_pose(shipped_solver, shared_data):
    from smplik.data.retarget import retarget_bvh
    from smplik.pose import Pose

    clip = retarget_bvh(shared_data.cmu("02_01.bvh"), "cmu")
    f = clip.num_frames // 2
    pose = Pose(clip.global_orient[f].astype(float), clip.body_pose[f].astype(float), clip.transl[f].astype(float),
                clip.betas.astype(float), clip.gender)
    res = recover_effectors(shipped_solver, TargetPose.from_pose(pose), RecoveryConfig(max_effectors=8, threshold=0))
    _check_quality(res)
    threshold = (res.errors[1] + res.errors[2]) / 2
    stopped = recover_effectors(shipped_solver, TargetPose.from_pose(pose),
                                RecoveryConfig(max_effectors=8, threshold=threshold))
    # stopped at the first count below the threshold (the greedy path, short of the maximum)
    assert len(stopped.errors) < 8 and stopped.errors[-1] < threshold <= min(stopped.errors[:-1])


def test_stand_in_runs_and_returns_a_solved_pose(stand_in_solver, synthetic_pose):
    target = TargetPose.from_pose(synthetic_pose(3))
    res = recover_effectors(stand_in_solver, target, RecoveryConfig(max_effectors=3, threshold=0.0))
    assert 1 <= len(res.effectors) <= 3 and res.pose.joints.shape == (24, 3)
    assert len({(e.joint, e.type) for e in res.effectors}) == len(res.effectors)  # no candidate twice
    assert all(b < a for a, b in zip(res.errors, res.errors[1:], strict=False))  # only improving steps kept


def test_negative_search_steps_are_refused(synthetic_pose, oracle_solver):
    target = TargetPose.from_pose(synthetic_pose(2))
    with pytest.raises(ValueError, match="search_refine_steps"):
        recover_effectors(oracle_solver(target.p_world), target, RecoveryConfig(search_refine_steps=-1))


def test_final_pose_is_what_the_effectors_re_solve_to(synthetic_pose, oracle_solver):
    """The result is the full-refinement solve of the recovered effectors (what re-solving a scene
    gives), even when the search's cheap solve came closer, and its error is reported as it is."""
    class WorseWhenFullyRefined(oracle_solver):
        """The search's solves are the oracle's; the final full-refinement solve lands 0.5 m off."""

        def solve_tensors(self, eff, betas, gender, *, refine=None):
            out = super().solve_tensors(eff, betas, gender)
            if refine is not None:
                return out
            return type(out)(out.R_local, out.R_world, out.p_world + 0.5, out.draft, out.transl)

    target = TargetPose.from_pose(synthetic_pose(4))
    res = recover_effectors(WorseWhenFullyRefined(target.p_world), target, RecoveryConfig(max_effectors=4,
                                                                                          threshold=0.0, polish=False))
    off = np.linalg.norm(res.pose.joints - target.p_world.numpy(), axis=-1)
    assert off.min() > 0.8 and res.final_error == pytest.approx(off.mean(), rel=1e-4)  # 0.5 m on each axis
    assert res.final_error > res.errors[-1]


def test_worst_limb_criterion_weighs_a_limb_far_off():
    from workflows.scene.recovery import JOINT_INDEX, LIMB_ZONES, limb_errors, recovery_score

    spread = torch.full((24,), 0.03)  # 3 cm everywhere
    one_arm = torch.zeros(24)
    one_arm[[JOINT_INDEX[n] for n in LIMB_ZONES["right_arm"]]] = 0.12  # a raised arm lost, the rest exact
    both = torch.stack([spread, one_arm])
    assert recovery_score(both, "joints")[1] < recovery_score(both, "joints")[0]  # the mean prefers losing the arm
    assert recovery_score(both, "joints+worst_limb")[1] > recovery_score(both, "joints+worst_limb")[0]
    assert limb_errors(one_arm)[2] == pytest.approx(0.12)


def test_recover_many_equals_one_by_one(synthetic_pose, stand_in_solver):
    from workflows.scene.recovery import recover_many

    targets = [TargetPose.from_pose(synthetic_pose(s)) for s in (5, 6, 7)]
    cfg = RecoveryConfig(max_effectors=4, threshold=0.0)
    solver = stand_in_solver
    steps = []
    many = recover_many(solver, targets, cfg, scales=[1.0, 1.3, 0.9], progress=lambda k, n: steps.append(k))
    one = [recover_effectors(solver, t, cfg, scale=s) for t, s in zip(targets, (1.0, 1.3, 0.9), strict=True)]
    for a, b in zip(many, one, strict=True):  # same choices, errors and final pose as one pose at a time
        assert [(e.joint, e.type) for e in a.effectors] == [(e.joint, e.type) for e in b.effectors]
        np.testing.assert_allclose(a.errors, b.errors, rtol=1e-4)
        assert a.final_error == pytest.approx(b.final_error, rel=1e-3)
    assert steps and steps[-1] <= 4


class _Trap:
    """An oracle solver (tests/conftest.py) with a penalty (metres, on every joint) per effector set."""

    def __init__(self, oracle_cls, target, penalty):
        self.oracle, self.penalty, self.widths = oracle_cls(target), penalty, []

    def solve_tensors(self, eff, betas, gender, *, refine=None):
        out = self.oracle.solve_tensors(eff, betas, gender, refine=refine)
        self.widths.append(eff.joint.shape[1])
        pen = torch.tensor([self.penalty(set(zip(j.tolist(), t.tolist(), strict=True)))
                            for j, t in zip(eff.joint, eff.type, strict=True)], dtype=torch.float32)
        return type(out)(out.R_local, out.R_world, out.p_world + pen[:, None, None], out.draft, out.transl)


def test_pairs_are_tried_when_no_single_candidate_helps(synthetic_pose, oracle_solver):
    """Every set of exactly three effectors lands 0.5 m off: the third step finds no single candidate, a
    pair (four effectors) lowers the error and the search goes on to the maximum."""
    target = TargetPose.from_pose(synthetic_pose(0))
    solver = _Trap(oracle_solver, target.p_world, lambda s: 0.5 if len(s) == 3 else 0.0)
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=6, threshold=0.0))
    assert 4 in solver.widths[2:4]  # the pair round came right after the failed third step
    assert len(res.effectors) == 6 and len(res.errors) == 6
    assert len({(e.joint, e.type) for e in res.effectors}) == 6
    assert res.errors[2] > 0.5 and res.errors[3] < res.errors[1]  # the pair's first member as a single, then the pair
    assert res.final_error == pytest.approx(res.errors[-1], rel=1e-5)


def test_a_stuck_search_restarts_from_the_dense_set(synthetic_pose, oracle_solver):
    """The greedy's first choice (spine3's rotation) poisons every larger set: singles and pairs fail,
    so the search restarts from the 6-point set of positions and fills up to the maximum from there."""
    from workflows.scene.recovery import RESTART_SET

    target = TargetPose.from_pose(synthetic_pose(0))
    spine3_rot = (9, int(EffectorType.ROTATION))
    solver = _Trap(oracle_solver, target.p_world, lambda s: 1.0 if spine3_rot in s and len(s) > 1 else 0.0)
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=8, threshold=0.0))
    restart = list(range(1, len(RESTART_SET) + 1))  # the restart set's prefixes: one solve per width
    assert any(solver.widths[i:i + len(restart)] == restart for i in range(8, len(solver.widths)))
    assert len(res.effectors) == 8 and spine3_rot not in {(e.joint, int(e.type)) for e in res.effectors}
    assert res.final_error < 0.3 * 18 / 24  # better than the stuck single effector (6 of 24 joints on target)


def test_never_stops_above_the_threshold_while_effectors_remain(synthetic_pose, oracle_solver):
    """A solver on which every extra effector makes things worse: the search still uses them all."""
    target = TargetPose.from_pose(synthetic_pose(1))
    solver = _Trap(oracle_solver, target.p_world, lambda s: 0.2 * len(s))
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=5, threshold=0.01))
    assert len(res.effectors) == 5 and len({(e.joint, e.type) for e in res.effectors}) == 5


def test_a_full_path_above_the_threshold_is_polished_by_swaps(synthetic_pose, oracle_solver):
    """The greedy's first choice (spine3's rotation) is good alone but costs 5 cm in any larger set: the
    restart (positions) is worse than that path, so a swap replaces spine3's rotation, and the path's
    per-count errors are scored again."""
    target = TargetPose.from_pose(synthetic_pose(0))
    spine3_rot = (9, int(EffectorType.ROTATION))
    solver = _Trap(oracle_solver, target.p_world, lambda s: 0.05 if spine3_rot in s and len(s) > 1 else 0.0)
    plain = recover_effectors(oracle_solver(target.p_world), target, RecoveryConfig(max_effectors=6, threshold=0))
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=6, threshold=0.0))
    assert (res.effectors[0].joint, int(res.effectors[0].type)) != spine3_rot
    assert spine3_rot not in {(e.joint, int(e.type)) for e in res.effectors} and len(res.effectors) == 6
    assert res.final_error == pytest.approx(res.errors[-1], rel=1e-5)  # errors re-scored for the new order
    assert res.final_error < plain.final_error + 0.05 - 0.01


def test_polish_off_keeps_the_plain_greedy_path(synthetic_pose, oracle_solver):
    target = TargetPose.from_pose(synthetic_pose(0))
    solver = oracle_solver(target.p_world)
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=6, threshold=0.0, polish=False))
    assert len(res.effectors) == 6 and solver.calls == 6 + 1  # one solve per greedy step, then the final pose
    assert all(b < a for a, b in zip(res.errors, res.errors[1:], strict=False))


class _CheapSolveMisleads:
    """An oracle solver (tests/conftest.py) whose cheap search solve (``refine`` given) likes spine3's rotation,
    while the full refinement (``refine=None``, the final solve) puts every joint 5 cm off in any set holding it."""

    def __init__(self, oracle_cls, target):
        self.oracle, self.refines = oracle_cls(target), []

    def solve_tensors(self, eff, betas, gender, *, refine=None):
        out = self.oracle.solve_tensors(eff, betas, gender, refine=refine)
        self.refines.append(refine)
        spine3_rot = (eff.joint == 9) & (eff.type == int(EffectorType.ROTATION))
        bad = spine3_rot.any(-1).float()[:, None, None]
        shift = -0.02 * bad if refine is not None else 0.05 * bad  # closer for the cheap solve, off when refined
        return type(out)(out.R_local, out.R_world, out.p_world + shift, out.draft, out.transl)


def test_a_hard_pose_is_searched_again_with_the_full_refinement(synthetic_pose, oracle_solver):
    """The cheap search solve picks spine3's rotation, which the final (fully refined) solve leaves 5 cm off: the
    path ends above ``polish_above``, so the search runs again scored with the solver's own refinement and the
    result avoids it; below ``polish_above`` the cheap path is kept as it is (no extra solve)."""
    target = TargetPose.from_pose(synthetic_pose(0))
    spine3_rot = (9, int(EffectorType.ROTATION))
    solver = _CheapSolveMisleads(oracle_solver, target.p_world)
    res = recover_effectors(solver, target, RecoveryConfig(max_effectors=6, threshold=0.0, polish_above=0.03))
    assert None in solver.refines[:-1]  # searched with the full refinement before the final solve
    assert spine3_rot not in {(e.joint, int(e.type)) for e in res.effectors} and len(res.effectors) == 6
    cheap = recover_effectors(_CheapSolveMisleads(oracle_solver, target.p_world), target,
                              RecoveryConfig(max_effectors=6, threshold=0.0, polish=False))
    assert (cheap.effectors[0].joint, int(cheap.effectors[0].type)) == spine3_rot
    assert res.final_error < cheap.final_error - 0.03
    calm = _CheapSolveMisleads(oracle_solver, target.p_world)
    kept = recover_effectors(calm, target, RecoveryConfig(max_effectors=6, threshold=0.0, polish_above=1.0))
    assert [(e.joint, e.type) for e in kept.effectors] == [(e.joint, e.type) for e in cheap.effectors]
    assert len(calm.refines) == 6 + 1 and calm.refines[:-1].count(None) == 0
