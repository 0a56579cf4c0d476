"""``smplik track``: a tracker recording -> an animation (``smplik-animation``) and animated BVH/GLB files.

The recording (:func:`smplik.tracking.recordings.read_trackers`: ``smplik-trackers`` JSON or a SteamVR JSON-lines log)
runs through the streaming tracker (:mod:`smplik.tracking.runtime`), one pose per input frame, on the user's
body (``betas``, ``gender``) or on a custom character (``--character``: its SMPL-SI shape and scale; the
trackers are then taken in the character's units and divided by its scale). The result is one track in the
world frame with its predicted foot contacts, written as ``OUT/animation.json``, so that export, previews and
the editor's timeline work on it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import Gender
from smplik.rotations import matrix_to_axis_angle_scipy
from workflows.animation.clips import Animation, AnimationError, AnimationTrack
from workflows.animation.run import animation_export_names, export_animation


@dataclass(frozen=True)
class TrackOutputs:
    """What :func:`track_file` wrote, and the animation."""

    animation_file: Path
    exported: tuple[Path, ...]
    animation: Animation
    anomaly_rate: float
    switches: int
    calibration: Any = None
    """:class:`smplik.tracking.calibrate.Calibration` (None with ``calibrate=False`` or a character)."""


def track_file(path: str | Path, out_dir: str | Path, *, samples: int = 1, betas: Sequence[float] | None = None,
               gender: Gender | str = Gender.NEUTRAL, character_path: str | Path | None = None,
               character_options: Any = None, formats: Sequence[str] = ("bvh",), checkpoint: str | Path | None = None,
               seed: int = 0, fit_trackers: bool = False, foot_locks: str = "offline", height: float | None = None,
               calibrate: bool = True, controller: str | None = None, csv_units: str | None = None,
               csv_time_unit: str | None = None, csv_axes: str | None = None) -> TrackOutputs:
    """Tracker recording -> ``out_dir/animation.json`` (+ ``formats``: bvh, glb). ``foot_locks``: ``offline`` (the
    whole recording known), ``streaming`` (causal, as ``smplik track --live``) or ``off``. ``calibrate``: the
    floor and the body from the recording (:func:`smplik.tracking.calibrate.calibrate`; ``height`` (stature, m)
    or ``betas`` given are used instead of the estimate); ``controller``, ``csv_*``: a CSV recording's controller
    kind and overrides (:mod:`smplik.tracking.csv_io`). Raises the project's
    one-line errors (tracker file, model file, character, export). Every file is written or none
    (:func:`smplik.output_files.staged_folder`), and none of them is an input."""
    from smplik.output_files import staged_folder
    from workflows.scene.export import FORMATS

    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise AnimationError(f"unknown export format(s) {bad}; choose from {', '.join(FORMATS)}.")
    if foot_locks not in ("offline", "streaming", "off"):
        raise AnimationError(f"foot_locks must be offline, streaming or off, got {foot_locks!r}.")
    if samples < 1 or samples > 1024:
        raise AnimationError(f"--samples must be in 1..1024, got {samples}.")

    out = Path(out_dir)
    reads = [path, character_path, checkpoint, getattr(character_options, "map", None)]
    with staged_folder(out, reads=reads) as stage:  # all files or none; none of them an input
        stage.check(["animation.json", *(f"person_0.{f}" for f in formats)])  # before any work
        read = {k: v for k, v in (("units", csv_units), ("time_unit", csv_time_unit), ("axes", csv_axes),
                                  ("controller", controller)) if v is not None}
        return _track_into(stage, path, samples=samples, betas=betas, gender=gender, character_path=character_path,
                           character_options=character_options, formats=formats, checkpoint=checkpoint, seed=seed,
                           fit_trackers=fit_trackers, foot_locks=foot_locks, height=height, calibrate=calibrate,
                           read=read)


def _track_into(stage: Any, path: str | Path, *, samples: int, betas: Sequence[float] | None, gender: Gender | str,
                character_path: str | Path | None, character_options: Any, formats: Sequence[str],
                checkpoint: str | Path | None, seed: int, fit_trackers: bool, foot_locks: str,
                height: float | None = None, calibrate: bool = True, read: dict[str, Any] | None = None
                ) -> TrackOutputs:
    from smplik.tracking.config import TrackerRuntimeConfig
    from smplik.tracking.recordings import read_trackers
    from smplik.tracking.runtime import ANOMALY_THRESHOLD, Tracker, track_sequence
    from workflows.animation.files import save_animation
    from workflows.scene import SkeletonSource

    signals = read_trackers(path, **(read or {}))
    scale, skeleton, cal = 1.0, None, None
    body_betas = np.zeros(10) if betas is None else np.asarray(betas, dtype=np.float64)
    body_gender = Gender.parse(gender)
    if character_path is not None:
        from shape_inversion.options import CharacterOptions
        from workflows.character import load_character

        options = CharacterOptions() if character_options is None else character_options
        character = load_character(character_path, options)
        body_betas, body_gender, scale = (np.asarray(character.betas, dtype=np.float64), character.gender,
                                          float(character.scale))
        skeleton = SkeletonSource.from_options(str(Path(character_path).resolve()), options)
        signals = replace(signals, positions=signals.positions / scale)
    elif calibrate:
        from smplik.tracking.calibrate import apply_floor
        from smplik.tracking.calibrate import calibrate as calibrate_recording

        cal = calibrate_recording(signals, height=height, betas=betas, gender=body_gender)
        signals, body_betas = apply_floor(signals, cal), cal.betas
    elif height is not None:
        from smplik.tracking.calibrate import betas_for_stature

        body_betas = betas_for_stature(height, body_gender)
    if checkpoint is None:  # the shipped model for the trackers the recording has (4, or head and hands only)
        from smplik.tracking.model_io import shipped_checkpoint

        checkpoint = shipped_checkpoint(signals.names)
    tracker = Tracker.load(checkpoint, betas=body_betas, gender=body_gender,
                           config=TrackerRuntimeConfig(samples=samples, seed=seed, tracker_fit=fit_trackers,
                                                       foot_lock=foot_locks != "off",
                                                       offline_lock=foot_locks == "offline"))
    result = track_sequence(tracker, signals)
    aa = matrix_to_axis_angle_scipy(result.R_local)
    track = AnimationTrack("person_0", "0", body_gender, body_betas, scale, skeleton, 0, aa[:, 0], aa[:, 1:],
                           result.transl, (), result.contacts.astype(bool))
    animation = Animation((track,), float(signals.fps), str(path), "smplik-trackers", "world", None, None)
    stage.check(animation_export_names(animation, formats))
    file = save_animation(animation, stage.dir / "animation.json")
    written = export_animation(animation, stage.dir, formats) if formats else []
    switches = int((np.diff(result.sample) != 0).sum())
    return TrackOutputs(stage.final(file), tuple(stage.final(w) for w in written), animation,
                        float((result.anomaly > ANOMALY_THRESHOLD).mean()), switches, cal)
