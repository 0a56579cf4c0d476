"""``smplik scene ...`` (editable scenes from estimator outputs) and ``smplik demo`` (the whole chain)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.cli.errors import fail, say, user_errors
from smplik.cli.options import check_image
from workflows import cli_shared

scene_app = typer.Typer(help="Editable scenes: from estimator outputs, re-solve after edits, render.",
                        no_args_is_help=True)
demo_app = typer.Typer(help="End-to-end demo on built-in material.")

Checkpoint = Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: the shipped model).")]
FORMATS = ("auto", "romp", "bev", "hybrik", "phalp", "wham", "pymafx", "vibe", "gvhmr", "glamr", "aist", "amass",
           "sam3d", "easymocap", "tram", "smplerx", "agora", "humandata", "smplifyx", "plain", "pose_array")
"""``--format`` choices (spelled out here so that ``--help`` does not import the readers; a test keeps them equal)."""


@scene_app.command("from-estimate")
@with_character_options
def from_estimate_cmd(
    results: Annotated[Path, typer.Argument(help="Estimator output (.npz, .pk, .pkl, .json, .pt), or a folder of "
                                            "per-frame outputs (SMPLer-X; --frame N).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    format: Annotated[str, typer.Option("--format", help=f"One of: {', '.join(FORMATS)}.")] = "auto",
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON).")] = None,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
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
    space: Annotated[str | None, typer.Option("--space", help="WHAM / GVHMR / GLAMR / TRAM: 'camera' or "
                                              "'world' output (default: WHAM, GLAMR world; GVHMR, TRAM "
                                              "camera).")] = None,
    focal: Annotated[float | None, typer.Option("--focal", min=0.0, help="Focal length (pixels of --image) for "
                                                "the overlay; gives a camera to files without one.")] = None,
    checkpoint: Checkpoint = None,
    no_previews: Annotated[bool, typer.Option("--no-previews", help="Skip the PNG previews.")] = False,
) -> None:
    """Estimator output -> SMPL-SI (with --character) -> effector recovery -> OUT/scene.json (+ previews, BVH)."""
    from rich.progress import Progress

    from smplik.cli.errors import console
    from workflows.scene.pipeline import from_estimate
    from workflows.scene.recovery import RecoveryConfig

    if format not in FORMATS:
        raise typer.BadParameter(f"--format must be one of {', '.join(FORMATS)}, got {format!r}.")
    if space not in (None, "camera", "world"):
        raise typer.BadParameter(f"--space must be 'camera' or 'world', got {space!r}.")
    with user_errors():
        check_image(image)
    options = character_cli()
    solver = cli_shared._solver(checkpoint)
    with user_errors(), Progress(console=console, transient=True, disable=not console.is_terminal) as bar:
        task = bar.add_task("effector recovery", total=None)

        def progress(done: int, total: int, name: str) -> None:
            bar.update(task, completed=done, total=total, description=f"effector recovery ({name})")

        outputs = from_estimate(results, out, solver, format=format, character_path=character,
                                character_options=options,
                                config=RecoveryConfig(max_effectors=max_effectors, threshold=threshold),
                                trust_pickle=trust_pickle, image_path=image, frame=frame,
                                previews=not no_previews, max_people=max_people, max_bytes=max_bytes, ground=ground,
                                space=space, focal=focal, progress=progress)
    for note in outputs.notes:
        say(note)
    if outputs.character is not None:  # the map chosen, the mapper's and SMPL-SI's doubts
        for line in outputs.character.character.map_report():
            say(line)
        for note in outputs.character.estimate.warnings:
            say(f"warning: {note}")
    for r in outputs.results:
        errs = ", ".join(f"{e * 1000:.0f}" for e in r.recovery.errors)
        say(f"{r.name}: {len(r.recovery.effectors)} effectors, error after each (mm): {errs}; "
                      f"final pose {r.recovery.final_error * 1000:.0f} mm")
    for path in outputs.all_files:
        say(f"wrote {path}")


@scene_app.command("solve")
def solve_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path | None, typer.Option("--out", help="Output scene (default: overwrite SCENE).")] = None,
    exact: Annotated[bool, typer.Option("--exact", help="Re-solve every effector exactly from scratch instead of "
                                        "solving the changed ones as drags.")] = False,
    checkpoint: Checkpoint = None,
) -> None:
    """Re-solve a scene after its effectors were edited: the effectors its stored pose does not meet (the ones
    you changed) are solved as the editor's drags (the stale effectors of their chains relaxed, the rest of the
    body kept); print what moved and what was relaxed, then each effector's residual and conflicts."""
    from workflows.scene import load_scene, save_scene
    from workflows.scene.edits import conflict_report, solve_scene_edits

    with user_errors():
        loaded = load_scene(scene)
        solver = cli_shared._solver(checkpoint)
        solved, reports = solve_scene_edits(loaded, solver, exact=exact)
        path = save_scene(solved, out or scene)
        lines = {r.character: r.line() for r in reports}
        for c in solved.characters:
            if not c.effectors:
                say(f"{c.name}: no effectors, pose unchanged")
                continue
            say(lines[c.name])
            for line in conflict_report(c, solver).lines():  # residuals, effectors not met and what they contradict
                say(line)
    say(f"wrote {path}")


