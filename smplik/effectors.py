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

from smplik.conventions import JOINT_NAMES, NUM_JOINTS, EffectorType, joint_index, unknown_joint
from smplik.validation import MAX_ABS_POSITION_M, JSONPathError, finite_array, short_repr

_TYPE_NAMES = tuple(t.name.lower() for t in EffectorType)
EXACT = 1e-12
"""A rotation value with ``|R^T R - I| <= EXACT`` (a look-at direction with ``|norm - 1| <= EXACT``) is kept as
given: re-projecting an exact one changes its last bits, and a written effector must read back unchanged."""


class EffectorError(ValueError):
    """An effector is invalid; the message names the joint or the JSON path."""


def _finite_array(name: str, value: Any, shape: tuple[int, ...], joint: str,
                  max_abs: float | None = None) -> np.ndarray:
    return finite_array(value, shape, f"Effector on '{joint}': {name}", EffectorError, max_abs=max_abs)


@dataclass(frozen=True)
class Effector:
    """One constraint on one joint. Build with :meth:`position`, :meth:`rotation`, :meth:`look_at`
    or :meth:`from_dict`; the constructors validate their input and raise :class:`EffectorError`.

    Positions and look-at targets must lie within ``MAX_ABS_POSITION_M`` (1 km) per coordinate."""

    joint: int
    type: EffectorType
    value: np.ndarray  # position (3,) | rotation (3, 3) | look-at target (3,)
    direction: np.ndarray | None = None  # look-at only: unit vector in the joint's frame
    tolerance: float = 0.0

    def __post_init__(self) -> None:
        name = JOINT_NAMES[self.joint] if 0 <= self.joint < NUM_JOINTS else str(self.joint)
        if isinstance(self.tolerance, bool) or not isinstance(self.tolerance, (int, float, np.floating, np.integer)):
            raise EffectorError(f"Effector on '{name}': tolerance must be a number in [0, 1], "
                                f"got {self.tolerance!r:.40}.")
        tol = float(self.tolerance)
        if not np.isfinite(tol) or not 0.0 <= tol <= 1.0:
            raise EffectorError(f"Effector on '{name}': tolerance {self.tolerance} is outside [0, 1].")

    @property
    def joint_name(self) -> str:
        return JOINT_NAMES[self.joint]

    @classmethod
    def position(cls, joint: str | int, xyz: Any, tolerance: float = 0.0) -> Effector:
        j = _joint(joint)
        value = _finite_array("value", xyz, (3,), JOINT_NAMES[j], MAX_ABS_POSITION_M)
        return cls(j, EffectorType.POSITION, value, None, tolerance)

    @classmethod
    def rotation(cls, joint: str | int, matrix: Any, tolerance: float = 0.0) -> Effector:
        j = _joint(joint)
        R = _finite_array("value", matrix, (3, 3), JOINT_NAMES[j])
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
            raise EffectorError(f"Effector on '{JOINT_NAMES[j]}': value is not a rotation matrix "
                                f"(needs R^T R = I and det R = +1; det = {np.linalg.det(R):.4f}).")
        if np.abs(R.T @ R - np.eye(3)).max() > EXACT:  # project to the nearest exact rotation; an exact one is
            u, _, vt = np.linalg.svd(R)              # kept, so a written effector reads back bit for bit
            R = u @ vt
        return cls(j, EffectorType.ROTATION, R, None, tolerance)

    @classmethod
    def look_at(cls, joint: str | int, target: Any, direction: Any = (0.0, 0.0, 1.0),
                tolerance: float = 0.0) -> Effector:
        j = _joint(joint)
        t = _finite_array("target", target, (3,), JOINT_NAMES[j], MAX_ABS_POSITION_M)
        d = _finite_array("direction", direction, (3,), JOINT_NAMES[j])
        n = np.linalg.norm(d)
        if not n >= 1e-8 or not np.isfinite(n):
            raise EffectorError(f"Effector on '{JOINT_NAMES[j]}': look-at direction is the zero vector "
                                "(or not normalisable).")
        return cls(j, EffectorType.LOOK_AT, t, d if abs(n - 1.0) <= EXACT else d / n, tolerance)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], path: str = "") -> Effector:
        """Parse the JSON form: ``{"joint", "type", "value" | ("target", "direction"), "tolerance"}``.

        Errors are :class:`EffectorError` reading ``<path>: <problem>`` (see :func:`parse_effector_dict`)."""
        return parse_effector_dict(data, path)

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


def _joint(joint: Any) -> int:
    try:
        return joint_index(joint)
    except (ValueError, KeyError, TypeError, IndexError):
        message = unknown_joint(joint)
        raise EffectorError(message[0].upper() + message[1:]) from None


