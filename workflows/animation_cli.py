"""``smplik scene animate``: a video's estimates -> per-track animations (logic in :mod:`workflows.animation`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from shape_inversion.options import (
    BindOption,
    MapOption,
    MaxJointsOption,
    PositionsOption,
    RestOption,
    RigOption,
    RootOption,
    UnitsOption,
    UpOption,
    character_options_from_cli,
)
from smplik.cli.errors import say, user_errors
from smplik.cli.options import check_fps
from smplik.limits import DEFAULT_MAX_JOINTS


def animate_cmd(
    results: Annotated[Path, typer.Argument(help="Video estimator output (GVHMR, WHAM, 4D-Humans/PHALP, HybrIK, "
                                            "AIST++, AMASS, ...).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (animation.json, one BVH per track).")],
    frames: Annotated[str, typer.Option("--frames", help="'all' or A:B (frames A..B-1).")] = "all",
    fps: Annotated[float | None, typer.Option("--fps", help="Source frame rate (default: the file's; needed "
                                              "when the format does not store it).")] = None,
    track: Annotated[str | None, typer.Option("--track", help="Only this track id (default: every track).")] = None,
    format: Annotated[str, typer.Option("--format", help="Estimator format (as in from-estimate).")] = "auto",
    space: Annotated[str | None, typer.Option("--space", help="WHAM / GVHMR: 'world' (their world trajectory, "
                                              "the default when present) or 'camera'.")] = None,
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON).")] = None,
    rig: RigOption = None,
    map_file: MapOption = None,
    units: UnitsOption = "auto",
    up: UpOption = "auto",
    rest: RestOption = "auto",
    bind: BindOption = "inverse_bind",
    positions: PositionsOption = "auto",
    max_joints: MaxJointsOption = DEFAULT_MAX_JOINTS,
    root: RootOption = None,
    smoothing: Annotated[str, typer.Option(
        "--smoothing", help="sequence (a sequence solve, the default), one_euro, savgol or none.")] = "sequence",
    smoothness: Annotated[float, typer.Option("--smoothness", help="sequence cleaning: weight of the joints' "
                                              "acceleration; higher smooths more.")] = 2.0,
    pose_budget: Annotated[float, typer.Option("--pose-budget", help="sequence cleaning: most the smoothing may "
                                               "move the pose from the estimate (pelvis-aligned MPJPE, mm); "
                                               "0: no cap.")] = 5.0,
    keep_depth: Annotated[bool, typer.Option("--keep-depth", help="Camera-space tracks of near-orthographic "
                                             "estimators (4D-Humans/PHALP): keep their depth instead of placing "
                                             "the body for a 60-degree camera.")] = False,
    foot_lock: Annotated[bool, typer.Option("--foot-lock/--no-foot-lock", help="Lock feet in contact.")] = True,
    keyframe_threshold: Annotated[float, typer.Option("--keyframe-threshold", help="Add keyframes where "
                                                      "interpolation errs more than this (m).")] = 0.03,
    export: Annotated[str, typer.Option("--export", help="Animated files per track, comma-separated: bvh, glb "
                                        "(GLB for SMPL bodies and glTF characters); '' for none.")] = "bvh",
    max_effectors: Annotated[int, typer.Option("--max-effectors", min=1, help="Most effectors per keyframe.")] = 6,
    preview: Annotated[Path | None, typer.Option("--preview", help="Write an animated preview (.gif or .mp4).")
                       ] = None,
    video: Annotated[Path | None, typer.Option("--video", help="Source video (or folder of frames) for the "
                                               "preview's background (camera-frame animations).")] = None,
    max_frames: Annotated[int, typer.Option("--max-frames", min=1, help="Refuse to read more frames than "
                                            "this.")] = 100_000,
    preview_every: Annotated[int, typer.Option("--preview-every", min=1, help="Preview every N-th frame.")] = 1,
    trust_pickle: Annotated[bool, typer.Option("--trust-pickle", help="Load pickles with plain joblib/pickle "
                                               "(runs code from the file; only for trusted files).")] = False,
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: shipped).")] = None,
) -> None:
    """Video estimates -> per track: cleaned per-frame poses on the body or character, effectors on keyframes,
    OUT/animation.json and an animated BVH (and GLB) at the source frame rate."""
    from rich.progress import Progress

    from smplik.cli.errors import console
    from workflows.animation import AnimateConfig, animate_file
    from workflows.cli import _solver
    from workflows.motion_clean import CleanConfig
    from workflows.recovery import RecoveryConfig

    with user_errors():  # one line also when the command runs outside smplik's top level
        check_fps(fps)
    options = character_options_from_cli(rig, map_file, units, up, rest, bind, positions, max_joints, root)
    solver = _solver(checkpoint)
    with user_errors(), Progress(console=console, transient=True) as bar:
        config = AnimateConfig(CleanConfig(smoothing=smoothing, smoothness=smoothness,  # type: ignore[arg-type]
                                           foot_lock=foot_lock, pose_budget_mm=pose_budget or None),
                               keyframe_threshold_m=keyframe_threshold,
                               camera_fov_deg=None if keep_depth else AnimateConfig().camera_fov_deg,
                               recovery=RecoveryConfig(max_effectors=max_effectors, threshold=0.03))
        task = bar.add_task("reading", total=None)

        def progress(done: int, total: int, what: str) -> None:
            bar.update(task, completed=done, total=total, description=what)

        outputs = animate_file(results, out, solver, format=format, frames=frames, fps=fps, track=track,
                               character_path=character, character_options=options, config=config,
                               trust_pickle=trust_pickle, space=space, progress=progress,
                               formats=[f.strip().lower() for f in export.split(",") if f.strip()],
                               max_frames=max_frames)
        files = list(outputs.all_files)
        anim = outputs.animation
        if preview is not None:
            from workflows.animation_preview import preview_frames, save_preview

            bar.update(task, description="preview")
            images = preview_frames(anim, video=video, every=preview_every)
            files.append(save_preview(images, preview, anim.fps / preview_every))
    if anim.depth_change is not None:
        say(anim.depth_change.describe())
    for t in anim.tracks:
        contacts = 0 if t.contacts is None else int(t.contacts.sum())
        say(f"{t.name}: frames {t.first_frame}..{t.first_frame + t.num_frames - 1} at {anim.fps:g} frames/s "
            f"({anim.space} frame), {len(t.keyframes)} keyframes, {contacts} foot-contact frames")
    for path in files:
        say(f"wrote {path}")


def edit_keyframe_cmd(
    animation: Annotated[Path, typer.Argument(help="Animation file (animation.json of scene animate).")],
    frame: Annotated[int, typer.Option("--frame", help="Source frame of the keyframe to set.")],
    effectors: Annotated[Path, typer.Option("--effectors", help="Effector file (smplik-effectors JSON, "
                                            "character space) for that frame.")],
    track: Annotated[str | None, typer.Option("--track", help="Track name or id (default: the only one).")] = None,
    window: Annotated[int, typer.Option("--window", min=0, help="Blend the change over this many frames on "
                                        "each side; frames beyond stay unchanged.")] = 10,
    out: Annotated[Path | None, typer.Option("--out", help="Output file (default: overwrite ANIMATION).")] = None,
    export: Annotated[str, typer.Option("--export", help="Also re-export per track next to the output: bvh, "
                                        "glb (comma-separated; default none).")] = "",
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: shipped).")] = None,
) -> None:
    """Set a keyframe's effectors, re-solve that frame and blend the change into the neighbouring frames."""
    from smplik.effector_schema import load_effector_file
    from workflows.animation import AnimationError, export_animation
    from workflows.animation_edit import edit_keyframe
    from workflows.animation_io import load_animation, save_animation
    from workflows.cli import _solver

    with user_errors():
        anim = load_animation(animation)
        if track is None:
            if len(anim.tracks) != 1:
                raise AnimationError(f"{animation}: {len(anim.tracks)} tracks; choose one with --track "
                                     f"({', '.join(t.name for t in anim.tracks)}).")
            track = anim.tracks[0].name
        effs = load_effector_file(effectors).effectors
        edited = edit_keyframe(anim, track, frame, effs, _solver(checkpoint), window=window)
        path = save_animation(edited, out or animation)
        formats = [f.strip().lower() for f in export.split(",") if f.strip()]
        files = export_animation(edited, path.parent, formats, base_dir=path.parent) if formats else []
    say(f"{track}: frame {frame} re-solved from {len(effs)} effectors, blended over +-{window} frames")
    for written in (path, *files):
        say(f"wrote {written}")