@scene_app.command("variants")
def variants_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (variant_0.json, variant_1.json, ...).")],
    k: Annotated[int, typer.Option("--k", min=1, max=64, help="Number of variants (variant 0: the plain solve).")] = 4,
    character: Annotated[str | None, typer.Option("--character", help="Character whose effectors get variants "
                                                  "(default: the first with effectors).")] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the random guide effectors.")] = 0,
    candidates: Annotated[int, typer.Option("--candidates", min=1, max=1024,
                                            help="Guided effector sets tried (one batch).")] = 32,
    checkpoint: Checkpoint = None,
) -> None:
    """K alternative poses of one character for its effectors: OUT/variant_I.json, each the scene with that
    character's effectors + the variant's guide effectors and the variant's pose (variant 0: the plain solve)."""
    from smplik.output_files import staged_folder
    from workflows.scene.export import scene_reads
    from workflows.scene.variants import scene_variants, write_variants

    with user_errors():
        from workflows.scene import load_scene

        loaded = load_scene(scene)
        reads = [scene, checkpoint, *scene_reads(loaded, scene.resolve().parent)]
        with staged_folder(out, reads=reads) as stage:  # every variant or none; none of them an input
            stage.check([f"variant_{i}.json" for i in range(k)])  # before any work
            solver = cli_shared._solver(checkpoint)
            scenes, name = scene_variants(loaded, solver, k=k, character=character, seed=seed,
                                          candidates=candidates)
            paths = [stage.final(p) for p in write_variants(scenes, stage.dir)]
    if len(paths) < k:
        say(f"notice: {name}'s effectors leave room for only {len(paths)} distinct plausible variant(s) of {k}.")
    for i, (path, (_, guides, dist)) in enumerate(zip(paths, scenes, strict=True)):
        what = "the plain solve" if i == 0 else f"{guides} guide effector(s), joints {100 * dist:.1f} cm from variant 0"
        say(f"wrote {path} ({name}: {what})")


@scene_app.command("render")
def render_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path, typer.Option("--out", help="Output PNG.")],
    image: Annotated[Path | None, typer.Option("--image", help="Background image (default: the scene's).")] = None,
) -> None:
    """Render all characters with their effector markers (over the source image when known)."""
    from smplik.render import save_png
    from workflows.scene import load_scene
    from workflows.scene.previews import load_image, render_scene

    with user_errors():
        loaded = load_scene(scene)
        src = image or (Path(loaded.image) if loaded.image else None)
        if src is not None and not src.is_absolute() and image is None:
            src = scene.parent / src
        check_image(image)
        if src is not None and image is None and loaded.camera is not None:
            if os.path.lexists(src):  # the scene's own image: refused as --image is (a device, a folder, ...)
                check_image(src, option=f"{scene}: \"image\"")
            else:
                say(f"notice: the scene's image {src} is not there; rendering without it.")
        from smplik.output_files import check_writes
        from workflows.scene.export import scene_reads

        check_writes([out], [scene, image, src, *scene_reads(loaded, scene.resolve().parent)])
        background = None
        if image is not None and loaded.camera is None:
            say(f"notice: the scene holds no camera, so --image {image} is not drawn under the characters.")
        if src is not None and src.is_file() and loaded.camera is not None:
            from smplik.limits import LimitError

            try:
                background = load_image(src)
            except LimitError:
                raise  # over a limit: its own line (names the variable)
            except (OSError, ValueError, SyntaxError, MemoryError) as exc:  # PIL/matplotlib on a bad file
                fail(f"{src}: not a readable image ({type(exc).__name__}: {exc})")
        save_png(render_scene(loaded, image=background, base_dir=scene.resolve().parent), out)
    say(f"wrote {out}")


