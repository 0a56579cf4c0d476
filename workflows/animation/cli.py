"""``smplik scene animate``: a video's estimates -> per-track animations (logic in :mod:`workflows.animation`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.cli.errors import say, user_errors
from smplik.cli.options import check_fps

PLAIN_PROGRESS_FROM = 1000
"""Without a terminal (a log, a pipe), steps of at least this many items (frames, keyframes) print a progress line
every 10 %; shorter ones print nothing but their result."""


@with_character_options
def animate_cmd(
    results: Annotated[Path, typer.Argument(help="Video estimator output (GVHMR, WHAM, 4D-Humans/PHALP, HybrIK, "
                                            "AIST++, AMASS, ...), a folder of per-frame outputs (SMPLer-X), or "
                                            "joint positions (HumanML3D .npy, MDM results.npy, a BVH).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (animation.json, one BVH per track).")],
    frames: Annotated[str, typer.Option("--frames", help="'all' or A:B (frames A..B-1).")] = "all",
    fps: Annotated[float | None, typer.Option("--fps", help="Source frame rate (default: the file's; GVHMR: 30; "
                                              "needed when the format does not store it).")] = None,
    track: Annotated[str | None, typer.Option("--track", help="Only this track id (default: every track).")] = None,
    format: Annotated[str, typer.Option("--format", help="Estimator format (as in from-estimate).")] = "auto",
    space: Annotated[str | None, typer.Option("--space", help="WHAM / GVHMR: 'world' (their world trajectory, "
                                              "the default when present) or 'camera'.")] = None,
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON).")] = None,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
    smoothing: Annotated[str, typer.Option(
        "--smoothing", help="auto (the default: adaptive, each channel smoothed as its measured noise asks; none for "
        "joints a model made), adaptive, sequence (a joint-space sequence solve), one_euro, savgol or "
        "none.")] = "auto",
    smoothness: Annotated[float, typer.Option("--smoothness", help="sequence cleaning: weight of the joints' "
                                              "acceleration; higher smooths more.")] = 2.0,
    pose_budget: Annotated[float, typer.Option("--pose-budget", help="sequence cleaning: most the smoothing may "
                                               "move the pose from the estimate (pelvis-aligned MPJPE, mm); "
                                               "0: no cap.")] = 0.0,
    keep_depth: Annotated[bool, typer.Option("--keep-depth", help="Camera-space tracks of near-orthographic "
                                             "estimators (4D-Humans/PHALP): keep their depth instead of placing "
                                             "the body for a 60-degree camera.")] = False,
    foot_lock: Annotated[bool, typer.Option("--foot-lock/--no-foot-lock", help="Lock feet in contact.")] = True,
    keyframe_threshold: Annotated[float, typer.Option("--keyframe-threshold", help="Add keyframes where "
                                                      "interpolation errs more than this (m).")] = 0.03,
    export: Annotated[str, typer.Option("--export", help="Animated files per track, comma-separated: bvh, glb "
                                        "(GLB: the body's or glTF character's mesh, a BVH/JSON character's "
                                        "SMPL-SI body); '' for none.")] = "bvh",
    max_effectors: Annotated[int, typer.Option("--max-effectors", min=1, help="Most effectors per keyframe.")] = 6,
    preview: Annotated[Path | None, typer.Option("--preview", help="Write an animated preview (.gif or .mp4).")
                       ] = None,
    video: Annotated[Path | None, typer.Option("--video", help="Source video (or folder of frames) for the "
                                               "preview's background (camera-frame animations).")] = None,
    max_frames: Annotated[int, typer.Option("--max-frames", min=1, help="Refuse to read more frames than "
                                            "this.")] = 100_000,
    preview_every: Annotated[int, typer.Option("--preview-every", min=1, max=1000, help="Preview every N-th frame, "
                                               "1..1000 (more than 1000 frames get a larger step, printed).")] = 1,
    trust_pickle: Annotated[bool, typer.Option("--trust-pickle", help="Load pickles with plain joblib/pickle "
                                               "(runs code from the file; only for trusted files).")] = False,
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: shipped).")] = None,
    mean: Annotated[Path | None, typer.Option("--mean", help="HumanML3D features (T, 263): the dataset's Mean.npy "
                                              "(with --std) to undo the normalisation.")] = None,
    std: Annotated[Path | None, typer.Option("--std", help="HumanML3D features: the dataset's Std.npy.")] = None,
) -> None:
    """Video estimates or joint-position motion (HumanML3D joints or features, MDM results.npy, a BVH) -> per
    track: cleaned per-frame poses on the body or character, effectors on keyframes, OUT/animation.json and an
    animated BVH (and GLB) at the source frame rate."""
    from workflows.animation.options import check_animate_options, check_preview_path

    formats = [f.strip().lower() for f in export.split(",") if f.strip()]
    with user_errors():  # options judged from their text: refused before numpy, torch or the model load
        check_fps(fps)
        check_animate_options(frames=frames, fps=fps, formats=formats, format=format, space=space,
                              smoothing=smoothing, smoothness=smoothness, pose_budget=pose_budget,
                              keyframe_threshold=keyframe_threshold, character=character)
        if preview is not None:  # a preview that cannot be written fails now, not after the work
            check_preview_path(preview)
        options = character_cli()  # --rig, --map, --units, ...
    from rich.progress import Progress

    from smplik.cli.errors import console
    from workflows.animation.clean import CleanConfig
    from workflows.animation.clips import AnimateConfig
    from workflows.animation.run import animate_file
    from workflows.cli_shared import _solver
    from workflows.scene.recovery import RecoveryConfig

    with user_errors():  # the numeric settings, checked by their configs before the model and the file load
        config = AnimateConfig(CleanConfig(smoothing="adaptive" if smoothing == "auto" else smoothing,  # type: ignore[arg-type]
                                           smoothness=smoothness, foot_lock=foot_lock,
                                           pose_budget_mm=pose_budget or None),
                               model_motion_smoothing="none" if smoothing == "auto" else None,
                               keyframe_threshold_m=keyframe_threshold,
                               camera_fov_deg=None if keep_depth else AnimateConfig().camera_fov_deg,
                               recovery=RecoveryConfig(max_effectors=max_effectors, threshold=0.03))
    solver = _solver(checkpoint)
    with user_errors(), Progress(console=console, transient=True, disable=not console.is_terminal) as bar:
        task = bar.add_task("reading", total=None)
        shown: list[tuple[str, int]] = []

        def progress(done: int, total: int, what: str) -> None:
            bar.update(task, completed=done, total=total, description=what)
            if not console.is_terminal and total >= PLAIN_PROGRESS_FROM:  # a log or a pipe: every 10 % of long steps
                tenth = 10 * done // max(total, 1)
                if not shown or shown[-1] != (what, tenth):
                    shown.append((what, tenth))
                    say(f"{what}: {done}/{total}")

        outputs = animate_file(results, out, solver, format=format, frames=frames, fps=fps, track=track,
                               character_path=character, character_options=options, config=config,
                               trust_pickle=trust_pickle, space=space, progress=progress,
                               formats=formats, max_frames=max_frames, mean=mean, std=std)
        files = list(outputs.all_files)
        anim = outputs.animation
        shown = None
        if preview is not None:
            from workflows.animation.preview import write_preview

            bar.update(task, description="preview")
            shown = write_preview(anim, preview, video=video, every=preview_every)
            files.append(shown.path)
    for note in anim.notes:  # what the reading assumed (a frame rate, a sequence, a folder's frames)
        say(note)
    if anim.depth_change is not None:
        say(anim.depth_change.describe())
    for t in anim.tracks:
        say(f"{t.name}: frames {t.first_frame}..{t.first_frame + t.num_frames - 1} at {anim.fps:g} frames/s "
            f"({anim.space} frame), {len(t.keyframes)} keyframes, {contact_summary(t.contacts)}")
    if shown is not None:
        say(shown.describe())
    if outputs.exported:
        from workflows.animation.files import scene_of
        from workflows.scene.export import glb_notes

        for note in glb_notes(scene_of(anim), formats):
            say(note)
    for path in files:
        say(f"wrote {path}")


def contact_summary(contacts: Any) -> str:
    """How a track's feet touch the ground, from its (T, 2) left/right contact flags (or None):
    ``"left foot in contact on 210 of 537 frames, right on 198"``."""
    if contacts is None:
        return "no foot contacts detected"
    left, right = (int(n) for n in contacts.sum(axis=0))
    return f"left foot in contact on {left} of {len(contacts)} frames, right on {right}"


def edit_keyframe_cmd(
    animation: Annotated[Path, typer.Argument(help="Animation file (animation.json of scene animate).")],
    frame: Annotated[int, typer.Option("--frame", help="Source frame of the keyframe to set.")],
    effectors: Annotated[Path, typer.Option("--effectors", help="Effector file (smplik-effectors JSON, "
                                            "character space) for that frame: the effectors to move or add; the "
                                            "keyframe's others are kept.")],
    track: Annotated[str | None, typer.Option("--track", help="Track name or id (default: the only one).")] = None,
    window: Annotated[int, typer.Option("--window", min=0, help="Blend the change over this many frames on "
                                        "each side; frames beyond stay unchanged.")] = 10,
    exact: Annotated[bool, typer.Option("--exact", help="Re-solve the frame from the merged effectors exactly "
                                        "instead of solving the moved ones as drags.")] = False,
    out: Annotated[Path | None, typer.Option("--out", help="Output file (default: overwrite ANIMATION).")] = None,
    export: Annotated[str, typer.Option("--export", help="Also re-export per track next to the output: bvh, "
                                        "glb (comma-separated; default none).")] = "",
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: shipped).")] = None,
) -> None:
    """Move or add a keyframe's effectors (merged into its recovered ones), re-pose the frame as the editor's drag
    does (the moved limbs only) and blend the change into the neighbouring frames."""
    from smplik.effector_schema import load_effector_file
    from smplik.output_files import staged_folder
    from workflows.animation.clips import AnimationError
    from workflows.animation.files import load_animation, save_animation, scene_of
    from workflows.animation.keyframe_edit import check_keyframe_edit, keyframe_edit
    from workflows.animation.run import animation_export_names, check_animate_options, export_animation
    from workflows.cli_shared import _solver
    from workflows.scene.export import scene_reads

    formats = [f.strip().lower() for f in export.split(",") if f.strip()]
    with user_errors():  # every input checked before the model loads and before anything is written
        check_animate_options(formats=formats)
        anim = load_animation(animation)
        if track is None:
            if len(anim.tracks) != 1:
                raise AnimationError(f"{animation}: {len(anim.tracks)} tracks; choose one with --track "
                                     f"({', '.join(t.name for t in anim.tracks)}).")
            track = anim.tracks[0].name
        target = out or animation
        reads = [animation, effectors, checkpoint, *scene_reads(scene_of(anim), animation.resolve().parent)]
        # every file or none; none of them an input (the animation itself only when edited in place)
        with staged_folder(target.parent, reads=reads, allow=[animation] if out is None else []) as stage:
            stage.check([target.name, *animation_export_names(anim, formats)])  # before any work
            effs = load_effector_file(effectors).effectors
            check_keyframe_edit(anim, track, frame, effs, window=window)
            edit = keyframe_edit(anim, track, frame, effs, _solver(checkpoint), window=window, exact=exact)
            path = stage.final(save_animation(edit.animation, stage.dir / target.name))
            files = [stage.final(f) for f in export_animation(edit.animation, stage.dir, formats,
                                                              base_dir=target.parent)] if formats else []
    say(edit.line())
    for written in (path, *files):
        say(f"wrote {written}")
