"""The animation file: a versioned JSON file of per-track motions with keyframe effectors.

Format ``smplik-animation``, version :data:`ANIMATION_VERSION` (the scene format grown over time; a
track's body fields are a scene character's, read by the scene reader's rules)::

    {
      "format": "smplik-animation",
      "version": 1,
      "source": "hmr4d_results.pt", "source_format": "gvhmr",     # optional
      "fps": 30.0,                                                 # the source frame rate
      "space": "camera" | "world",                                 # estimator camera frame or world trajectory
      "camera": null | {...scene camera...},
      "clean": null | {"smoothing": "adaptive", "smoothness": 2.0, ...},   # workflows.animation.clean.CleanConfig
      "tracks": [
        {
          "name": "person_0", "track_id": "0", "gender": "neutral", "betas": [10 numbers], "scale": 1.0,
          "skeleton": null | {"path": ..., "rig": ..., ...},      # as in scenes
          "first_frame": 12,                                       # source frame of row 0
          "global_orient": [[3] x T], "body_pose": [[[3] x 23] x T], "transl": [[3] x T],   # SMPL space
          "contacts": null | [[left, right] x T],                  # foot contacts (booleans)
          "repaired": [frames],                                    # glitches replaced by interpolation
          "keyframes": [{"frame": 12, "error_m": 0.012, "effectors": [...scene effectors...]}, ...]
        }
      ]
    }

Keyframe frames are source frame numbers inside the track, strictly increasing. The reader is
strict (unknown keys, shapes, types, ranges): errors are one-line :class:`AnimationFileError` naming
the file and JSON path, e.g. ``anim.json: tracks[0].keyframes[2].frame: 99 is outside the track's
frames 12..80``. :func:`save_animation` checks that the file reads back, then writes atomically.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from smplik.atomic import write_json_atomic
from smplik.effector_schema import MAX_EFFECTORS
from smplik.effectors import parse_effector_dict
from smplik.limits import LimitError, check_rate
from smplik.validation import JSONPathError, read_json, short_repr
from workflows.animation.clean import CleanConfig
from workflows.animation.clips import Animation, AnimationTrack, Keyframe
from workflows.scene.document import (
    Scene,
    SceneCharacter,
    SceneError,
    _check_keys,
    _expect,
    _numbers,
    scene_from_dict,
)

ANIMATION_FORMAT = "smplik-animation"
ANIMATION_VERSION = 1
MAX_TRACKS = 100
MAX_FRAMES = 1_000_000
_BODY_KEYS = ("name", "gender", "betas", "scale", "skeleton")
_TRACK_KEYS = {*_BODY_KEYS, "track_id", "first_frame", "global_orient", "body_pose", "transl", "contacts",
               "keyframes", "repaired"}
_ROOT_KEYS = {"format", "version", "source", "source_format", "fps", "space", "camera", "clean", "tracks"}


class AnimationFileError(SceneError):
    """An animation file is invalid; the message names the file and the JSON path."""


def _track_to_dict(t: AnimationTrack) -> dict[str, Any]:
    return {
        "name": t.name, "track_id": t.track_id, "gender": t.gender.value, "betas": [float(b) for b in t.betas],
        "scale": float(t.scale), "skeleton": None if t.skeleton is None else t.skeleton.to_dict(),
        "first_frame": int(t.first_frame), "global_orient": np.asarray(t.global_orient).tolist(),
        "body_pose": np.asarray(t.body_pose).tolist(), "transl": np.asarray(t.transl).tolist(),
        "contacts": None if t.contacts is None else np.asarray(t.contacts, dtype=bool).tolist(),
        "repaired": [int(f) for f in t.repaired],
        "keyframes": [{"frame": int(k.frame), "error_m": float(k.error_m),
                       "effectors": [e.to_dict() for e in k.effectors]} for k in t.keyframes],
    }


def animation_to_dict(animation: Animation) -> dict[str, Any]:
    """The JSON object of an :class:`Animation` (module docstring)."""
    return {
        "format": ANIMATION_FORMAT, "version": ANIMATION_VERSION, "source": animation.source,
        "source_format": animation.source_format, "fps": float(animation.fps), "space": animation.space,
        "camera": None if animation.camera is None else animation.camera.to_dict(),
        "clean": None if animation.clean is None else dataclasses.asdict(animation.clean),
        "tracks": [_track_to_dict(t) for t in animation.tracks],
    }


def _whole(value: Any, path: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise AnimationFileError(f"{path}: expected a whole number, got {short_repr(value)}.")
    if not low <= value <= high:
        raise AnimationFileError(f"{path}: {value} is outside [{low}, {high}].")
    return value


def _frames_array(value: Any, tail: tuple[int, ...], T: int | None, path: str) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise AnimationFileError(f"{path}: expected a non-empty list of per-frame values.")
    if len(value) > MAX_FRAMES:
        raise AnimationFileError(f"{path}: {len(value)} frames; at most {MAX_FRAMES} are accepted.")
    n = len(value) if T is None else T
    if len(value) != n:
        raise AnimationFileError(f"{path}: has {len(value)} frames; expected {n} (as global_orient).")
    try:
        return _numbers(value, (n, *tail), path)
    except SceneError as exc:
        raise AnimationFileError(str(exc)) from None


def _body(data: Mapping[str, Any], path: str, camera: Any) -> SceneCharacter:
    """A track's body fields, validated by the scene reader (its messages re-pointed at ``path``)."""
    mini = {"format": "smplik-scene", "version": 1, "camera": camera,
            "characters": [{k: data[k] for k in _BODY_KEYS if k in data}]}
    try:
        return scene_from_dict(mini, source="").characters[0]
    except SceneError as exc:
        message = str(exc).removeprefix(": ").replace("characters[0]", path)
        raise AnimationFileError(message) from None


