"""``smplik scene ...`` (editable scenes from estimator outputs) and ``smplik demo`` (the whole chain)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

scene_app = typer.Typer(help="Editable scenes: from estimator outputs, re-solve after edits, render.",
                        no_args_is_help=True)
demo_app = typer.Typer(help="End-to-end demo on built-in material.")
console = Console(stderr=True)

Checkpoint = Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: the shipped model).")]
FORMATS = ("auto", "romp", "bev", "hybrik", "phalp", "wham", "pymafx", "gvhmr", "aist", "amass", "plain")


def _solver(checkpoint: Path | None):
    import torch

    from smplik.solver import IKSolver

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    try:
        return IKSolver.load(checkpoint)
    except (FileNotFoundError, ValueError) as exc:
        _fail(exc)


def _fail(exc: Exception) -> None:
    from rich.markup import escape

    message = " ".join(str(exc).split())  # one line
    console.print(f"[red]error:[/red] {escape(message)}", soft_wrap=True, markup=True, highlight=False)
    raise typer.Exit(1) from None


@scene_app.command("from-estimate")
def from_estimate_cmd(
    results: Annotated[Path, typer.Argument(help="Estimator output (.npz, .pk, .pkl, .json, .pt).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    format: Annotated[str, typer.Option("--format", help=f"One of: {', '.join(FORMATS)}.")] = "auto",
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON).")] = None,
    rig: Annotated[str | None, typer.Option("--rig", help="Rig preset of --character (default: detected).")] = None,
    max_effectors: Annotated[int, typer.Option("--max-effectors", min=1, help="Most effectors per person.")] = 8,
    threshold: Annotated[float, typer.Option("--threshold", min=0.0, help="Stop below this error (m).")] = 0.02,
    trust_pickle: Annotated[bool, typer.Option("--trust-pickle", help="Load pickles with plain joblib/pickle "
                                               "(runs code from the file; only for trusted files).")] = False,
    image: Annotated[Path | None, typer.Option("--image", help="Source image for the overlay preview.")] = None,
    frame: Annotated[int, typer.Option("--frame", min=0, help="Video frame whose people make the scene (one "
                                       "character per track id); single-image files have only frame 0.")] = 0,
    ground: Annotated[bool, typer.Option("--ground", help="Put the people on a floor (lowest point at y = 0; "
                                         "the camera is raised with them, recorded in scene.json).")] = False,
    max_people: Annotated[int, typer.Option("--max-people", min=1, help="Refuse files with more people in "
                                            "the frame than this.")] = 100,
    max_bytes: Annotated[int, typer.Option("--max-bytes", min=1, help="Refuse estimator files whose data is "
                                           "larger than this uncompressed (bytes).")] = 1 << 30,
    space: Annotated[str | None, typer.Option("--space", help="WHAM / GVHMR: 'camera' or 'world' output "
                                              "(default: WHAM world, GVHMR camera).")] = None,
    checkpoint: Checkpoint = None,
    no_previews: Annotated[bool, typer.Option("--no-previews", help="Skip the PNG previews.")] = False,
) -> None:
    """Estimator output -> SMPL-SI (with --character) -> effector recovery -> OUT/scene.json (+ previews, BVH)."""
    from rich.progress import Progress

    from smplik.render import RenderError
    from workflows.pipeline import from_estimate
    from workflows.recovery import RecoveryConfig

    if format not in FORMATS:
        raise typer.BadParameter(f"--format must be one of {', '.join(FORMATS)}, got {format!r}.")
    if space not in (None, "camera", "world"):
        raise typer.BadParameter(f"--space must be 'camera' or 'world', got {space!r}.")
    solver = _solver(checkpoint)
    try:
        with Progress(console=console, transient=True) as bar:
            task = bar.add_task("effector recovery", total=None)

            def progress(done: int, total: int, what: str) -> None:
                bar.update(task, completed=done, total=total, description=f"effector recovery ({what})")

            outputs = from_estimate(results, out, solver, format=format, character_path=character, rig=rig,
                                    config=RecoveryConfig(max_effectors=max_effectors, threshold=threshold),
                                    trust_pickle=trust_pickle, image_path=image, frame=frame,
                                    previews=not no_previews, max_people=max_people, max_bytes=max_bytes, ground=ground,
                                    space=space,
                                    progress=progress)
    except (ValueError, OSError, RenderError) as exc:
        _fail(exc)
    for r in outputs.results:
        errs = ", ".join(f"{e * 1000:.0f}" for e in r.recovery.errors)
        console.print(f"{r.name}: {len(r.recovery.effectors)} effectors, error after each (mm): {errs}; "
                      f"final pose {r.recovery.final_error * 1000:.0f} mm")
    for path in outputs.all_files:
        console.print(f"wrote {path}")


@scene_app.command("solve")
def solve_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path | None, typer.Option("--out", help="Output scene (default: overwrite SCENE).")] = None,
    checkpoint: Checkpoint = None,
) -> None:
    """Re-solve every character from its (edited) effectors and shape."""
    from workflows.scene import load_scene, save_scene, solve_scene

    try:
        loaded = load_scene(scene)
    except ValueError as exc:
        _fail(exc)
    try:
        solved = solve_scene(loaded, _solver(checkpoint))
    except ValueError as exc:
        _fail(exc)
    path = save_scene(solved, out or scene)
    console.print(f"wrote {path}")


@scene_app.command("render")
def render_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path, typer.Option("--out", help="Output PNG.")],
    image: Annotated[Path | None, typer.Option("--image", help="Background image (default: the scene's).")] = None,
) -> None:
    """Render all characters with their effector markers (over the source image when known)."""
    from smplik.render import RenderError, save_png
    from workflows.previews import load_image, render_scene
    from workflows.scene import load_scene

    try:
        loaded = load_scene(scene)
    except ValueError as exc:
        _fail(exc)
    src = image or (Path(loaded.image) if loaded.image else None)
    if src is not None and not src.is_absolute() and image is None:
        src = scene.parent / src
    background = load_image(src) if src is not None and src.is_file() and loaded.camera is not None else None
    try:
        save_png(render_scene(loaded, image=background), out)
    except RenderError as exc:
        _fail(exc)
    console.print(f"wrote {out}")


@demo_app.command("demo")
def demo_cmd(
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    checkpoint: Checkpoint = None,
) -> None:
    """Whole chain on built-in material: estimator file -> SMPL-SI character -> effector recovery -> scene, BVH."""
    from smplik.render import RenderError
    from workflows.demo import run_demo

    solver = _solver(checkpoint)
    try:
        outputs = run_demo(out, solver)
    except (ValueError, OSError, RenderError) as exc:
        _fail(exc)
    for r in outputs.smpl.results + outputs.character.results:
        errs = ", ".join(f"{e * 1000:.0f}" for e in r.recovery.errors)
        console.print(f"{r.name}: effectors {[f'{e.joint_name}:{e.type.name.lower()}' for e in r.recovery.effectors]}"
                      f"; error after each (mm): {errs}; final pose {r.recovery.final_error * 1000:.0f} mm")
    for path in outputs.all_files:
        console.print(f"wrote {path}")
