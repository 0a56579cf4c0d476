"""Effectors: the user's constraints and their tensor packing (training-time sampling:
:mod:`smplik.data.effector_sampling`).

An effector targets one SMPL joint and is one of (ProtoRes section 2):

* ``position``: the joint's world position (metres).
* ``rotation``: the joint's **global** rotation ``R_world_joint`` (3 x 3).
* ``look_at``: a world ``target`` the joint should face along a unit ``direction`` given in the
  joint's own frame (e.g. ``(0, 0, 1)`` for the head's forward axis).

Each has a ``tolerance`` in [0, 1]: 0 asks for the constraint to be met as closely as the
model can, 1 lets the model treat it as a loose hint.

Packed form (per effector, 6 data values, ProtoRes App. B): position ``(x, y, z, 0, 0, 0)``,
rotation ``6D`` (first two columns), look-at ``(target xyz, direction xyz)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_NAMES, NUM_JOINTS, EffectorType, joint_index
from smplik.validation import finite_array


def _finite_array(name: str, value: Any, shape: tuple[int, ...], joint: str) -> np.ndarray:
    return finite_array(value, shape, f"Effector on '{joint}': {name}")


@dataclass(frozen=True)
class Effector:
    """One constraint on one joint. Build with :meth:`position`, :meth:`rotation`, :meth:`look_at`
    or :meth:`from_dict`; the constructors validate their input and raise ``ValueError``."""

    joint: int
    type: EffectorType
    value: np.ndarray  # position (3,) | rotation (3, 3) | look-at target (3,)
    direction: np.ndarray | None = None  # look-at only: unit vector in the joint's frame
    tolerance: float = 0.0

    def __post_init__(self) -> None:
        name = JOINT_NAMES[self.joint] if 0 <= self.joint < NUM_JOINTS else str(self.joint)
        tol = float(self.tolerance)
        if not np.isfinite(tol) or not 0.0 <= tol <= 1.0:
            raise ValueError(f"Effector on '{name}': tolerance {self.tolerance} is outside [0, 1].")

    @property
    def joint_name(self) -> str:
        return JOINT_NAMES[self.joint]

    @classmethod
    def position(cls, joint: str | int, xyz: Any, tolerance: float = 0.0) -> Effector:
        j = joint_index(joint)
        return cls(j, EffectorType.POSITION, _finite_array("value", xyz, (3,), JOINT_NAMES[j]), None, tolerance)

    @classmethod
    def rotation(cls, joint: str | int, matrix: Any, tolerance: float = 0.0) -> Effector:
        j = joint_index(joint)
        R = _finite_array("value", matrix, (3, 3), JOINT_NAMES[j])
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
            raise ValueError(f"Effector on '{JOINT_NAMES[j]}': value is not a rotation matrix "
                             f"(needs R^T R = I and det R = +1; det = {np.linalg.det(R):.4f}).")
        u, _, vt = np.linalg.svd(R)  # project to the nearest exact rotation
        return cls(j, EffectorType.ROTATION, u @ vt, None, tolerance)

    @classmethod
    def look_at(cls, joint: str | int, target: Any, direction: Any = (0.0, 0.0, 1.0),
                tolerance: float = 0.0) -> Effector:
        j = joint_index(joint)
        t = _finite_array("target", target, (3,), JOINT_NAMES[j])
        d = _finite_array("direction", direction, (3,), JOINT_NAMES[j])
        n = np.linalg.norm(d)
        if n < 1e-8:
            raise ValueError(f"Effector on '{JOINT_NAMES[j]}': look-at direction is the zero vector.")
        return cls(j, EffectorType.LOOK_AT, t, d / n, tolerance)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Effector:
        """Parse the JSON form: ``{"joint", "type", "value" | ("target", "direction"), "tolerance"}``."""
        if not isinstance(data, Mapping):
            raise ValueError(f"An effector must be a JSON object, got {type(data).__name__}.")
        for key in ("joint", "type"):
            if key not in data:
                raise ValueError(f"Effector {dict(data)!r:.80} is missing key '{key}'.")
        kind = EffectorType.parse(data["type"])
        tol = data.get("tolerance", 0.0)
        try:
            tol = float(tol)
        except (TypeError, ValueError):
            raise ValueError(f"Effector on {data['joint']!r}: tolerance must be a number, got {tol!r}.") from None
        allowed = {"joint", "type", "tolerance"} | ({"target", "direction"} if kind == EffectorType.LOOK_AT
                                                   else {"value"})
        unknown = set(data) - allowed
        if unknown:
            raise ValueError(f"Effector on {data['joint']!r}: unknown key(s) {sorted(unknown)} for a "
                             f"{kind.name.lower()} effector; allowed: {sorted(allowed)}.")
        if kind == EffectorType.LOOK_AT:
            if "target" not in data:
                raise ValueError(f"Look-at effector on {data['joint']!r} is missing key 'target'.")
            return cls.look_at(data["joint"], data["target"], data.get("direction", (0.0, 0.0, 1.0)), tol)
        if "value" not in data:
            raise ValueError(f"Effector on {data['joint']!r} is missing key 'value'.")
        if kind == EffectorType.POSITION:
            return cls.position(data["joint"], data["value"], tol)
        return cls.rotation(data["joint"], data["value"], tol)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"joint": self.joint_name, "type": self.type.name.lower()}
        if self.type == EffectorType.LOOK_AT:
            out["target"] = self.value.tolist()
            out["direction"] = self.direction.tolist()  # type: ignore[union-attr]
        else:
            out["value"] = self.value.tolist()
        out["tolerance"] = float(self.tolerance)
        return out

    def data6(self) -> np.ndarray:
        """The 6 packed data values (see module docstring)."""
        if self.type == EffectorType.POSITION:
            return np.concatenate([self.value, np.zeros(3)])
        if self.type == EffectorType.ROTATION:
            return np.concatenate([self.value[:, 0], self.value[:, 1]])
        return np.concatenate([self.value, self.direction])  # type: ignore[arg-type]


@dataclass(frozen=True)
class EffectorBatch:
    """Packed effectors. joint (B, N) long, type (B, N) long, data (B, N, 6), tolerance (B, N),
    mask (B, N) bool (False = padding; every row needs at least one real effector)."""

    joint: Tensor
    type: Tensor
    data: Tensor
    tolerance: Tensor
    mask: Tensor

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.joint.shape)  # type: ignore[return-value]

    def to(self, device: torch.device | str) -> EffectorBatch:
        return EffectorBatch(*(getattr(self, f).to(device) for f in ("joint", "type", "data", "tolerance", "mask")))


def pack_effectors(effectors: Sequence[Effector] | Sequence[Sequence[Effector]],
                   dtype: torch.dtype = torch.float32) -> EffectorBatch:
    """Pack one list (-> batch of 1) or a batch of lists (padded to the longest, with a mask)."""
    if len(effectors) == 0:
        raise ValueError("At least one effector is needed.")
    batch = [effectors] if isinstance(effectors[0], Effector) else effectors
    N = max(len(row) for row in batch)
    if any(len(row) == 0 for row in batch):
        raise ValueError("Every pose in a batch needs at least one effector.")
    B = len(batch)
    joint = torch.zeros(B, N, dtype=torch.long)
    kind = torch.zeros(B, N, dtype=torch.long)
    data = np.zeros((B, N, 6))
    tol = torch.zeros(B, N, dtype=dtype)
    mask = torch.zeros(B, N, dtype=torch.bool)
    for b, row in enumerate(batch):
        for i, eff in enumerate(row):
            if not isinstance(eff, Effector):
                raise ValueError(f"Expected Effector objects, got {type(eff).__name__}.")
            joint[b, i], kind[b, i], tol[b, i], mask[b, i] = eff.joint, int(eff.type), eff.tolerance, True
            data[b, i] = eff.data6()
    return EffectorBatch(joint, kind, torch.as_tensor(data, dtype=dtype), tol, mask)
