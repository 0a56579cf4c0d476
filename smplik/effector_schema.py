"""Effector files: a versioned JSON format for effectors plus the body they apply to.

Format ``smplik-effectors``, version :data:`EFFECTORS_VERSION` (the JSON Schema is
:func:`json_schema`, also shipped as ``docs/effectors.schema.json``)::

    {
      "format": "smplik-effectors",        # optional on input, always written
      "version": 1,                        # optional on input, always written
      "betas": [0, 0, 0, 0, 0, 0, 0, 0, 0, 0],   # optional, exactly 10 numbers
      "gender": "female",                  # optional: neutral | male | female
      "effectors": [
        {"joint": "left_wrist", "type": "position", "value": [0.4, 1.1, 0.2], "tolerance": 0.0},
        {"joint": "pelvis", "type": "rotation", "value": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        {"joint": "head", "type": "look_at", "target": [0, 1.6, 2.0], "direction": [0, 0, 1]}
      ]
    }

Units are metres in SMPL's y-up world. ``value`` of a rotation effector is the joint's global
rotation ``R_world_joint`` given as 3 rows; ``direction`` of a look-at effector is a unit vector in
the joint's own frame (default ``[0, 0, 1]``, the body's forward axis at rest); ``tolerance`` is in
[0, 1] (default 0: meet the constraint as closely as possible). A bare JSON list is read as the
``effectors`` list alone.

Every error is a ``ValueError`` naming the file and the JSON path of the offending item, e.g.
``poses/wave.json: effectors[2].value: has shape (2,); expected (3,)``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.atomic import write_json_atomic
from smplik.conventions import JOINT_NAMES, NUM_BETAS, EffectorType, Gender
from smplik.effectors import Effector

EFFECTORS_FORMAT = "smplik-effectors"
EFFECTORS_VERSION = 1
_TOP_KEYS = ("format", "version", "betas", "gender", "effectors")
_TYPE_NAMES = tuple(t.name.lower() for t in EffectorType)


@dataclass(frozen=True)
class EffectorFile:
    """The content of an effector file.

    Attributes:
        effectors: the constraints (at least one).
        betas: (10,) float64 body shape, or None when the file gives none.
        gender: the body gender, or None when the file gives none.
    """

    effectors: tuple[Effector, ...]
    betas: np.ndarray | None = None
    gender: Gender | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (format and version first)."""
        out: dict[str, Any] = {"format": EFFECTORS_FORMAT, "version": EFFECTORS_VERSION}
        if self.betas is not None:
            out["betas"] = [float(b) for b in self.betas]
        if self.gender is not None:
            out["gender"] = self.gender.value
        out["effectors"] = [e.to_dict() for e in self.effectors]
        return out


