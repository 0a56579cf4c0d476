"""Helpers shared by several test modules (no tests here): an OpenGL check, the demo's two-person scene, the
shipped model and onnxruntime checks, random effector batches and a tiny SMPL-like model file's arrays."""

from __future__ import annotations

import os
from importlib import resources

import pytest


def can_render() -> bool:
    """Whether offscreen rendering works here (EGL or OSMesa)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        from smplik.render import Sphere, render

        render([], [Sphere((0, 0, 0))], size=(32, 32))
        return True
    except Exception:  # noqa: BLE001 - no OpenGL backend on this machine
        return False


needs_gl = pytest.mark.skipif(not can_render(), reason="no OpenGL backend for offscreen rendering: install EGL "
                              "(apt-get install libegl1) or OSMesa")
"""Skip a test that renders when :func:`can_render` is False."""


def demo_scene(solver):  # noqa: ANN001, ANN201 - an IKSolver -> workflows.scene.Scene
    """The demo's two people, recovered (4 effectors each, threshold 0) as ``scene from-estimate`` does."""
    from workflows.estimators.base import EstimatedPerson
    from workflows.examples_gen import example_poses
    from workflows.scene.pipeline import scene_from_people
    from workflows.scene.recovery import RecoveryConfig

    people = [EstimatedPerson(p.pose.global_orient, p.pose.body_pose, p.pose.transl, p.pose.betas, p.pose.gender,
                              person_id=str(i)) for i, p in enumerate(example_poses())]
    built, _ = scene_from_people(people, solver, config=RecoveryConfig(max_effectors=4, threshold=0.0))
    return built


SHIPPED = resources.files("smplik") / "checkpoints" / "smplik_cmu.pt"
needs_shipped = pytest.mark.skipif(not SHIPPED.is_file(),
                                   reason="shipped model smplik/checkpoints/smplik_cmu.pt absent")


def _ort_installed() -> bool:
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


needs_ort = pytest.mark.skipif(not _ort_installed(),
                               reason="onnxruntime/onnx not installed (pip install 'smplik[fast]')")


def random_effectors(bodies, B: int, N: int, seed: int):  # noqa: ANN001, ANN201 - (EffectorBatch, betas, gender)
    """B rows of up to N effectors of all three types from random posed bodies; rows padded at random."""
    import torch

    from smplik.effectors import EffectorBatch
    from smplik.rotations import axis_angle_to_matrix
    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(B, 10, generator=g)
    gender = torch.randint(0, 3, (B,), generator=g)
    from smplik.kinematics import forward_kinematics

    R_world, p_world = forward_kinematics(axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g) * 0.3),
                                          bodies.rest_joints(betas, gender), torch.randn(B, 3, generator=g) * 0.3)
    joint = torch.randint(0, 24, (B, N), generator=g)
    kind = torch.randint(0, 3, (B, N), generator=g)
    rows = torch.arange(B)[:, None]
    p, R = p_world[rows, joint], R_world[rows, joint]
    direction = torch.nn.functional.normalize(torch.randn(B, N, 3, generator=g), dim=-1)
    look_target = p + 1.5 * (R @ direction[..., None])[..., 0]
    data = torch.where((kind == 0)[..., None], torch.cat([p, torch.zeros_like(p)], -1),
                       torch.where((kind == 1)[..., None], torch.cat([R[..., 0], R[..., 1]], -1),
                                   torch.cat([look_target, direction], -1)))
    count = torch.randint(1, N + 1, (B,), generator=g)
    mask = torch.arange(N)[None] < count[:, None]
    tolerance = torch.rand(B, N, generator=g) * 0.5 * (torch.rand(B, N, generator=g) < 0.3)
    eff = EffectorBatch(joint, kind, data * mask[..., None], tolerance * mask, mask)
    return eff, betas, gender


def tiny_smpl_arrays(V: int = 30, seed: int = 0) -> dict:
    """The arrays of a random SMPL-like body model file with V vertices (SMPL's keys and shapes)."""
    import numpy as np

    from smplik.conventions import PARENTS

    rng = np.random.default_rng(seed)
    J_reg = rng.random((24, V))
    J_reg /= J_reg.sum(1, keepdims=True)
    weights = rng.random((V, 24))
    weights /= weights.sum(1, keepdims=True)
    kintree = np.stack([np.array([4294967295] + list(PARENTS[1:]), dtype=np.int64), np.arange(24)])
    return {
        "v_template": rng.normal(size=(V, 3)),
        "shapedirs": rng.normal(size=(V, 3, 10)) * 0.01,
        "posedirs": np.zeros((V, 3, 207)),
        "J_regressor": J_reg,
        "weights": weights,
        "kintree_table": kintree,
        "f": rng.integers(0, V, size=(40, 3)),
    }
