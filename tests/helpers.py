"""Helpers shared by several test modules (no tests here): an OpenGL check and the demo's two-person scene."""

from __future__ import annotations

import os

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
