"""``smplik export-model`` and ``smplik average-models``: model files from checkpoints (torch is imported
only when a command runs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from smplik.cli.errors import fail


def average_command(
    models: Annotated[list[Path], typer.Argument(help="Two or more model files or checkpoints of one architecture, "
                                                 "fine-tuned from the same start.")],
    out: Annotated[Path, typer.Option("--out", help="Model file to write (the uniform average of the weights).")],
    full_precision: Annotated[bool, typer.Option(help="Keep fp32 weights (default: fp16).")] = False,
) -> None:
    """Average the weights of models fine-tuned from one start (a model soup); calibrate the result anew."""
    from smplik.model_io import CheckpointError, average_models

    try:
        average_models(models, out, half=not full_precision)
    except (FileNotFoundError, CheckpointError, ValueError) as exc:
        fail(exc)
    typer.echo(f"wrote {out} (average of {len(models)} models)")


def export_command(
    checkpoint: Annotated[Path, typer.Argument(help="Training checkpoint (RUN_DIR/checkpoint.pt) or model file.")],
    out: Annotated[Path | None, typer.Option(
        "--out", help="Compact model file for `smplik solve --checkpoint`.")] = None,
    full_precision: Annotated[bool, typer.Option(help="Keep fp32 weights (default: fp16).")] = False,
    onnx: Annotated[Path | None, typer.Option("--onnx", help="Also (or only) write the network + FK as ONNX "
                                              "(opset 15, dynamic batch and effector count; needs smplik[fast]). "
                                              "With --out it is exported from that file's weights.")] = None,
    legacy: Annotated[bool, typer.Option("--legacy", help="Read an older smplik file whose metadata holds numpy "
                                         "values (still the restricted loader: runs no code) and write it in "
                                         "the current format.")] = False,
) -> None:
    """Write a compact inference model (fp16 weights by default) from a checkpoint (converts old files),
    and/or its ONNX graph."""
    from smplik.model_io import CheckpointError, export_model

    if out is None and onnx is None:
        fail("nothing to write; give --out FILE.pt and/or --onnx FILE.onnx.")
    if out is not None:
        try:
            export_model(checkpoint, out, half=not full_precision, legacy=legacy)
        except (FileNotFoundError, CheckpointError) as exc:
            fail(exc)
        typer.echo(f"wrote {out}")
    if onnx is not None:
        from smplik.onnx_runtime import OnnxUnavailableError, export_onnx
        from smplik.solver import IKSolver

        try:
            solver = IKSolver.load(out or checkpoint, runtime="torch")
            export_onnx(solver.model, onnx, meta={"source": solver.source, "step": solver.meta.get("step"),
                                                  "body_fingerprint": solver.bodies.fingerprint})
        except (FileNotFoundError, ValueError, OnnxUnavailableError) as exc:
            fail(exc)
        typer.echo(f"wrote {onnx}")
