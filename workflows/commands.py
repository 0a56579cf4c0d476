"""The ``smplik`` command table: every top-level command, its loader and its one-line help.

It lives at the top layer because its commands come from all three packages; each loader imports its command's
module with a real import (inside the function: ``smplik --help`` imports none of them), so every command's
dependencies are edges the layering test (``tests/test_architecture.py``) sees. The entry point
(:mod:`smplik.cli.main`) reads this table. To add a command, write a loader and add one row to :data:`COMMANDS`.
Importing this module imports no numpy or torch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["COMMANDS", "load_command"]


def _demo() -> Any:
    from workflows.cli import demo_cmd

    return demo_cmd


def _solve() -> Any:
    from smplik.cli.solve import solve_command

    return solve_command


def _scene() -> Any:
    from workflows.cli import scene_app

    return scene_app


def _edit() -> Any:
    from workflows.editor.cli import edit_cmd

    return edit_cmd


def _invert_shape() -> Any:
    from shape_inversion.cli import invert_shape

    return invert_shape


def _body() -> Any:
    from smplik.cli.body import body_app

    return body_app


def _data() -> Any:
    from shape_inversion.data_cli import app

    return app


def _train() -> Any:
    from smplik.cli.train import train_command

    return train_command


def _track_train() -> Any:
    from smplik.cli.track_train import track_train_command

    return track_train_command


def _export_model() -> Any:
    from smplik.cli.models import export_command

    return export_command


def _average_models() -> Any:
    from smplik.cli.models import average_command

    return average_command


def _benchmark() -> Any:
    from workflows.benchmark_cli import app

    return app


def _track() -> Any:
    from workflows.tracking.cli import track_cmd

    return track_cmd


def _batch() -> Any:
    from workflows.batch.cli import app

    return app


COMMANDS: dict[str, tuple[Callable[[], Any], str]] = {
    # name: (loader returning a typer command function or a typer.Typer group, one-line help)
    "demo": (_demo, "The whole chain on built-in material: estimator file -> scenes, BVH."),
    "solve": (_solve, "Solve an SMPL pose for the effectors in a JSON file."),
    "scene": (_scene, "Editable scenes: from estimator outputs, re-solve, render, export."),
    "edit": (_edit, "Edit a scene in the browser (needs the edit extra: viser)."),
    "invert-shape": (_invert_shape, "SMPL-SI: custom skeleton -> SMPL shape (beta) and scale."),
    "body": (_body, "Body models: export, inspect and render."),
    "data": (_data, "Motion data: build pose caches from BVH/AMASS, preview retargeting."),
    "train": (_train, "Train SMPL-IK on a pose cache (resumable; torchrun for DDP)."),
    "track-train": (_track_train, "Train the tracking model (VR trackers -> body) on a 60 Hz pose cache."),
    "export-model": (_export_model, "Compact inference model and/or ONNX graph of a checkpoint."),
    "average-models": (_average_models, "Average models fine-tuned from one start (model soup)."),
    "benchmark": (_benchmark, "Randomized-effector IK benchmark: make files, run methods, calibrate."),
    "track": (_track, "Full body from VR trackers (head, wrists, pelvis) -> animation."),
    "batch": (_batch, "One job over many inputs (folder, glob, manifest): local pool or Ray."),
}
"""Every top-level command, in the order ``smplik --help`` lists them."""


def load_command(name: str) -> Any:
    """Import the command ``name`` of :data:`COMMANDS` and return it as a click command of the tree."""
    from smplik.cli.tree import click_command

    return click_command(COMMANDS[name][0](), name)