class _Path:
    """Builds ``source: json.path: message`` errors."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, path: str, message: str) -> ValueError:
        return ValueError(f"{self.source}: {path}: {message}" if path else f"{self.source}: {message}")


def _numbers(err: _Path, path: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    if isinstance(value, (str, bytes, Mapping)) or value is None or isinstance(value, bool):
        raise err.error(path, f"must be {_shape_words(shape)}, got {json.dumps(value)[:60]}.")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise err.error(path, f"must be {_shape_words(shape)}, got {json.dumps(value, default=str)[:60]}.") from None
    if arr.shape != shape:
        raise err.error(path, f"has shape {arr.shape}; expected {shape}.")
    if not np.isfinite(arr).all():
        raise err.error(path, "contains NaN or inf.")
    return arr


def _shape_words(shape: tuple[int, ...]) -> str:
    return f"a list of {shape[0]} numbers" if len(shape) == 1 else f"{shape[0]} rows of {shape[1]} numbers"


def _parse_effector(err: _Path, path: str, data: Any) -> Effector:
    if not isinstance(data, Mapping):
        raise err.error(path, f"an effector must be a JSON object, got {type(data).__name__}.")
    for key in ("joint", "type"):
        if key not in data:
            raise err.error(path, f"missing key '{key}'.")
    joint = data["joint"]
    if not isinstance(joint, str) or joint not in JOINT_NAMES:
        raise err.error(f"{path}.joint", f"unknown joint {joint!r}; valid names: {', '.join(JOINT_NAMES)}.")
    kind_text = data["type"]
    if not isinstance(kind_text, str):
        raise err.error(f"{path}.type", f"must be one of {', '.join(_TYPE_NAMES)}, got {kind_text!r}.")
    try:
        kind = EffectorType.parse(kind_text)
    except ValueError as exc:
        raise err.error(f"{path}.type", str(exc)) from None
    allowed = {"joint", "type", "tolerance"} | ({"target", "direction"} if kind == EffectorType.LOOK_AT else {"value"})
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise err.error(path, f"unknown key(s) {unknown} for a {kind.name.lower()} effector; "
                              f"allowed: {sorted(allowed)}.")
    tol = data.get("tolerance", 0.0)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)):
        raise err.error(f"{path}.tolerance", f"must be a number in [0, 1], got {json.dumps(tol, default=str)}.")
    if not np.isfinite(tol) or not 0.0 <= tol <= 1.0:
        raise err.error(f"{path}.tolerance", f"{tol} is outside [0, 1].")
    if kind == EffectorType.LOOK_AT:
        if "target" not in data:
            raise err.error(path, "missing key 'target' (look-at effectors need a target).")
        target = _numbers(err, f"{path}.target", data["target"], (3,))
        direction = _numbers(err, f"{path}.direction", data.get("direction", (0.0, 0.0, 1.0)), (3,))
        if np.linalg.norm(direction) < 1e-8:
            raise err.error(f"{path}.direction", "look-at direction is the zero vector.")
        return Effector.look_at(joint, target, direction, float(tol))
    if "value" not in data:
        raise err.error(path, "missing key 'value'.")
    if kind == EffectorType.POSITION:
        return Effector.position(joint, _numbers(err, f"{path}.value", data["value"], (3,)), float(tol))
    R = _numbers(err, f"{path}.value", data["value"], (3, 3))
    try:
        return Effector.rotation(joint, R, float(tol))
    except ValueError as exc:
        raise err.error(f"{path}.value", str(exc).split(": ", 1)[-1]) from None


def parse_effector_document(data: Any, source: str = "<effectors>") -> EffectorFile:
    """Validate and parse the JSON form (a dict, or a bare list of effectors).

    Raises:
        ValueError: naming ``source`` and the JSON path of the problem.
    """
    err = _Path(source)
    if isinstance(data, list):
        data = {"effectors": data}
    if not isinstance(data, Mapping):
        raise err.error("", f"expected a JSON object with keys {', '.join(_TOP_KEYS)}, got {type(data).__name__}.")
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise err.error("", f"unknown key(s) {unknown}; valid keys: {', '.join(_TOP_KEYS)}.")
    if "format" in data and data["format"] != EFFECTORS_FORMAT:
        raise err.error("format", f"expected {EFFECTORS_FORMAT!r}, got {data['format']!r}.")
    if "version" in data:
        version = data["version"]
        if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= EFFECTORS_VERSION:
            raise err.error("version", f"unsupported version {version!r}; this smplik reads version "
                                       f"{EFFECTORS_VERSION}.")
    betas = None
    if data.get("betas") is not None:
        raw = data["betas"]
        if isinstance(raw, list) and len(raw) != NUM_BETAS:
            raise err.error("betas", f"has {len(raw)} values; expected exactly {NUM_BETAS}.")
        betas = _numbers(err, "betas", raw, (NUM_BETAS,))
    gender = None
    if data.get("gender") is not None:
        try:
            gender = Gender.parse(data["gender"]) if isinstance(data["gender"], str) else Gender.parse("?")
        except ValueError:
            valid = ", ".join(g.value for g in Gender)
            raise err.error("gender", f"unknown gender {data['gender']!r}; expected one of: {valid}.") from None
    if "effectors" not in data:
        raise err.error("", "missing key 'effectors'.")
    items = data["effectors"]
    if not isinstance(items, list):
        raise err.error("effectors", f"must be a list, got {type(items).__name__}.")
    if not items:
        raise err.error("effectors", "is empty; at least one effector is needed.")
    effectors = tuple(_parse_effector(err, f"effectors[{i}]", item) for i, item in enumerate(items))
    seen: dict[tuple[int, EffectorType], int] = {}
    for i, e in enumerate(effectors):
        key = (e.joint, e.type)
        if key in seen:
            raise err.error(f"effectors[{i}]", f"duplicate {e.type.name.lower()} effector on '{e.joint_name}' "
                                               f"(also effectors[{seen[key]}]).")
        seen[key] = i
    return EffectorFile(effectors, betas, gender)


def load_effector_file(path: str | Path) -> EffectorFile:
    """Read an effector file (see the module docstring). Raises ``ValueError`` naming the file."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ValueError(f"Effector file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read effector file ({exc}).") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON ({exc}).") from None
    return parse_effector_document(data, source=str(path))


