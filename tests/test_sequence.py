"""Sequence solving (:mod:`smplik.sequence`) and the default cleaning built on it (``sequence_clean``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, EffectorType, Gender
from smplik.effectors import EffectorBatch
from smplik.sequence import SequenceConfig, SequenceError, smooth_trajectories, solve_sequence
from workflows.animation.clean import CleanConfig, foot_skating, jitter, sequence_clean
from workflows.animation.clips import joints_of, rest_joints


def _accel(p: np.ndarray) -> np.ndarray:
    return p[2:] - 2.0 * p[1:-1] + p[:-2]


def test_smooth_trajectories_is_the_weighted_whittaker_solution():
    rng = np.random.default_rng(0)
    T, K = 40, 3
    y = rng.normal(size=(T, K, 3))
    w = rng.uniform(0.5, 5.0, size=(T, K))
    z = smooth_trajectories(y, w, 7.0)
    D = np.diff(np.eye(T), n=2, axis=0)  # (T-2, T) second difference
    for k in range(K):
        expected = np.linalg.solve(np.diag(w[:, k]) + 7.0 * D.T @ D, w[:, k, None] * y[:, k])
        np.testing.assert_allclose(z[:, k], expected, atol=1e-10)
    assert np.array_equal(smooth_trajectories(y, w, 0.0), y)
    assert np.array_equal(smooth_trajectories(y[:2], w[:2], 5.0), y[:2])
    with pytest.raises(SequenceError, match="do not match"):
        smooth_trajectories(y, w[:-1], 1.0)


def _true_motion(T: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth motion: local rotations (T, 24, 3, 3), transl (T, 3), rest joints (24, 3)."""
    t = np.arange(T) / 30.0
    aa = np.zeros((T, 24, 3))
    aa[:, 1:, 0] = 0.3 * np.sin(2 * np.pi * 0.7 * t)[:, None] * np.linspace(0.2, 1.0, 23)
    aa[:, 16, 2], aa[:, 17, 2] = -1.0, 1.0
    transl = np.stack([0.5 * t, 0.9 + 0 * t, 0 * t], -1)
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    return R, transl, rest_joints(np.zeros(10), Gender.NEUTRAL)


def test_sequence_solve_beats_frame_wise_poses_on_mpjpe_and_acceleration():
    """Per-frame effectors (positions of the wrists, ankles and head: exact) with frame-wise poses that meet
    them but jitter where they leave the pose open (noise on the spine and elbows): the sequence solve is
    closer to the true motion and far smoother."""
    R_true, transl, J = _true_motion()
    T = R_true.shape[0]
    p_true = joints_of(R_true, transl, J)
    rng = np.random.default_rng(1)
    noise = np.zeros((T, 24, 3))
    noise[:, [3, 6, 9, 18, 19, 4, 5]] = rng.normal(0, 0.08, (T, 7, 3))
    R_frame = Rotation.from_rotvec(noise.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3) @ R_true
    joints = [JOINT_INDEX[n] for n in ("left_wrist", "right_wrist", "left_ankle", "right_ankle", "head")]
    eff = EffectorBatch(torch.tensor(joints).expand(T, 5), torch.full((T, 5), int(EffectorType.POSITION)),
                        torch.cat([torch.as_tensor(p_true[:, joints]), torch.zeros(T, 5, 3, dtype=torch.float64)], -1),
                        torch.zeros(T, 5, dtype=torch.float64), torch.ones(T, 5, dtype=torch.bool))
    p_frame = joints_of(R_frame, transl, J)
    R_seq, t_seq = solve_sequence(torch.as_tensor(R_frame), torch.as_tensor(transl), torch.as_tensor(J), eff)
    p_seq = joints_of(R_seq.numpy(), t_seq.numpy(), J)

    def mpjpe(p: np.ndarray) -> float:
        return float(np.linalg.norm(p - p_true, axis=-1).mean())

    def accel_err(p: np.ndarray) -> float:
        return float(np.linalg.norm(_accel(p) - _accel(p_true), axis=-1).mean())

    assert mpjpe(p_seq) < 0.8 * mpjpe(p_frame)
    assert accel_err(p_seq) < 0.5 * accel_err(p_frame)
    assert np.linalg.norm(p_seq[:, joints] - p_true[:, joints], axis=-1).mean() < 0.01  # effectors still met
    # no effectors and no smoothing needed: a smooth motion stays where it is
    R_same, t_same = solve_sequence(torch.as_tensor(R_true), torch.as_tensor(transl), torch.as_tensor(J))
    assert np.linalg.norm(joints_of(R_same.numpy(), t_same.numpy(), J) - p_true, axis=-1).mean() < 0.002


