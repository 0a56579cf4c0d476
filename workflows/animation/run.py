"""``scene animate`` end to end: an estimator output file -> ``animation.json`` and its exports.

The steps (reading, cleaning, keyframes, effectors) are :func:`workflows.animation.clips.animation_from_clip`'s;
this module writes the files (:mod:`workflows.animation.files`, :func:`workflows.scene.export.export_scene`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from workflows.animation.clips import (
    MAX_FRAMES,
    AnimateConfig,
    Animation,
    AnimationError,
    Progress,
    SkeletonSource,
    TrackMotion,
    animation_from_clip,
    read_clip,
)
from workflows.animation.files import save_animation, scene_of
from workflows.animation.joint_motion import JointMotion
from workflows.animation.options import check_animate_options  # noqa: F401 (re-exported)
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
                 max_frames: int = MAX_FRAMES, progress: Progress | None = None,
                 mean: str | Path | None = None, std: str | Path | None = None) -> AnimateOutputs:
    """Estimator output -> ``out_dir/animation.json`` (+ per track, animated at the source frame rate, the
    ``formats`` of :func:`workflows.scene.export.export_scene`: ``"bvh"``, ``"glb"`` (SMPL bodies and glTF
    characters)).

    Joint-position motion (HumanML3D joints or features, MDM's ``results.npy``, a BVH:
    :mod:`workflows.animation.joint_motion`) is fitted first: SMPL-SI's body for its bone lengths, the SMPL-IK
    solver per frame; ``mean``/``std``: HumanML3D's Mean.npy/Std.npy for normalised features."""
    span = check_animate_options(frames=frames, fps=fps, formats=formats)
    fps = None if fps is None else float(fps)
    from smplik.output_files import check_writes, staged_folder

    reads = [results_path, character_path, getattr(character_options, "map", None), mean, std]
    check_writes([Path(out_dir) / "animation.json"], reads)  # before any work (the exports' names: after reading)
    character = skeleton = None
    if character_path is not None:
        from shape_inversion.options import CharacterOptions
        from workflows.character import load_character

        options = CharacterOptions() if character_options is None else character_options
        character = load_character(character_path, options)
        skeleton = SkeletonSource.from_options(str(Path(character_path).resolve()), options)
    # a BVH input is mapped with --rig/--map/--units/--up only when they are not the character's
    motion = read_joint_motion_file(results_path, format=format, trust_pickle=trust_pickle, max_bytes=max_bytes,
                                    mean=mean, std=std, options=character_options if character_path is None else None)
    if motion is not None:
        animation, motions = joint_animation(motion, str(results_path), solver, fps=fps, track=track, frames=span,
                                             character=character, skeleton=skeleton, config=config,
                                             max_frames=max_frames, progress=progress)
    else:
        clip = read_clip(results_path, format=format, trust_pickle=trust_pickle, space=space, max_people=max_people,
                         max_bytes=max_bytes, solver=solver, frames=span, max_frames=max_frames, progress=progress)
        first = next(iter(clip.tracks.values()))[0][1]
        animation, motions = animation_from_clip(clip, solver, fps=fps, track=track, frames=span,
                                                 character=character, skeleton=skeleton, config=config,
                                                 camera=first.camera, progress=progress)
    with staged_folder(out_dir, reads=reads) as stage:  # all files or none; none of them an input
        stage.check(animation_export_names(animation, formats))
        path = save_animation(animation, stage.dir / "animation.json")
        written = export_animation(animation, stage.dir, formats) if formats else []
    return AnimateOutputs(stage.final(path), tuple(stage.final(w) for w in written), animation, tuple(motions))


def animation_export_names(animation: Animation, formats: Sequence[str]) -> list[str]:
    """The file names :func:`export_animation` writes (one per track and format)."""
    from workflows.scene.export import export_names

    return export_names(scene_of(animation), formats, posed=[t.name for t in animation.tracks])


