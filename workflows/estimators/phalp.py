"""4D-Humans / PHALP joblib ``.pkl`` tracking results.

Layout (PHALP's ``results`` dict, checked against public readers of these files): one entry per
frame, keyed by the frame's name, each a dict of per-detection lists:

* ``smpl``: list of dicts with ``global_orient`` (1, 3, 3), ``body_pose`` (23, 3, 3) rotation
  matrices (OpenCV camera frame) and ``betas`` (10,).
* ``camera``: list of (3,) camera translations of the full image, added to the SMPL output without
  ``transl`` (smplx ``transl``).
* ``tid``: track ids; ``size``: list of ``[width, height]``; ``time``: frame number.

4D-Humans renders with a focal length of 5000 px for a 256 px crop, scaled to the image's larger
side: ``focal = 5000 / 256 * max(width, height)``.
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

FORMAT = "phalp"
FOCAL_PER_PIXEL = 5000.0 / 256.0


def matches(data: Any) -> bool:
    if not isinstance(data, dict) or not data:
        return False
    first = next(iter(data.values()))
    return isinstance(first, dict) and "smpl" in first and "camera" in first


def from_data(data: dict[str, Any], *, source: str = "<phalp>",
              frame: int | str | None = None) -> list[EstimatedPerson]:
    if not isinstance(data, dict) or not data:
        raise EstimateFormatError(f"{source}: expected a dict of frames.")
    names = sorted(data, key=str)
    if frame is None:
        key = next((n for n in names if isinstance(data[n], dict) and len(data[n].get("smpl", []))), names[0])
    elif isinstance(frame, int) and frame not in data:
        if not 0 <= frame < len(names):
            raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{len(names) - 1}).")
        key = names[frame]
    else:
        if frame not in data:
            raise EstimateFormatError(f"{source}: no frame {frame!r} (first frames: {', '.join(map(str, names[:5]))}).")
        key = frame
    entry = data[key]
    where = f"{source}[{key!r}]"
    smpl = list(require(entry, "smpl", where))
    cams = list(require(entry, "camera", where))
    if len(smpl) != len(cams):
        raise EstimateFormatError(f"{where}: {len(smpl)} 'smpl' entries but {len(cams)} 'camera' entries.")
    R = np.zeros((len(smpl), NUM_JOINTS, 3, 3))
    betas = np.zeros((len(smpl), 10))
    for i, s in enumerate(smpl):
        R[i, 0] = np.asarray(require(s, "global_orient", f"{where}.smpl[{i}]"), dtype=np.float64).reshape(3, 3)
        R[i, 1:] = np.asarray(require(s, "body_pose", f"{where}.smpl[{i}]"), dtype=np.float64).reshape(23, 3, 3)
        betas[i] = np.asarray(require(s, "betas", f"{where}.smpl[{i}]"), dtype=np.float64).reshape(-1)[:10]
    camera = np.asarray(cams, dtype=np.float64).reshape(-1, 3)
    sizes = entry.get("size")
    size = (int(sizes[0][0]), int(sizes[0][1])) if sizes is not None and len(sizes) else None
    focal = FOCAL_PER_PIXEL * max(size) if size else None
    tids = [str(t) for t in entry.get("tid", range(len(smpl)))]
    return make_people(rotations_to_axis_angle(R), camera, betas, frame_of_reference="camera",
                       translation_kind="transl", camera=CameraInfo(focal, size), person_ids=tids,
                       frames=[str(key)] * len(smpl), source=f"{source} (phalp)")


def read(path: str | Path, *, frame: int | str | None = None, trust_pickle: bool = False) -> list[EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