@scene_app.command("export")
def export_cmd(
    scene: Annotated[Path, typer.Argument(help="Scene JSON.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    format: Annotated[str, typer.Option("--format", help="Comma-separated: bvh, glb.")] = "bvh,glb",
    bvh_frame: Annotated[str, typer.Option("--bvh-frame", help="world: every BVH in the scene's world frame "
                                           "(metres, y-up, lined up with the GLBs); source: each file's own units "
                                           "and axes.")] = "world",
) -> None:
    """Per character: a posed BVH of its own skeleton and a posed GLB (its mesh, or the SMPL mesh)."""
    from smplik.output_files import staged_folder
    from workflows.scene import load_scene
    from workflows.scene.export import export_names, export_scene, glb_notes, scene_reads

    formats = [f for f in format.split(",") if f.strip()]
    with user_errors():
        loaded = load_scene(scene)
        base = scene.resolve().parent
        with staged_folder(out, reads=[scene, *scene_reads(loaded, base)]) as stage:  # all files or none
            stage.check(export_names(loaded, formats))  # before any work: no export replaces an input
            paths = [stage.final(p) for p in export_scene(loaded, stage.dir, formats=formats, base_dir=base,
                                                          bvh_frame=bvh_frame)]
    for note in glb_notes(loaded, formats, base) if paths else []:
        say(note)
    for path in paths:
        say(f"wrote {path}")
    if not paths:
        say("no posed character to export")


@demo_app.command("demo")
def demo_cmd(
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    checkpoint: Checkpoint = None,
) -> None:
    """Whole chain on built-in material: estimator file -> SMPL-SI character -> effector recovery -> scene, BVH."""
    from workflows.demo import run_demo

    solver = cli_shared._solver(checkpoint)
    with user_errors():
        outputs = run_demo(out, solver)
    for line in demo_report(outputs):
        say(line)


def demo_report(outputs) -> list[str]:  # noqa: ANN001 - workflows.demo.DemoOutputs
    """The demo's printout: each run's people and files, what each file is, and what to open first."""
    from workflows.demo import EDIT_JOINT, EDIT_RAISE_M

    def people(results) -> list[str]:  # noqa: ANN001
        lines = []
        for r in results:
            errs = ", ".join(f"{e * 1000:.0f}" for e in r.recovery.errors)
            names = ", ".join(f"{e.joint_name}:{e.type.name.lower()}" for e in r.recovery.effectors)
            lines.append(f"  {r.name}: {len(r.recovery.effectors)} effectors ({names}); mean joint error after "
                         f"each (mm): {errs}; final pose {r.recovery.final_error * 1000:.0f} mm")
        return lines

    def files(run) -> list[str]:  # noqa: ANN001 - EstimateOutputs
        what = {run.scene: "the editable scene (effectors, shapes, solved poses)"}
        what |= {p: "preview: the people over the photo, front and side views" if p.name == "scene.png"
                 else "preview: the custom character beside its SMPL body" for p in run.previews}
        what |= {p: "plot: joint error against the number of recovered effectors" for p in run.plots}
        what |= {p: "the posed custom character (its own skeleton)" for p in run.bvh}
        return [f"  {p}  {text}" for p, text in what.items()]

    smpl, character = outputs.smpl, outputs.character
    npz, photo, bvh = outputs.examples
    lines = ["generated inputs:",
             f"  {npz}  a ROMP-style estimator output of two people",
             f"  {photo}  the photo they were estimated from",
             f"  {bvh}  a Mixamo-named custom character (BVH, centimetres)",
             f"1. estimator output -> SMPL scene ({smpl.scene.parent}):", *people(smpl.results), *files(smpl),
             f"2. the same people on the custom character through SMPL-SI ({character.scene.parent}):",
             *people(character.results), *files(character),
             f"3. an edit ({character.results[0].name}'s {EDIT_JOINT} raised {EDIT_RAISE_M * 100:.0f} cm), "
             "re-solved as a drag:", *(f"  {line}" for line in outputs.edit_lines),
             f"  {outputs.edited_scene}  the edited scene"]
    if outputs.edited_preview is not None:
        lines.append(f"  {outputs.edited_preview}  its preview")
    first = next((p for p in smpl.previews if p.name == "scene.png"), smpl.scene)
    lines += [f"open first: {first} (the solved people over the photo); then edit a scene in the browser with "
              f"`smplik edit {character.scene}` or export it with `smplik scene export {smpl.scene} --out exported`"]
    return lines


# ``smplik scene animate`` (video estimates -> animations): the command lives in workflows/animation/cli.py
from workflows.animation.cli import animate_cmd, edit_keyframe_cmd  # noqa: E402

scene_app.command("animate")(animate_cmd)
scene_app.command("edit-keyframe")(edit_keyframe_cmd)