def parse_effector_dict(data: Any, path: str = "", error: JSONPathError | None = None) -> Effector:
    """The one parser of an effector's JSON form, shared by effector files, scenes and the solver API.

    Strict: unknown keys, a non-string joint or type, a tolerance that is not a number (``"0.5"``,
    ``true``), booleans among the numbers, NaN/inf, wrong shapes and out-of-range values are refused.

    Args:
        data: the dict ``{"joint", "type", "value" | ("target", "direction"), "tolerance"}``.
        path: the JSON path of ``data`` for messages (``effectors[2]``).
        error: builds the error (source file and error class); default :class:`EffectorError`.

    Raises:
        The error class of ``error`` (default :class:`EffectorError`): ``<source>: <path>.<key>: <problem>``.
    """
    err = error or JSONPathError("", EffectorError)

    def sub(key: str) -> str:
        return f"{path}.{key}" if path else key

    if not isinstance(data, Mapping):
        raise err(path, f"an effector must be a JSON object, got {type(data).__name__}.")
    for key in ("joint", "type"):
        if key not in data:
            raise err(path, f"missing key '{key}'.")
    joint = data["joint"]
    if not isinstance(joint, str) or joint not in JOINT_NAMES:
        raise err(sub("joint"), unknown_joint(joint))
    kind_text = data["type"]
    try:
        if not isinstance(kind_text, str):
            raise ValueError
        kind = EffectorType.parse(kind_text)
    except (ValueError, KeyError):
        raise err(sub("type"), f"must be one of {', '.join(_TYPE_NAMES)}, got {short_repr(kind_text)}.") from None
    allowed = {"joint", "type", "tolerance"} | ({"target", "direction"} if kind == EffectorType.LOOK_AT else {"value"})
    unknown = sorted(str(k) for k in set(data) - allowed)
    if unknown:
        raise err(path, f"unknown key(s) {unknown} for a {kind.name.lower()} effector; allowed: {sorted(allowed)}.")
    tol = data.get("tolerance", 0.0)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)):
        raise err(sub("tolerance"), f"must be a number in [0, 1], got {short_repr(tol)}.")
    if not np.isfinite(tol) or not 0.0 <= tol <= 1.0:
        raise err(sub("tolerance"), f"{tol} is outside [0, 1].")

    def numbers(key: str, value: Any, shape: tuple[int, ...], max_abs: float | None = None) -> np.ndarray:
        try:
            return finite_array(value, shape, "", EffectorError, max_abs=max_abs)
        except EffectorError as exc:
            raise err(sub(key), str(exc)[2:]) from None

    if kind == EffectorType.LOOK_AT:
        if "target" not in data:
            raise err(path, "missing key 'target' (look-at effectors need a target).")
        target = numbers("target", data["target"], (3,), MAX_ABS_POSITION_M)
        direction = numbers("direction", data.get("direction", [0.0, 0.0, 1.0]), (3,))
        if not np.linalg.norm(direction) >= 1e-8:
            raise err(sub("direction"), "look-at direction is the zero vector.")
        return Effector.look_at(joint, target, direction, float(tol))
    if "value" not in data:
        raise err(path, "missing key 'value'.")
    if kind == EffectorType.POSITION:
        return Effector.position(joint, numbers("value", data["value"], (3,), MAX_ABS_POSITION_M), float(tol))
    R = numbers("value", data["value"], (3, 3))
    try:
        return Effector.rotation(joint, R, float(tol))
    except EffectorError as exc:
        raise err(sub("value"), str(exc).split(": ", 1)[-1]) from None


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
    """The one effector packing: one list (-> batch of 1) or a batch of lists (padded to the longest,
    with a mask), building numpy arrays once (fast for the small inputs of one solve)."""
    joint, kind, data, tol, mask = pack_effector_arrays(effectors)
    return EffectorBatch(torch.from_numpy(joint), torch.from_numpy(kind), torch.from_numpy(data).to(dtype),
                         torch.from_numpy(tol).to(dtype), torch.from_numpy(mask))


def pack_effector_arrays(effectors: Sequence[Effector] | Sequence[Sequence[Effector]]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`pack_effectors` as numpy arrays: joint, type (B, N) int64, data (B, N, 6), tolerance (B, N)
    float64 and mask (B, N) bool."""
    if len(effectors) == 0:
        raise EffectorError("At least one effector is needed.")
    rows = [effectors] if isinstance(effectors[0], Effector) else effectors
    if any(len(row) == 0 for row in rows):
        raise EffectorError("Every pose in a batch needs at least one effector.")
    B, N = len(rows), max(len(r) for r in rows)
    joint = np.zeros((B, N), np.int64)
    kind = np.zeros((B, N), np.int64)
    data = np.zeros((B, N, 6), np.float64)
    tol = np.zeros((B, N), np.float64)
    mask = np.zeros((B, N), bool)
    for b, row in enumerate(rows):
        for i, e in enumerate(row):
            if not isinstance(e, Effector):
                raise EffectorError(f"Expected Effector objects, got {type(e).__name__}.")
            joint[b, i], kind[b, i], tol[b, i], mask[b, i] = e.joint, int(e.type), e.tolerance, True
            if e.type == EffectorType.POSITION:
                data[b, i, :3] = e.value
            elif e.type == EffectorType.ROTATION:
                data[b, i, :3], data[b, i, 3:] = e.value[:, 0], e.value[:, 1]
            else:
                data[b, i, :3], data[b, i, 3:] = e.value, e.direction
    return joint, kind, data, tol, mask
