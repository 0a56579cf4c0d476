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
          "skeleton": null | {"path": "hero.bvh", "rig": "mixamo" | null},
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

Errors are ``ValueError`` naming the file and the JSON path, e.g.
``scene.json: characters[1].effectors[0].value: has shape (2,); expected (3,)``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.atomic import write_json_atomic
from smplik.conventions import NUM_BETAS, EffectorType, Gender
from smplik.effectors import Effector
from smplik.pose import Pose
from smplik.validation import finite_array
from workflows.estimators.base import CameraInfo

SCENE_FORMAT = "smplik-scene"
SCENE_VERSION = 1


class SceneError(ValueError):
    """A scene file is invalid; the message names the JSON path."""


@dataclass(frozen=True)
class SkeletonSource:
    """Where a custom character's skeleton comes from: a file and its rig preset (None: detected)."""

    path: str
    rig: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"path": self.path, "rig": self.rig}


@dataclass(frozen=True)
class SceneCharacter:
    """One character: its SMPL body, scale, optional custom skeleton, effectors and solved pose."""

    name: str
    gender: Gender
    betas: np.ndarray
    scale: float = 1.0
    skeleton: SkeletonSource | None = None
    effectors: tuple[Effector, ...] = ()
    pose: Pose | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "gender": self.gender.value,
            "betas": [float(b) for b in self.betas],
            "scale": float(self.scale),
            "skeleton": None if self.skeleton is None else self.skeleton.to_dict(),
            "effectors": [e.to_dict() for e in self.effectors],
            "pose": None if self.pose is None else self.pose.to_dict(),
        }


@dataclass(frozen=True)
class GroundRecord:
    """``--ground``: the people were moved up onto a floor (their lowest point at y = 0).

    Attributes:
        camera_height_m: the shift; the world is the camera frame moved up by it, so the estimator's
            camera centre sits at ``(0, camera_height_m, 0)`` (same orientation) and overlays still fit.
    """

    camera_height_m: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"camera_height_m": float(self.camera_height_m)}


@dataclass(frozen=True)
class Scene:
    """A scene: characters plus, for estimator scenes, the source, image, camera and ground record."""

    characters: tuple[SceneCharacter, ...]
    source: str | None = None
    image: str | None = None
    camera: CameraInfo | None = None
    ground: GroundRecord | None = None

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
        raise SceneError(f"{path}: expected {what}, got {type(value).__name__} {value!r:.60}.")
    return value


def _numbers(value: Any, shape: tuple[int, ...], path: str) -> np.ndarray:
    return finite_array(value, shape, path, SceneError)


def _effector(data: Any, path: str) -> Effector:
    _expect(data, Mapping, path, "an effector object")
    for key, shape in (("value", (3, 3) if str(data.get("type", "")).lower() == "rotation" else (3,)),
                       ("target", (3,)), ("direction", (3,))):
        if key in data:
            _numbers(data[key], shape, f"{path}.{key}")
    try:
        return Effector.from_dict(data)
    except ValueError as exc:
        raise SceneError(f"{path}: {exc}") from None