def read_joint_motion_file(path: str | Path, *, format: str = "auto", trust_pickle: bool = False,
                           max_bytes: int | None = None, mean: str | Path | None = None,
                           std: str | Path | None = None, options: Any = None) -> JointMotion | None:
    """The joint motion of a ``.bvh`` or ``.npy`` file (:mod:`workflows.animation.joint_motion`), or None for
    any other estimator output. ``format``: ``"auto"`` or one of the joint formats (any other name: None)."""
    from workflows.animation.joint_motion import FORMATS as JOINT_FORMATS
    from workflows.animation.joint_motion import joint_motion_from_data, read_bvh_joints
    from workflows.estimators import MAX_BYTES, _load_raw

    path = Path(path)
    if format != "auto" and format not in JOINT_FORMATS:
        return None
    if path.suffix.lower() == ".bvh" and path.is_file():
        return read_bvh_joints(path, options)
    if path.suffix.lower() != ".npy" or not path.is_file():
        if mean is not None or std is not None:
            raise AnimationError(f"{path}: --mean/--std apply to HumanML3D features (a (T, 263) .npy) only.")
        return None
    data = _load_raw(path, trust_pickle, MAX_BYTES if max_bytes is None else max_bytes)
    return joint_motion_from_data(data, str(path), mean=mean, std=std)


def joint_animation(motion: JointMotion, source: str, solver: TensorSolver, *, fps: float | None = None,
                    track: str | None = None, frames: tuple[int, int] | None = None, character: Any = None,
                    skeleton: SkeletonSource | None = None, config: AnimateConfig | None = None,
                    max_frames: int = MAX_FRAMES, progress: Progress | None = None
                    ) -> tuple[Animation, list[TrackMotion]]:
    """Every track of a joint motion -> one :class:`Animation` (:func:`workflows.animation.joint_motion.joints_to_clip`,
    then :func:`animation_from_clip` per track on its SMPL-SI body, or on ``character``)."""
    from workflows.animation.joint_motion import joints_to_clip

    ids = list(motion.tracks)
    if track is not None:
        if str(track) not in motion.tracks:
            raise AnimationError(f"{source}: no track {track!r} (tracks: {', '.join(ids[:20])}).")
        ids = [str(track)]
    total = sum(len(motion.tracks[i]) if frames is None else frames[1] - frames[0] for i in ids)
    if total > max_frames:
        raise AnimationError(f"{source}: {total} frames to read; refusing more than {max_frames} "
                             "(--frames A:B reads a part; max_frames / --max-frames raises the cap).")
    tracks, motions = [], []
    notes = list(motion.notes)
    if fps is None and motion.fps_assumed:
        notes.append(f"{source}: {motion.fps:g} frames/s assumed (HumanML3D's rate, that of the text-to-motion models "
                     "trained on it; --fps sets another).")
    rate = fps
    config = AnimateConfig() if config is None else config
    if motion.format != "bvh_joints" and config.model_motion_smoothing is not None:
        config = dataclasses.replace(config, clean=dataclasses.replace(config.clean,
                                                                       smoothing=config.model_motion_smoothing))
        notes.append(f"{source}: joints made by a model are smooth already: smoothing "
                     f"{config.model_motion_smoothing!r} (--smoothing sets another), glitch repair and foot locks kept")
    for tid in ids:
        clip, body = joints_to_clip(motion, solver, source, tid, frames)
        notes.append(f"track {tid}: SMPL-SI body for its bone lengths: scale {body.scale:.3f}, betas "
                     f"[{', '.join(f'{b:.2f}' for b in body.betas[:3])}, ...], bone lengths within "
                     f"{body.bone_residual_m * 1000:.1f} mm on average")
        anim, mots = animation_from_clip(clip, solver, fps=fps, frames=frames, character=character or body,
                                         skeleton=skeleton, config=config, progress=progress)
        tracks += anim.tracks
        motions += mots
        rate, clean = anim.fps, anim.clean
    return Animation(tuple(tracks), float(rate), source, motion.format, "world", None, clean, None,
                     tuple(notes)), motions


def export_animation(animation: Animation, out_dir: str | Path, formats: Sequence[str] = ("bvh",),
                     base_dir: str | Path | None = None) -> list[Path]:
    """Per track, the animation at its frame rate as ``formats`` (:func:`workflows.scene.export.export_scene`): the
    clip's frames only, in the animation's world frame (metres, y-up), like every scene export."""
    from workflows.scene.export import export_scene

    return export_scene(scene_of(animation), out_dir, formats=formats, frame_time=1.0 / animation.fps,
                        poses={t.name: t.poses() for t in animation.tracks}, base_dir=base_dir,
                        keep_source_frames=False)
