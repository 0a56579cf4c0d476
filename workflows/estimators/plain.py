"""A plain ``.npz`` or JSON of SMPL parameters, one or several people.

Keys (smplx's names): ``global_orient`` (3) or (N, 3), ``body_pose`` (23, 3), (69,), (N, 23, 3) or
(N, 69), optional ``transl`` (N, 3) and ``betas`` (N, 10) (zeros when absent), optional ``gender``
(a string, or one per person) and optional ``frame``: ``"world"`` (default: smplik's y-up world,
used as is) or ``"camera"`` (OpenCV camera frame, converted like the estimators' outputs).
A JSON file may also be a list of such objects, one per person.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import NUM_BETAS, Gender
from workflows.estimators.base import CameraInfo, EstimatedPerson, EstimateFormatError, make_people, require
from workflows.safe_pickle import load_npz

FORMAT = "plain"


def matches(data: Any) -> bool:
    if isinstance(data, list):
        return bool(data) and all(matches(d) for d in data)
    return isinstance(data, dict) and "global_orient" in data and "body_pose" in data


def _one(data: dict[str, Any], source: str) -> list[EstimatedPerson]:
    go = np.asarray(require(data, "global_orient", source), dtype=np.float64).reshape(-1, 3)
    N = go.shape[0]
    bp = np.asarray(require(data, "body_pose", source), dtype=np.float64)
    if bp.size != N * 69:
        raise EstimateFormatError(f"{source}: 'body_pose' has shape {bp.shape}; expected ({N}, 23, 3) or ({N}, 69).")
    bp = bp.reshape(N, 23, 3)
    transl = np.asarray(data.get("transl", np.zeros((N, 3))), dtype=np.float64).reshape(N, 3)
    betas = np.asarray(data.get("betas", np.zeros((N, NUM_BETAS))), dtype=np.float64).reshape(N, -1)
    g = data.get("gender", "neutral")
    g = np.asarray(g).reshape(-1).tolist()
    genders = [Gender.parse(str(x)) for x in (g if len(g) == N else g[:1] * N)]
    frame = str(np.asarray(data.get("frame", "world")))
    if frame not in ("world", "camera"):
        raise EstimateFormatError(f"{source}: 'frame' must be 'world' or 'camera', got {frame!r}.")
    pose = np.concatenate([go[:, None], bp], axis=1)
    return make_people(pose, transl, betas, frame_of_reference=frame, translation_kind="transl", genders=genders,
                       camera=CameraInfo(), source=f"{source} (plain)")


def from_data(data: Any, *, source: str = "<plain>") -> list[EstimatedPerson]:
    if isinstance(data, list):
        return [p for i, d in enumerate(data) for p in _one(d, f"{source}[{i}]")]
    return _one(data, source)


def read(path: str | Path) -> list[EstimatedPerson]:
    path = Path(path)
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise EstimateFormatError(f"{path}: cannot read JSON ({exc}).") from exc
    else:
        data = load_npz(path)
    return from_data(data, source=str(path))
