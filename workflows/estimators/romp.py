"""ROMP / BEV (simple_romp) ``.npz`` results.

Layout: ``np.savez(path, results=dict)`` (the dict is stored as a pickled 0-d object array and is
read by the restricted unpickler), or the same keys at the top level of the ``.npz``:

* ``smpl_thetas`` (N, 72): axis-angle, root first, OpenCV camera frame.
* ``smpl_betas`` (N, 10), or (N, 11) for BEV, whose 11th component (SMPL+A age offset) is dropped.
* ``cam_trans`` (N, 3): camera-frame translation added to the SMPL output without ``transl``, i.e.
  smplx's ``transl`` (pass ``translation_kind="pelvis"`` for files produced with ``root_align``).

ROMP assumes a 60-degree field of view over the larger image side; no focal length is stored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from workflows.estimators.base import CameraInfo, EstimatedPerson, TranslationKind, make_people, require
from workflows.safe_pickle import load_npz

FORMAT = "romp"


def unwrap(data: dict[str, Any]) -> dict[str, Any]:
    """The ``results`` dict, or the top level when the keys are there."""
    inner = data.get("results", data) if isinstance(data, dict) else data
    return inner if isinstance(inner, dict) else data


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "smpl_thetas" in unwrap(data)


def from_data(data: dict[str, Any], *, source: str = "<romp>",
              translation_kind: TranslationKind = "transl") -> list[EstimatedPerson]:
    res = unwrap(data)
    thetas = np.asarray(require(res, "smpl_thetas", source), dtype=np.float64).reshape(-1, 72)
    betas = np.asarray(require(res, "smpl_betas", source), dtype=np.float64).reshape(thetas.shape[0], -1)
    trans = np.asarray(require(res, "cam_trans", source), dtype=np.float64).reshape(-1, 3)
    return make_people(thetas, trans, betas, frame_of_reference="camera", translation_kind=translation_kind,
                       camera=CameraInfo(default_fov_deg=60.0), source=f"{source} (romp)")


def read(path: str | Path, *, translation_kind: TranslationKind = "transl") -> list[EstimatedPerson]:
    return from_data(load_npz(path), source=str(path), translation_kind=translation_kind)
