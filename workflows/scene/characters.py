"""A scene's characters: the records of one character (body, scale, skeleton source, effectors, pose), the
ground record, the scene error, and the solving of one character.

The scene document that holds them, its file format and spaces: :mod:`workflows.scene.document`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from shape_inversion.options import CharacterOptions
from smplik.conventions import EffectorType, Gender
from smplik.data.bvh import DEFAULT_MAX_JOINTS
from smplik.effectors import Effector
from smplik.pose import Pose


class SceneError(ValueError):
    """A scene file is invalid; the message names the JSON path."""


@dataclass(frozen=True)
class SkeletonSource:
    """Where a custom character's skeleton comes from: a file and how to read it.

    The fields after ``path`` are those of :class:`shape_inversion.options.CharacterOptions` (same
    names, defaults and meaning), so ``scene solve`` / ``scene export`` re-read the character exactly
    as ``scene from-estimate --character`` did.
    """

    path: str
    rig: str | None = None
    map: str | None = None
    units: str = "auto"
    up: str = "auto"
    rest: str = "auto"
    bind: str = "inverse_bind"
    positions: str = "auto"
    max_joints: int = DEFAULT_MAX_JOINTS
    root: str | None = None
    joint_map: dict[str, str] | None = None
    """The SMPL joint -> rig joint map the character was read with (a record; re-reading maps it again)."""

    def __hash__(self) -> int:
        # The dataclass hash would hash the joint_map dict (unhashable); hash its items instead, so a
        # skeleton record can key caches (the editor's per-character cache) like every other field.
        fields = tuple(getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "joint_map")
        items = None if self.joint_map is None else tuple(sorted(self.joint_map.items()))
        return hash((fields, items))

    @classmethod
    def from_options(cls, path: str, options: CharacterOptions,
                     joint_map: Mapping[str, str] | None = None) -> SkeletonSource:
        return cls(path, **options.to_dict(), joint_map=None if joint_map is None else dict(joint_map))

    @property
    def options(self) -> CharacterOptions:
        """The character options (validated)."""
        data = dataclasses.asdict(self)
        data.pop("path")
        data.pop("joint_map")
        return CharacterOptions.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


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


# ----------------------------------------------------------------------------- solving one character


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


def character_joints(character: SceneCharacter) -> np.ndarray | None:
    """The character's posed joints in character space (24, 3), or None without a pose."""
    if character.pose is None:
        return None
    joints = character.pose.joints
    if joints is None:
        from workflows.scene.recovery import TargetPose

        joints = TargetPose.from_pose(character.pose).p_world.double().numpy()
    return np.asarray(joints) * character.scale