def test_sequence_solve_rejects_bad_input_with_one_line():
    R, transl, J = _true_motion(10)
    with pytest.raises(SequenceError, match="shapes do not match"):
        solve_sequence(torch.as_tensor(R), torch.as_tensor(transl[:-1]), torch.as_tensor(J))
    with pytest.raises(SequenceError, match="weights"):
        solve_sequence(torch.as_tensor(R), torch.as_tensor(transl), torch.as_tensor(J),
                       joint_weights=np.zeros((10, 24)))
    with pytest.raises(SequenceError, match="smoothness"):
        SequenceConfig(smoothness=-1.0)
    with pytest.raises(ValueError, match="smoothness must be a positive number"):
        CleanConfig(smoothness=0.0)


def test_budgeted_sequence_cleaning_lowers_jitter_and_skating_and_stays_near_the_estimate():
    """A person standing with jittery legs and arms (an estimate's noise): the sequence solve with foot locks and a
    5 mm pose budget (the earlier default, now an option) cuts jitter and skating and moves the joints by a few
    millimetres only."""
    from smplik.conventions import Gender

    rng = np.random.default_rng(3)
    T = 90
    aa = np.zeros((T, 24, 3))
    aa[:, [1, 2], 0] = -0.25
    aa[:, [4, 5], 0] = 0.5
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    aa[:, [1, 2, 4, 5, 18, 19], 0] += rng.normal(0, 0.01, (T, 6))
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    J = rest_joints(np.zeros(10), Gender.NEUTRAL)
    transl = np.zeros((T, 3))
    transl[:, 1] = 0.05
    cfg = CleanConfig(smoothing="sequence", pose_budget_mm=5.0)  # the earlier default, now an option
    p_raw = joints_of(R, transl, J)
    R_c, t_c, contacts = sequence_clean(R, transl, J, 30.0, cfg)
    p_clean = joints_of(R_c, t_c, J)
    assert contacts.mean() > 0.9
    assert jitter(p_clean) < 0.5 * jitter(p_raw)
    assert foot_skating(p_clean, contacts) < 0.2 * foot_skating(p_raw, contacts)
    assert np.linalg.norm(p_clean - p_raw, axis=-1).mean() < 0.005


def test_sequence_solve_is_the_same_in_chunks_and_on_either_refinement_backend(monkeypatch):
    import smplik.sequence as sequence
    from smplik.refine import numba_available, refine_backend

    R, transl, J = _true_motion(30)
    rng = np.random.default_rng(5)
    noisy = Rotation.from_rotvec(rng.normal(0, 0.05, (30 * 24, 3))).as_matrix().reshape(30, 24, 3, 3) @ R
    args = (torch.as_tensor(noisy), torch.as_tensor(transl), torch.as_tensor(J))
    whole = solve_sequence(*args)
    monkeypatch.setattr(sequence, "REFINE_CHUNK", 7)
    chunked = solve_sequence(*args)
    for a, b in zip(whole, chunked, strict=True):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=0)
    if numba_available():
        with refine_backend("reference"):
            reference = solve_sequence(*args)
        torch.testing.assert_close(reference[1], whole[1], atol=1e-5, rtol=0)
        assert (reference[0] - whole[0]).abs().max() < 1e-4


def test_foot_locks_and_smoothing_fit_the_pose_budget_together():
    """Locks move the legs too: where the budgeted smoothing plus the locks would exceed the pose budget, the
    smoothing is lowered until both fit (a noisy standing estimate whose feet are locked all along)."""
    import dataclasses

    from smplik.conventions import Gender
    from workflows.animation.clean import budgeted_smoothness

    rng = np.random.default_rng(4)
    T = 60
    aa = np.zeros((T, 24, 3))
    aa[:, [1, 2], 0], aa[:, [4, 5], 0] = -0.25, 0.5
    aa[:, [1, 2, 4, 5, 7, 8], :] += rng.normal(0, 0.03, (T, 6, 3))  # jittery legs
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    J = rest_joints(np.zeros(10), Gender.NEUTRAL)
    transl = np.tile([0.0, 0.05, 0.0], (T, 1))
    cfg = CleanConfig(pose_budget_mm=5.0, contact_speed_mps=3.0)  # the feet are locked in every frame
    p_raw = joints_of(R, transl, J)

    def change_mm(R_c, t_c):
        p = joints_of(R_c, t_c, J)
        return 1000 * np.linalg.norm(p - p[:, :1] - (p_raw - p_raw[:, :1]), axis=-1).mean()

    R_c, t_c, contacts = sequence_clean(R, transl, J, 30.0, cfg)
    assert contacts.mean() > 0.9 and change_mm(R_c, t_c) <= 5.0
    # the smoothing budgeted on the paths alone, with the locks on top, goes over
    alone = dataclasses.replace(cfg, smoothness=budgeted_smoothness(p_raw, cfg), pose_budget_mm=None)
    assert change_mm(*sequence_clean(R, transl, J, 30.0, alone)[:2]) > 5.0
