"""The editable scene: a versioned JSON file of characters, their effectors and solved poses.

Format ``smplik-scene``, version :data:`SCENE_VERSION`::

    {
      "format": "smplik-scene",
      "version": 1,
      "source": "results.npz",                       # optional: what the scene came from
      "image": "photo.jpg",                          # optional: source image (relative to the scene file)
      "camera": {"focal_px": null, "image_size": [640, 480], "default_fov_deg": 60.0,
                 "principal_px": null, "focal_rule": "fov"},   # optional: the estimator's intrinsics
      "ground": {"camera_height_m": 1.42},           # optional: --ground moved the people onto y = 0
      "characters": [
        {
          "name": "person_0",
          "gender": "neutral",
          "betas": [10 numbers],
          "scale": 1.0,
          "skeleton": null | {"path": "hero.bvh", "rig": "mixamo" | null, "map": null, "units": "auto",
                               "up": "auto", "rest": "auto", "bind": "inverse_bind", "positions": "auto",
                               "max_joints": 10000, "root": null,   # the character options (all but path optional)
                               "joint_map": {"pelvis": "Hips", ...}},  # the map used (a record)
          "effectors": [{"joint": "left_wrist", "type": "position", "value": [x, y, z], "tolerance": 0.0}, ...],
          "pose": {"global_orient": [...], "body_pose": [...], "transl": [...], "betas": [...], "gender": ...}
        }
      ]
    }

Spaces. The world is smplik's y-up frame in metres (for estimator scenes: the camera centre at the
origin, looking down -z). A character is its SMPL body ``(betas, gender)`` scaled by ``scale``
about the world origin (scaling about the camera centre keeps the image projection unchanged).
**Effectors are in character space** (what a user sees and edits); **``pose`` is in SMPL space**
(smplx parameters of the unscaled body; its ``joints`` times ``scale`` are the character's joints).
:func:`solve_scene` divides effector positions and look-at targets by ``scale`` before solving.

Errors are :class:`SceneError` (a ``ValueError``) naming the file and the JSON path, e.g.
``scene.json: characters[1].effectors[0].value: has shape (2,); expected (3,)``. The reader is strict:
the allowed keys are the fields of :class:`Scene`, :class:`SceneCharacter`, :class:`SkeletonSource` and
:class:`~workflows.estimators.base.CameraInfo`; a character's ``pose`` must have the character's betas and
gender; the focal length must be a positive finite number (or null), the scale in [0.001, 1000], at most
:data:`MAX_CHARACTERS` characters with unique names, effectors as in effector files.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shape_inversion.options import CharacterOptions
from smplik.atomic import write_json_atomic
from smplik.conventions import NUM_BETAS, EffectorType, Gender
from smplik.effector_schema import MAX_EFFECTORS
from smplik.effectors import parse_effector_dict
from smplik.pose import Pose
from smplik.validation import (
    MAX_ABS_POSITION_M,
    MAX_SCALE,
    MIN_SCALE,
    JSONPathError,
    check_betas,
    finite_array,
    read_json,
    short_repr,
)
from workflows.estimators.base import CameraInfo
from workflows.scene.characters import (
    GroundRecord,
    SceneCharacter,
    SceneError,
    SkeletonSource,
    solve_character,
)

SCENE_FORMAT = "smplik-scene"
SCENE_VERSION = 1
MAX_CHARACTERS = 100
"""Most characters a scene file may hold (``load_scene(..., max_characters=)`` raises it)."""


@dataclass(frozen=True)
class Scene:
    """A scene: characters plus, for estimator scenes, the source, image, camera and ground record."""

    characters: tuple[SceneCharacter, ...]
    source: str | None = None
    image: str | None = None
    camera: CameraInfo | None = None
    ground: GroundRecord | None = None

    def drag(self, character: str, joint: str | int, *, position: Any = None, offset: Any = None,
             rotation: Any = None, tolerance: float = 0.0, solver: Any = None) -> Scene:
        """A scripted drag, as in the editor: this scene with ``character``'s effector on ``joint`` moved (or
        added) and the character re-solved so that only the dragged limb moves
        (:func:`workflows.scene.edits.drag_scene_effector`, which also returns what was relaxed).

        Exactly one of ``position`` (3,) (character space, metres), ``offset`` (3,) (from where the stored pose
        has the joint) or ``rotation`` (3, 3) (world); ``solver``: default the shipped model."""
        from workflows.scene.edits import drag_scene_effector

        return drag_scene_effector(self, character, joint, position=position, offset=offset, rotation=rotation,
                                   tolerance=tolerance, solver=solver)[0]

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": SCENE_FORMAT,
            "version": SCENE_VERSION,
            "source": self.source,
            "image": self.image,
            "camera": None if self.camera is None else self.camera.to_dict(),
            "ground": None if self.ground is None else self.ground.to_dict(),
            "characters": [c.to_dict() for c in self.characters],
        }


# ----------------------------------------------------------------------------- parsing


def _expect(value: Any, kind: type | tuple[type, ...], path: str, what: str) -> Any:
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise SceneError(f"{path}: expected {what}, got {type(value).__name__} {short_repr(value)}.")
    return value


def _numbers(value: Any, shape: tuple[int, ...], path: str) -> np.ndarray:
    return finite_array(value, shape, path, SceneError)


def _field_names(cls: type) -> set[str]:
    """The JSON keys of a scene record: its dataclass fields (so a new field is a new allowed key)."""
    return {f.name for f in dataclasses.fields(cls)}


def _file_name(value: Any, path: str, what: str) -> str:
    """``value`` as a file path string: a string without a NUL character (the OS refuses those with "embedded
    null byte", a line naming no file)."""
    _expect(value, str, path, what)
    if "\x00" in value:
        raise SceneError(f"{path}: {short_repr(value)} holds a NUL character (\\u0000); not a file path.")
    return value


def _check_keys(data: Mapping[str, Any], allowed: set[str], path: str) -> None:
    unknown = sorted(str(k) for k in set(data) - allowed)
    if unknown:
        raise SceneError(f"{path}: unknown key(s) {unknown}; allowed: {sorted(allowed)}.")


def _character(data: Any, path: str) -> SceneCharacter:
    _expect(data, Mapping, path, "a character object")
    _check_keys(data, _field_names(SceneCharacter), path)
    name = _expect(data.get("name", ""), str, f"{path}.name", "a string")
    try:
        gender = Gender.parse(_expect(data.get("gender", "neutral"), str, f"{path}.gender", "a string"))
    except ValueError as exc:
        raise SceneError(f"{path}.gender: {exc}") from None
    betas = check_betas(data.get("betas", [0.0] * NUM_BETAS), where=f"{path}.betas", error=SceneError)
    scale = float(_numbers(data.get("scale", 1.0), (), f"{path}.scale"))
    if not MIN_SCALE <= scale <= MAX_SCALE:
        raise SceneError(f"{path}.scale: must be in [{MIN_SCALE:g}, {MAX_SCALE:g}], got {scale}.")
    skeleton = None
    if data.get("skeleton") is not None:
        sk = _expect(data["skeleton"], Mapping, f"{path}.skeleton", "null or {\"path\", \"rig\", ...}")
        _check_keys(sk, _field_names(SkeletonSource), f"{path}.skeleton")
        sk_path = _file_name(sk.get("path"), f"{path}.skeleton.path", "a string")
        if sk.get("map") is not None:
            _file_name(sk["map"], f"{path}.skeleton.map", "a file path or null")
        try:
            options = CharacterOptions.from_dict({k: v for k, v in sk.items() if k not in ("path", "joint_map")})
        except (ValueError, TypeError) as exc:
            raise SceneError(f"{path}.skeleton: {exc}") from None
        joint_map = sk.get("joint_map")
        if joint_map is not None and not (isinstance(joint_map, Mapping) and all(
                isinstance(k, str) and isinstance(v, str) for k, v in joint_map.items())):
            raise SceneError(f"{path}.skeleton.joint_map: expected null or an object of SMPL joint -> rig joint names.")
        skeleton = SkeletonSource.from_options(sk_path, options, joint_map)
    effs = _expect(data.get("effectors", []), list, f"{path}.effectors", "a list")
    if len(effs) > MAX_EFFECTORS:
        raise SceneError(f"{path}.effectors: has {len(effs)} effectors; at most {MAX_EFFECTORS} are accepted.")
    err = JSONPathError("", SceneError)
    effectors = tuple(parse_effector_dict(e, f"{path}.effectors[{i}]", err) for i, e in enumerate(effs))
    # Effectors are in character space: the solve divides them by the scale, which must stay in range.
    for i, e in enumerate(effectors):
        if e.type != EffectorType.ROTATION and np.abs(e.value).max() / scale > MAX_ABS_POSITION_M:
            raise SceneError(f"{path}.effectors[{i}]: the target divided by scale {scale:g} is beyond "
                             f"{MAX_ABS_POSITION_M:g} m.")
    pose = None
    if data.get("pose") is not None:
        try:
            pose = Pose.from_dict(dict(_expect(data["pose"], Mapping, f"{path}.pose", "a pose object")),
                                  source=f"{path}.pose")
        except SceneError:
            raise
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        if not np.allclose(pose.betas, betas, atol=1e-6):
            raise SceneError(f"{path}.pose.betas: {short_repr(pose.betas.round(4).tolist())} do not match the "
                             f"character's betas {short_repr(betas.round(4).tolist())}; re-solve the character "
                             "or remove its pose.")
        if pose.gender != gender:
            raise SceneError(f"{path}.pose.gender: {pose.gender.value!r} does not match the character's gender "
                             f"{gender.value!r}.")
    return SceneCharacter(name or path, gender, betas, scale, skeleton, effectors, pose)


def _camera(data: Any) -> CameraInfo:
    cam = _expect(data, Mapping, "camera", "an object")
    _check_keys(cam, _field_names(CameraInfo), "camera")
    focal = cam.get("focal_px")
    if focal is not None:
        focal = float(_numbers(focal, (), "camera.focal_px"))
        if not focal > 0:
            raise SceneError(f"camera.focal_px: must be a positive number of pixels or null, got {focal}.")
    size = cam.get("image_size")
    if size is not None:
        arr = _numbers(size, (2,), "camera.image_size")
        if not ((arr >= 1) & (arr <= 100_000) & (arr == np.round(arr))).all():
            raise SceneError(f"camera.image_size: must be two whole numbers of pixels in [1, 100000], "
                             f"got {short_repr(size)}.")
    fov = float(_numbers(cam.get("default_fov_deg", 60.0), (), "camera.default_fov_deg"))
    if not 1.0 <= fov <= 179.0:
        raise SceneError(f"camera.default_fov_deg: must be in [1, 179] degrees, got {fov}.")
    try:
        return CameraInfo.from_dict(dict(cam))
    except (TypeError, ValueError, IndexError, KeyError) as exc:
        raise SceneError(f"camera: {exc}") from None


def scene_from_dict(data: Any, source: str = "scene", *, max_characters: int | None = None) -> Scene:
    """Validate and build a :class:`Scene`; errors read ``<source>: <JSON path>: <problem>``.

    Strict: the keys of the scene, each character, skeleton and camera are their dataclass fields;
    at most ``max_characters`` (default :data:`MAX_CHARACTERS`) characters."""
    try:
        return _scene(data, MAX_CHARACTERS if max_characters is None else max_characters)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _scene(data: Any, max_characters: int) -> Scene:
    _expect(data, Mapping, "(root)", "a JSON object")
    fmt, version = data.get("format"), data.get("version")
    if fmt != SCENE_FORMAT:
        raise SceneError(f"format: expected {SCENE_FORMAT!r}, got {short_repr(fmt)}.")
    if version != SCENE_VERSION or isinstance(version, bool):
        raise SceneError(f"version: this smplik reads version {SCENE_VERSION}, got {short_repr(version)}.")
    _check_keys(data, {"format", "version"} | _field_names(Scene), "(root)")
    chars = _expect(data.get("characters"), list, "characters", "a list")
    if len(chars) > max_characters:
        raise SceneError(f"characters: {len(chars)} characters; at most {max_characters} are accepted "
                         "(raise the cap with max_characters=, workflows.scene.MAX_CHARACTERS).")
    characters = tuple(_character(c, f"characters[{i}]") for i, c in enumerate(chars))
    names = [c.name for c in characters]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise SceneError(f"characters: the name {duplicate!r} is used twice; names select characters.")
    camera = None if data.get("camera") is None else _camera(data["camera"])
    for key in ("source", "image"):
        if data.get(key) is not None:
            _file_name(data[key], key, "a string or null")
    ground = None
    if data.get("ground") is not None:
        g = _expect(data["ground"], Mapping, "ground", "an object")
        _check_keys(g, _field_names(GroundRecord), "ground")
        ground = GroundRecord(float(_numbers(g.get("camera_height_m", 0.0), (), "ground.camera_height_m")))
    return Scene(characters, data.get("source"), data.get("image"), camera, ground)


def load_scene(path: str | Path, *, max_characters: int | None = None) -> Scene:
    """Read and validate a scene file (one-line :class:`SceneError` naming the file and JSON path)."""
    return scene_from_dict(read_json(path, SceneError, what="scene file"), source=str(path),
                           max_characters=max_characters)


def relative_to_scene(name: str | None, scene_dir: Path) -> str | None:
    """An absolute file path rewritten relative to the scene file's folder (POSIX separators), so a moved folder
    keeps working; relative paths (already relative to the scene file) and paths on another drive are kept."""
    import os

    if name is None or not Path(name).is_absolute():
        return name
    try:
        return Path(os.path.relpath(Path(name), Path(scene_dir).resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        return name


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write ``scene`` as JSON, atomically; a scene that would not read back (NaN focal length, betas
    that do not match a pose, ...) is refused with a :class:`SceneError` and nothing is written.

    Absolute skeleton and image paths are written relative to the scene file (:func:`relative_to_scene`);
    readers resolve relative paths against the scene file's folder and still read absolute ones."""
    folder = Path(path).parent
    scene = dataclasses.replace(scene, image=relative_to_scene(scene.image, folder), characters=tuple(
        c if c.skeleton is None else dataclasses.replace(c, skeleton=dataclasses.replace(
            c.skeleton, path=relative_to_scene(c.skeleton.path, folder))) for c in scene.characters))
    data = scene.to_dict()
    scene_from_dict(json.loads(json.dumps(data)), source=str(path),
                    max_characters=max(MAX_CHARACTERS, len(scene.characters)))
    return write_json_atomic(path, data)


def solve_scene(scene: Scene, solver: Any, *, only: Sequence[str] | None = None) -> Scene:
    """Re-solve every character (or those named in ``only``) exactly from all its effectors with ``solver.solve``
    (an IKSolver): ``smplik scene solve --exact``. Plain ``scene solve`` solves only the effectors the stored pose
    does not meet, as drags (:func:`workflows.scene.edits.solve_scene_edits`)."""
    chars = tuple(solve_character(c, solver) if only is None or c.name in only else c for c in scene.characters)
    return dataclasses.replace(scene, characters=chars)