def _keyframe(data: Any, path: str, frames: range) -> Keyframe:
    _expect(data, Mapping, path, "a keyframe object")
    _check_keys(data, {"frame", "error_m", "effectors"}, path)
    frame = _whole(data.get("frame"), f"{path}.frame", 0, MAX_FRAMES * 1000)
    if frame not in frames:
        raise AnimationFileError(f"{path}.frame: {frame} is outside the track's frames {frames.start}.."
                                 f"{frames.stop - 1}.")
    error = float(_numbers(data.get("error_m", 0.0), (), f"{path}.error_m"))
    if error < 0:
        raise AnimationFileError(f"{path}.error_m: must be >= 0, got {error}.")
    effs = _expect(data.get("effectors", []), list, f"{path}.effectors", "a list")
    if len(effs) > MAX_EFFECTORS:  # counted before any is parsed: the scenes' cap, per keyframe
        raise AnimationFileError(f"{path}.effectors: {len(effs)} effectors; at most {MAX_EFFECTORS} per keyframe are "
                                 "accepted (as in a scene).")
    err = JSONPathError("", AnimationFileError)
    return Keyframe(frame, tuple(parse_effector_dict(e, f"{path}.effectors[{i}]", err) for i, e in enumerate(effs)),
                    error)


def _track(data: Any, path: str, camera: Any) -> AnimationTrack:
    _expect(data, Mapping, path, "a track object")
    _check_keys(data, _TRACK_KEYS, path)
    body = _body(data, path, camera)
    track_id = _expect(data.get("track_id", "0"), str, f"{path}.track_id", "a string")
    first = _whole(data.get("first_frame", 0), f"{path}.first_frame", 0, MAX_FRAMES * 1000)
    go = _frames_array(data.get("global_orient"), (3,), None, f"{path}.global_orient")
    T = go.shape[0]
    bp = _frames_array(data.get("body_pose"), (23, 3), T, f"{path}.body_pose")
    tr = _frames_array(data.get("transl"), (3,), T, f"{path}.transl")
    if np.abs(go).max() > 1e3 or np.abs(bp).max() > 1e3:
        raise AnimationFileError(f"{path}: axis-angle values beyond 1000 rad are not rotations.")
    if np.abs(tr).max() > 1e4:
        raise AnimationFileError(f"{path}.transl: beyond 10 km.")
    contacts = None
    if data.get("contacts") is not None:
        raw = data["contacts"]
        if (not isinstance(raw, list) or len(raw) != T
                or not all(isinstance(r, list) and len(r) == 2 and all(isinstance(b, bool) for b in r) for r in raw)):
            raise AnimationFileError(f"{path}.contacts: expected {T} pairs of booleans [left, right].")
        contacts = np.asarray(raw, dtype=bool)
    frames = range(first, first + T)
    keys = _expect(data.get("keyframes", []), list, f"{path}.keyframes", "a list")
    keyframes = tuple(_keyframe(k, f"{path}.keyframes[{i}]", frames) for i, k in enumerate(keys))
    for i in range(1, len(keyframes)):
        if keyframes[i].frame <= keyframes[i - 1].frame:
            raise AnimationFileError(f"{path}.keyframes[{i}].frame: {keyframes[i].frame} does not follow "
                                     f"{keyframes[i - 1].frame}; keyframes must be strictly increasing.")
    repaired = _expect(data.get("repaired", []), list, f"{path}.repaired", "a list of frames")
    for i, f in enumerate(repaired):
        _whole(f, f"{path}.repaired[{i}]", frames.start, frames.stop - 1)
        if i and f <= repaired[i - 1]:
            raise AnimationFileError(f"{path}.repaired[{i}]: {f} does not follow {repaired[i - 1]}; frames must be "
                                     "strictly increasing.")
    return AnimationTrack(body.name, track_id, body.gender, body.betas, body.scale, body.skeleton, first, go, bp, tr,
                          keyframes, contacts, tuple(repaired))


