"""The ``smplik`` command tree, built explicitly from each component's command group."""

from __future__ import annotations

import os

import typer

from shape_inversion.cli import invert_shape
from smplik.cli.benchmark import app as benchmark_app
from smplik.cli.body import body_app
from smplik.cli.errors import run_guarded
from smplik.cli.solve import solve_command
from smplik.cli.train import average_command, export_command, train_command
from smplik.data.cli import app as data_app
from workflows.cli import demo_cmd, scene_app
from workflows.editor.cli import edit_cmd

app = typer.Typer(help="Morphology-aware learned IK on the SMPL body model.", no_args_is_help=True,
                  pretty_exceptions_enable=False)
app.add_typer(body_app, name="body")
app.add_typer(data_app, name="data")
app.add_typer(benchmark_app, name="benchmark")
app.add_typer(scene_app, name="scene")
app.command("train")(train_command)
app.command("export-model")(export_command)
app.command("average-models")(average_command)
app.command("solve")(solve_command)
app.command("invert-shape")(invert_shape)
app.command("demo")(demo_cmd)
app.command("edit")(edit_cmd)


def main() -> None:
    """Console-script entry point."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless rendering by default
    run_guarded(app)  # a user's mistake: one stderr line, exit 1; a bug: its traceback
