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

Every error is an :class:`~smplik.effectors.EffectorError` (a ``ValueError``) naming the file and the
JSON path of the offending item, e.g. ``poses/wave.json: effectors[2].value: has shape (2,); expected (3,)``.
The reader is strict: unknown keys, a tolerance given as a string, booleans where numbers belong,
NaN/inf, positions or look-at targets beyond 1 km (:data:`smplik.validation.MAX_ABS_POSITION_M`),
|beta| > 20 and more than :data:`MAX_EFFECTORS` effectors are refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.atomic import write_json_atomic
from smplik.conventions import JOINT_NAMES, NUM_BETAS, EffectorType, Gender
from smplik.effectors import Effector, EffectorError, parse_effector_dict
from smplik.validation import JSONPathError, check_betas, read_json

EFFECTORS_FORMAT = "smplik-effectors"
EFFECTORS_VERSION = 1
_TOP_KEYS = ("format", "version", "betas", "gender", "effectors")
MAX_EFFECTORS = 64
"""Most effectors accepted in one file (the network was trained with at most 16)."""


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


def parse_effector_document(data: Any, source: str = "<effectors>") -> EffectorFile:
    """Validate and parse the JSON form (a dict, or a bare list of effectors).

    Raises:
        ValueError: naming ``source`` and the JSON path of the problem.
    """
    err = JSONPathError(source, EffectorError)
    if isinstance(data, list):
        data = {"effectors": data}
    if not isinstance(data, Mapping):
        raise err("", f"expected a JSON object with keys {', '.join(_TOP_KEYS)}, got {type(data).__name__}.")
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise err("", f"unknown key(s) {unknown}; valid keys: {', '.join(_TOP_KEYS)}.")
    if "format" in data and data["format"] != EFFECTORS_FORMAT:
        raise err("format", f"expected {EFFECTORS_FORMAT!r}, got {data['format']!r}.")
    if "version" in data:
        version = data["version"]
        if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= EFFECTORS_VERSION:
            raise err("version", f"unsupported version {version!r}; this smplik reads version "
                                       f"{EFFECTORS_VERSION}.")
    betas = None
    if data.get("betas") is not None:
        raw = data["betas"]
        if isinstance(raw, list) and len(raw) != NUM_BETAS:
            raise err("betas", f"has {len(raw)} values; expected exactly {NUM_BETAS}.")
        betas = check_betas(raw, where=f"{source}: betas", error=EffectorError)
    gender = None
    if data.get("gender") is not None:
        try:
            gender = Gender.parse(data["gender"]) if isinstance(data["gender"], str) else Gender.parse("?")
        except ValueError:
            valid = ", ".join(g.value for g in Gender)
            raise err("gender", f"unknown gender {data['gender']!r}; expected one of: {valid}.") from None
    if "effectors" not in data:
        raise err("", "missing key 'effectors'.")
    items = data["effectors"]
    if not isinstance(items, list):
        raise err("effectors", f"must be a list, got {type(items).__name__}.")
    if not items:
        raise err("effectors", "is empty; at least one effector is needed.")
    if len(items) > MAX_EFFECTORS:
        raise err("effectors", f"has {len(items)} effectors; at most {MAX_EFFECTORS} are accepted.")
    effectors = tuple(parse_effector_dict(item, f"effectors[{i}]", err) for i, item in enumerate(items))
    seen: dict[tuple[int, EffectorType], int] = {}
    for i, e in enumerate(effectors):
        key = (e.joint, e.type)
        if key in seen:
            raise err(f"effectors[{i}]", f"duplicate {e.type.name.lower()} effector on '{e.joint_name}' "
                                               f"(also effectors[{seen[key]}]).")
        seen[key] = i
    return EffectorFile(effectors, betas, gender)


def load_effector_file(path: str | Path) -> EffectorFile:
    """Read an effector file (see the module docstring). Raises :class:`EffectorError` naming the file."""
    return parse_effector_document(read_json(path, EffectorError, what="effector file"), source=str(path))


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
