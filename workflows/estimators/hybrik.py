"""HybrIK ``.pk`` results (a plain pickle, read by the restricted unpickler).

Layout (one row per person, or per frame of a video run):

* ``pred_thetas`` (N, 24, 3, 3) rotation matrices, or flattened (N, 216); OpenCV camera frame.
* ``pred_betas`` (N, 10).
* ``transl`` (N, 3): the camera-frame **pelvis** position (HybrIK's mesh is root-aligned before
  the translation is added).
* optional ``focal`` (scalar, pixels), ``width``/``height`` (image size).

Lists of per-frame arrays (the demo's ``res_db``) are stacked; ``frame`` picks one row.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import NUM_JOINTS
from workflows.estimators.base import (
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    make_people,
    require,
    rotations_to_axis_angle,
)
from workflows.safe_pickle import load_pickle

FORMAT = "hybrik"


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "pred_thetas" in data


def _stack(value: Any) -> np.ndarray:
    """An array, or a list of per-frame arrays flattened and concatenated (reshaped by the caller)."""
    if isinstance(value, (list, tuple)):
        return np.concatenate([np.asarray(v, dtype=np.float64).reshape(-1) for v in value])
    return np.asarray(value, dtype=np.float64)


def from_data(data: dict[str, Any], *, source: str = "<hybrik>", frame: int | None = None) -> list[EstimatedPerson]:
    thetas = _stack(require(data, "pred_thetas", source))
    if thetas.size % (NUM_JOINTS * 9) == 0 and (thetas.ndim == 1 or thetas.shape[-1] in (3, NUM_JOINTS * 9)):
        thetas = thetas.reshape(-1, NUM_JOINTS, 3, 3)
    if thetas.ndim != 4 or thetas.shape[1:] != (NUM_JOINTS, 3, 3):
        raise EstimateFormatError(f"{source}: 'pred_thetas' has shape {thetas.shape}; expected (N, 24, 3, 3) "
                                  "or (N, 216).")
    N = thetas.shape[0]
    betas = _stack(require(data, "pred_betas", source)).reshape(N, -1)
    transl = _stack(require(data, "transl", source)).reshape(N, 3)
    rows = np.arange(N) if frame is None else np.array([frame])
    if frame is not None and not 0 <= frame < N:
        raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{N - 1}).")
    size = None
    if "width" in data and "height" in data:
        w, h = np.ravel(data["width"])[0], np.ravel(data["height"])[0]
        size = (int(w), int(h))
    focal = float(np.ravel(data["focal"])[0]) if "focal" in data else None
    aa = rotations_to_axis_angle(thetas[rows])
    return make_people(aa, transl[rows], betas[rows], frame_of_reference="camera", translation_kind="pelvis",
                       camera=CameraInfo(focal, size), person_ids=[str(r) for r in rows],
                       source=f"{source} (hybrik)")


def read(path: str | Path, *, frame: int | None = None, trust_pickle: bool = False) -> list[EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