def _character(data: Any, path: str) -> SceneCharacter:
    _expect(data, Mapping, path, "a character object")
    allowed = {"name", "gender", "betas", "scale", "skeleton", "effectors", "pose"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise SceneError(f"{path}: unknown key(s) {unknown}; allowed: {sorted(allowed)}.")
    name = _expect(data.get("name", ""), str, f"{path}.name", "a string")
    try:
        gender = Gender.parse(_expect(data.get("gender", "neutral"), str, f"{path}.gender", "a string"))
    except ValueError as exc:
        raise SceneError(f"{path}.gender: {exc}") from None
    betas = _numbers(data.get("betas", [0.0] * NUM_BETAS), (NUM_BETAS,), f"{path}.betas")
    scale = float(_numbers(data.get("scale", 1.0), (), f"{path}.scale"))
    if scale <= 0:
        raise SceneError(f"{path}.scale: must be positive, got {scale}.")
    skeleton = None
    if data.get("skeleton") is not None:
        sk = _expect(data["skeleton"], Mapping, f"{path}.skeleton", "null or {\"path\", \"rig\"}")
        sk_path = _expect(sk.get("path"), str, f"{path}.skeleton.path", "a string")
        rig = sk.get("rig")
        if rig is not None:
            _expect(rig, str, f"{path}.skeleton.rig", "a string or null")
        skeleton = SkeletonSource(sk_path, rig)
    effs = _expect(data.get("effectors", []), list, f"{path}.effectors", "a list")
    effectors = tuple(_effector(e, f"{path}.effectors[{i}]") for i, e in enumerate(effs))
    pose = None
    if data.get("pose") is not None:
        try:
            pose = Pose.from_dict(dict(_expect(data["pose"], Mapping, f"{path}.pose", "a pose object")),
                                  source=f"{path}.pose")
        except ValueError as exc:
            raise SceneError(str(exc)) from None
    return SceneCharacter(name or path, gender, betas, scale, skeleton, effectors, pose)


def scene_from_dict(data: Any, source: str = "scene") -> Scene:
    """Validate and build a :class:`Scene`; errors read ``<source>: <JSON path>: <problem>``."""
    try:
        return _scene(data)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _scene(data: Any) -> Scene:
    _expect(data, Mapping, "(root)", "a JSON object")
    fmt, version = data.get("format"), data.get("version")
    if fmt != SCENE_FORMAT:
        raise SceneError(f"format: expected {SCENE_FORMAT!r}, got {fmt!r}.")
    if version != SCENE_VERSION:
        raise SceneError(f"version: this smplik reads version {SCENE_VERSION}, got {version!r}.")
    allowed = {"format", "version", "source", "image", "camera", "ground", "characters"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise SceneError(f"(root): unknown key(s) {unknown}; allowed: {sorted(allowed)}.")
    chars = _expect(data.get("characters"), list, "characters", "a list")
    characters = tuple(_character(c, f"characters[{i}]") for i, c in enumerate(chars))
    camera = None
    if data.get("camera") is not None:
        cam = _expect(data["camera"], Mapping, "camera", "an object")
        try:
            camera = CameraInfo.from_dict(dict(cam))
        except (TypeError, ValueError, IndexError) as exc:
            raise SceneError(f"camera: {exc}") from None
    for key in ("source", "image"):
        if data.get(key) is not None:
            _expect(data[key], str, key, "a string or null")
    ground = None
    if data.get("ground") is not None:
        g = _expect(data["ground"], Mapping, "ground", "an object")
        ground = GroundRecord(float(_numbers(g.get("camera_height_m", 0.0), (), "ground.camera_height_m")))
    return Scene(characters, data.get("source"), data.get("image"), camera, ground)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"Scene file not found: {path}") from None
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: invalid JSON ({exc}).") from None
    return scene_from_dict(data, source=str(path))


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write ``scene`` as JSON, atomically."""
    return write_json_atomic(path, scene.to_dict())


# ----------------------------------------------------------------------------- solving


def scale_effector(effector: Effector, factor: float) -> Effector:
    """The effector with its position / look-at target multiplied by ``factor`` (rotations unchanged)."""
    if effector.type == EffectorType.ROTATION:
        return effector
    return dataclasses.replace(effector, value=np.asarray(effector.value) * factor)


def solve_character(character: SceneCharacter, solver: Any) -> SceneCharacter:
    """Re-solve one character from its effectors (character space) and shape; no effectors: unchanged."""
    if not character.effectors:
        return character
    effectors = [scale_effector(e, 1.0 / character.scale) for e in character.effectors]
    pose = solver.solve(effectors, betas=character.betas, gender=character.gender)
    return dataclasses.replace(character, pose=pose)


def solve_scene(scene: Scene, solver: Any, *, only: Sequence[str] | None = None) -> Scene:
    """Re-solve every character (or those named in ``only``) with ``solver.solve`` (an IKSolver)."""
    chars = tuple(solve_character(c, solver) if only is None or c.name in only else c for c in scene.characters)
    return dataclasses.replace(scene, characters=chars)


def character_joints(character: SceneCharacter) -> np.ndarray | None:
    """The character's posed joints in character space (24, 3), or None without a pose."""
    if character.pose is None:
        return None
    joints = character.pose.joints
    if joints is None:
        from workflows.recovery import TargetPose

        joints = TargetPose.from_pose(character.pose).p_world.double().numpy()
    return np.asarray(joints) * character.scale