def save_effector_file(path: str | Path, effectors: Sequence[Effector], *, betas: Any = None,
                       gender: Gender | str | None = None) -> Path:
    """Write effectors (and optionally the body) in the current format version, atomically."""
    doc = EffectorFile(tuple(effectors), None if betas is None else np.asarray(betas, dtype=np.float64),
                       None if gender is None else Gender.parse(gender))
    parse_effector_document(doc.to_dict(), source=str(path))  # never write a file we could not read back
    return write_json_atomic(path, doc.to_dict())


def json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of the effector file format (``docs/effectors.schema.json``)."""
    vec3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
    tolerance = {"type": "number", "minimum": 0, "maximum": 1, "default": 0,
                 "description": "0: meet the constraint as closely as possible; 1: a loose hint."}
    joint = {"enum": list(JOINT_NAMES), "description": "SMPL joint name."}

    def effector(kind: str, props: dict[str, Any], required: list[str], doc: str) -> dict[str, Any]:
        return {"type": "object", "description": doc, "additionalProperties": False,
                "required": ["joint", "type", *required],
                "properties": {"joint": joint, "type": {"const": kind}, **props, "tolerance": tolerance}}

    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://github.com/smplik/smplik/docs/effectors.schema.json",
        "title": "smplik effector file",
        "description": "Effectors (IK constraints) for one SMPL body, metres, y-up world. Version "
                       f"{EFFECTORS_VERSION}.",
        "type": "object",
        "additionalProperties": False,
        "required": ["effectors"],
        "properties": {
            "format": {"const": EFFECTORS_FORMAT},
            "version": {"const": EFFECTORS_VERSION},
            "betas": {"type": "array", "items": {"type": "number"}, "minItems": NUM_BETAS, "maxItems": NUM_BETAS,
                      "description": "SMPL shape coefficients (default: zeros)."},
            "gender": {"enum": [g.value for g in Gender], "description": "Body model (default: neutral)."},
            "effectors": {"type": "array", "minItems": 1, "items": {"oneOf": [
                effector("position", {"value": {**vec3, "description": "World position of the joint (m)."}},
                         ["value"], "The joint's world position."),
                effector("rotation", {"value": {"type": "array", "items": vec3, "minItems": 3, "maxItems": 3,
                                                "description": "Global rotation R_world_joint, 3 rows."}},
                         ["value"], "The joint's global rotation."),
                effector("look_at", {"target": {**vec3, "description": "World point to look at (m)."},
                                     "direction": {**vec3, "default": [0, 0, 1],
                                                   "description": "Non-zero axis in the joint's frame."}},
                         ["target"], "Point the joint's local direction at a world target."),
            ]}},
        },
    }