def _clean(data: Any) -> CleanConfig:
    _expect(data, Mapping, "clean", "an object")
    _check_keys(data, {f.name for f in dataclasses.fields(CleanConfig)}, "clean")
    try:
        return CleanConfig(**data)
    except (TypeError, ValueError) as exc:
        raise AnimationFileError(f"clean: {exc}") from None


def animation_from_dict(data: Any, source: str = "animation") -> Animation:
    """Validate and build an :class:`Animation`; errors read ``<source>: <JSON path>: <problem>``."""
    try:
        return _animation(data)
    except SceneError as exc:
        raise AnimationFileError(f"{source}: {exc}") from None


def _animation(data: Any) -> Animation:
    _expect(data, Mapping, "(root)", "a JSON object")
    fmt, version = data.get("format"), data.get("version")
    if fmt != ANIMATION_FORMAT:
        raise AnimationFileError(f"format: expected {ANIMATION_FORMAT!r}, got {short_repr(fmt)}.")
    if version != ANIMATION_VERSION or isinstance(version, bool):
        raise AnimationFileError(f"version: this smplik reads version {ANIMATION_VERSION}, got {short_repr(version)}.")
    _check_keys(data, _ROOT_KEYS, "(root)")
    try:
        fps = check_rate(data.get("fps"), "fps")
    except LimitError as exc:
        raise AnimationFileError(str(exc)) from None
    space = data.get("space", "camera")
    if space not in ("camera", "world"):
        raise AnimationFileError(f"space: expected 'camera' or 'world', got {short_repr(space)}.")
    for key in ("source", "source_format"):
        if data.get(key) is not None:
            _expect(data[key], str, key, "a string or null")
    tracks = _expect(data.get("tracks"), list, "tracks", "a list")
    if len(tracks) > MAX_TRACKS:
        raise AnimationFileError(f"tracks: {len(tracks)} tracks; at most {MAX_TRACKS} are accepted.")
    camera = data.get("camera")
    parsed = tuple(_track(t, f"tracks[{i}]", camera) for i, t in enumerate(tracks))
    names = [t.name for t in parsed]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise AnimationFileError(f"tracks: the name {duplicate!r} is used twice; names select tracks.")
    cam = None
    if camera is not None:
        cam = scene_from_dict({"format": "smplik-scene", "version": 1, "camera": camera, "characters": []},
                              source="").camera
    clean = None if data.get("clean") is None else _clean(data["clean"])
    return Animation(parsed, fps, data.get("source"), data.get("source_format"), space, cam, clean)


def load_animation(path: str | Path) -> Animation:
    """Read and validate an animation file (one-line :class:`AnimationFileError` naming file and JSON path)."""
    return animation_from_dict(read_json(path, AnimationFileError, what="animation file"), source=str(path))


def save_animation(animation: Animation, path: str | Path) -> Path:
    """Write ``animation`` as JSON atomically; one that would not read back is refused and nothing is written."""
    data = animation_to_dict(animation)
    animation_from_dict(json.loads(json.dumps(data)), source=str(path))
    return write_json_atomic(path, data, indent=None)


def scene_of(animation: Animation, frame: int | None = None) -> Scene:
    """A scene with one character per track, posed at source frame ``frame`` (default: each track's first
    keyframe, with its effectors; a track without that frame gets no pose)."""
    chars = []
    for t in animation.tracks:
        key = next((k for k in t.keyframes if frame is None or k.frame == frame), None)
        at = (key.frame if key is not None else t.first_frame) if frame is None else frame
        pose = t.pose(at - t.first_frame) if at in t.frames else None
        chars.append(SceneCharacter(t.name, t.gender, np.asarray(t.betas, dtype=np.float64), t.scale, t.skeleton,
                                    key.effectors if key is not None and key.frame == at else (), pose))
    return Scene(tuple(chars), animation.source, None, animation.camera)
