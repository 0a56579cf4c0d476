"""The SMPL pose value type and its JSON file format.

JSON keys are exactly smplx's argument names plus the body: ``global_orient`` (3), ``body_pose``
(23 x 3) axis-angle radians, ``transl`` (3) metres in the y-up world, ``betas`` (10),
``gender`` ("neutral" | "male" | "female") and ``joints`` (24 x 3, metres; optional on load).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.atomic import write_json_atomic
from smplik.conventions import NUM_BETAS, NUM_JOINTS, Gender
from smplik.validation import MAX_ABS_POSITION_M, check_betas, finite_array, read_json, short_repr

MAX_ABS_AXIS_ANGLE = 1000.0
"""Largest accepted |axis-angle component| (radians); angles wrap, so this only bounds the numbers."""
POSE_KEYS = ("global_orient", "body_pose", "transl", "betas", "gender", "joints")
_SHAPES = {"global_orient": (3,), "body_pose": (NUM_JOINTS - 1, 3), "transl": (3,), "betas": (NUM_BETAS,),
           "joints": (NUM_JOINTS, 3)}


def _array(name: str, value: Any, source: str = "pose") -> np.ndarray:
    if name == "betas":
        return check_betas(value, where=f"{source}: '{name}'")
    limit = MAX_ABS_POSITION_M if name in ("transl", "joints") else MAX_ABS_AXIS_ANGLE
    return finite_array(value, _SHAPES[name], f"{source}: '{name}'", max_abs=limit)


def _gender(value: Any, source: str) -> Gender:
    if not isinstance(value, (str, Gender)):
        raise ValueError(f"{source}: 'gender' must be one of neutral, male, female; got {short_repr(value)}.")
    try:
        return Gender.parse(value)
    except ValueError as exc:
        raise ValueError(f"{source}: 'gender': {exc}") from None


@dataclass(frozen=True)
class Pose:
    """One SMPL body pose (numpy, float64). ``joints`` are the posed joints when known."""

    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    betas: np.ndarray
    gender: Gender = Gender.NEUTRAL
    joints: np.ndarray | None = None

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "pose") -> Pose:
        """Build from a dict with the JSON keys; missing ``betas``/``transl`` default to zeros."""
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a JSON object with keys {', '.join(POSE_KEYS)}.")
        unknown = set(data) - set(POSE_KEYS)
        if unknown:
            raise ValueError(f"{source}: unknown key(s) {sorted(unknown)}; valid keys: {', '.join(POSE_KEYS)}.")
        for key in ("global_orient", "body_pose"):
            if key not in data:
                raise ValueError(f"{source}: missing key '{key}'.")
        return cls(
            global_orient=_array("global_orient", data["global_orient"], source),
            body_pose=_array("body_pose", data["body_pose"], source),
            transl=_array("transl", data.get("transl", [0.0] * 3), source),
            betas=_array("betas", data.get("betas", [0.0] * NUM_BETAS), source),
            gender=_gender(data.get("gender", "neutral"), source),
            joints=None if data.get("joints") is None else _array("joints", data["joints"], source),
        )

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "global_orient": self.global_orient.tolist(),
            "body_pose": self.body_pose.tolist(),
            "transl": self.transl.tolist(),
            "betas": self.betas.tolist(),
            "gender": self.gender.value,
        }
        if self.joints is not None:
            out["joints"] = self.joints.tolist()
        return out

    def to_smplx_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for an ``smplx.SMPL`` layer (batch of 1, float32 tensors)."""
        import torch

        return {
            "global_orient": torch.as_tensor(self.global_orient, dtype=torch.float32)[None],
            "body_pose": torch.as_tensor(self.body_pose.reshape(-1), dtype=torch.float32)[None],
            "transl": torch.as_tensor(self.transl, dtype=torch.float32)[None],
            "betas": torch.as_tensor(self.betas, dtype=torch.float32)[None],
        }

    def save(self, path: str | Path) -> Path:
        """Write the pose as JSON (atomically)."""
        return write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> Pose:
        """Read a pose JSON file; errors are one-line ``ValueError`` naming the file and key."""
        return cls.from_dict(read_json(path, ValueError, what="pose file"), source=str(path))
