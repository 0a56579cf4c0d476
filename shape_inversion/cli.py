"""``smplik invert-shape``: estimate SMPL shape and scale for a custom character's skeleton.

``app`` is a :class:`typer.Typer` holding the one command; the top-level CLI mounts it.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Annotated

import typer

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.conventions import Gender

app = typer.Typer(help="SMPL-SI: custom skeleton -> SMPL shape (beta) and scale.", no_args_is_help=True,
                  pretty_exceptions_enable=False)


def shape_payload(character, estimate, model, *, rest: str, elapsed_s: float) -> dict:
    """The SHAPE.json content: the estimate plus where it came from and how well it fits."""
    out = estimate.to_dict()
    out["format"] = "smplik.shape/1"
    out["body_model"] = {"source": model.source, "fingerprint": model.fingerprint}
    out["character"] = {
        "source": character.skeleton.source,
        "format": character.skeleton.format,
        "rest": (character.skeleton.rest or rest) if character.skeleton.format in ("bvh", "fbx") else None,
        "rig": character.rig.name,
        "units_m": character.units_m,
        "units_source": character.units_source,
        "up": character.up,
        "head_ankle_height_m": character.head_ankle_height_m,
        "height_m": character.height_m,
        "joint_map": character.joint_map,
        "root": character.rig.root,
        "map_warnings": list(character.rig.warnings),
    }
    out["diagnostics"]["query_time_s"] = elapsed_s
    return out


def joint_fit_note(character, estimate) -> str:
    """One line: the mapped rest joints' mean distance from the SMPL body (% of the stature), and the stage kept."""
    import math

    if not math.isfinite(estimate.rest_joint_residual_m):
        return ""
    stature = character.head_ankle_height_m / 0.84
    first, last = (100 * r / stature for r in (estimate.first_stage_rest_joint_residual_m,
                                                estimate.rest_joint_residual_m))
    if estimate.joint_fit:
        return f"joint fit: rest joints {last:.1f} % of the stature from the SMPL body (six features: {first:.1f} %)"
    return f"joint fit not kept: rest joints {first:.1f} % of the stature from the SMPL body (six features)"


@app.command("invert-shape")
@with_character_options
def invert_shape(
    character: Annotated[Path, typer.Argument(help="Skeleton file: .bvh, .glb/.gltf, .vrm or .json of named joints.",
                                              exists=True, dir_okay=False)],
    out: Annotated[Path, typer.Option("--out", help="Output SHAPE.json (betas, scale, gender, diagnostics).")],
    gender: Annotated[Gender, typer.Option("--gender", case_sensitive=False, help="Body model gender.")]
    = Gender.NEUTRAL,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
    render_png: Annotated[Path | None, typer.Option("--render", help="Also write a comparison PNG.")] = None,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files "
                                                      "(default: $SMPLIK_MODEL_DIR, else the built-in model).")]
    = None,
    bank_samples: Annotated[int, typer.Option("--bank-samples", hidden=True, help="Bank size per gender (tests).")]
    = 20_000,
    refine: Annotated[bool, typer.Option("--refine", help="Polish the kernel estimate to match the six bone "
                                         "features to ~1 mm (may push unobserved betas to extremes).")] = False,
) -> None:
    """Estimate SMPL beta and scale for CHARACTER and write them to --out."""
    from rich.console import Console
    from rich.markup import escape

    from shape_inversion.bank import BankConfig
    from shape_inversion.estimator import EstimatorConfig, ShapeEstimator
    from shape_inversion.skeleton_io import read_character
    from smplik.atomic import write_json_atomic
    from smplik.body_model import load_body_model

    console = Console(stderr=True, soft_wrap=True)  # a status line is never cut mid-number
    options = character_cli()
    try:
        char = read_character(character, options)
        model = load_body_model(gender, model_dir)
        estimator = ShapeEstimator.build(model, BankConfig(num_samples=bank_samples),
                                         EstimatorConfig(refine=refine))
        start = time.perf_counter()
        with warnings.catch_warnings():  # its notes are printed below, once
            warnings.simplefilter("ignore")
            estimate = estimator.estimate(char.features, char.mapped_rest())
        elapsed = time.perf_counter() - start
    except ValueError as exc:  # SkeletonError, RigError, ShapeInversionError, ModelFileError
        console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)
        raise typer.Exit(code=1) from None
    payload = shape_payload(char, estimate, model, rest=options.rest, elapsed_s=elapsed)
    payload["character"]["options"] = options.to_dict()
    for line in char.map_report():  # the map chosen, and the mapper's doubts
        console.print(escape(line), soft_wrap=True, highlight=False)
    for note in estimate.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(note)}", soft_wrap=True)
    write_json_atomic(out, payload)
    if note := joint_fit_note(char, estimate):
        console.print(note, soft_wrap=True, highlight=False)
    console.print(f"rig {char.rig.name}, units {char.units_m:g} m ({char.units_source}), up {char.up}; "
                  f"scale {estimate.scale:.3f}, max feature residual {estimate.max_feature_residual_m * 1000:.2f} mm, "
                  f"effective samples {estimate.effective_samples:.1f} -> {out}")
    if render_png is not None:
        from shape_inversion.preview import render_comparison
        from smplik.render import RenderError, save_png

        try:
            save_png(render_comparison(char, estimate, model), render_png)
        except RenderError as exc:
            console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)
            raise typer.Exit(code=1) from None
        console.print(f"render -> {render_png}")


def main() -> None:  # pragma: no cover - convenience entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
