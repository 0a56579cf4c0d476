"""``scene animate`` end to end: an estimator output file -> ``animation.json`` and its exports.

The steps (reading, cleaning, keyframes, effectors) are :func:`workflows.animation.clips.animation_from_clip`'s;
this module writes the files (:mod:`workflows.animation.files`, :func:`workflows.scene.export.export_scene`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workflows.animation.clips import (
    MAX_FRAMES,
    AnimateConfig,
    Animation,
    AnimationError,
    Progress,
    SkeletonSource,
    TrackMotion,
    animation_from_clip,
    parse_frames,
    read_clip,
)
from workflows.animation.files import save_animation, scene_of
from workflows.scene.recovery import TensorSolver


@dataclass(frozen=True)
class AnimateOutputs:
    """Files written by :func:`animate_file`, and the animation with its before/after motions."""

    animation_file: Path
    exported: tuple[Path, ...]
    animation: Animation
    motions: tuple[TrackMotion, ...]

    @property
    def all_files(self) -> tuple[Path, ...]:
        return (self.animation_file, *self.exported)


def animate_file(results_path: str | Path, out_dir: str | Path, solver: TensorSolver, *, format: str = "auto",
                 frames: str = "all", fps: float | None = None, track: str | None = None,
                 character_path: str | Path | None = None, character_options: Any = None,
                 config: AnimateConfig | None = None, trust_pickle: bool = False, space: str | None = None,
                 max_people: int | None = None, max_bytes: int | None = None, formats: Sequence[str] = ("bvh",),
                 max_frames: int = MAX_FRAMES, progress: Progress | None = None) -> AnimateOutputs:
    """Estimator output -> ``out_dir/animation.json`` (+ per track, animated at the source frame rate, the
    ``formats`` of :func:`workflows.scene.export.export_scene`: ``"bvh"``, ``"glb"`` (SMPL bodies and glTF
    characters))."""
    from workflows.scene.export import FORMATS

    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise AnimationError(f"unknown export format(s) {bad}; choose from {', '.join(FORMATS)}.")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise AnimationError(f"--fps must be a positive frame rate, got {fps}.")
    span = parse_frames(frames)
    from smplik.output_files import check_writes, staged_folder

    reads = [results_path, character_path, getattr(character_options, "map", None)]
    check_writes([Path(out_dir) / "animation.json"], reads)  # before any work (the exports' names: after reading)
    character = skeleton = None
    if character_path is not None:
        from shape_inversion.options import CharacterOptions
        from workflows.character import load_character

        options = CharacterOptions() if character_options is None else character_options
        character = load_character(character_path, options)
        skeleton = SkeletonSource.from_options(str(Path(character_path).resolve()), options)
    clip = read_clip(results_path, format=format, trust_pickle=trust_pickle, space=space, max_people=max_people,
                     max_bytes=max_bytes, solver=solver, frames=span, max_frames=max_frames, progress=progress)
    first = next(iter(clip.tracks.values()))[0][1]
    animation, motions = animation_from_clip(clip, solver, fps=fps, track=track, frames=span, character=character,
                                             skeleton=skeleton, config=config, camera=first.camera,
                                             progress=progress)
    with staged_folder(out_dir, reads=reads) as stage:  # all files or none; none of them an input
        stage.check(animation_export_names(animation, formats))
        path = save_animation(animation, stage.dir / "animation.json")
        written = export_animation(animation, stage.dir, formats) if formats else []
    return AnimateOutputs(stage.final(path), tuple(stage.final(w) for w in written), animation, tuple(motions))


def animation_export_names(animation: Animation, formats: Sequence[str]) -> list[str]:
    """The file names :func:`export_animation` writes (one per track and format)."""
    from workflows.scene.export import export_names

    return export_names(scene_of(animation), formats, posed=[t.name for t in animation.tracks])


def export_animation(animation: Animation, out_dir: str | Path, formats: Sequence[str] = ("bvh",),
                     base_dir: str | Path | None = None) -> list[Path]:
    """Per track, the animation at its frame rate as ``formats`` (:func:`workflows.scene.export.export_scene`): the
    clip's frames only, in the animation's world frame (metres, y-up), like every scene export."""
    from workflows.scene.export import export_scene

    return export_scene(scene_of(animation), out_dir, formats=formats, frame_time=1.0 / animation.fps,
                        poses={t.name: t.poses() for t in animation.tracks}, base_dir=base_dir,
                        keep_source_frames=False)
