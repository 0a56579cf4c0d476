"""VIBE and PARE joblib ``.pkl`` results: ``{person_id: {...}}`` with a weak-perspective full-image camera.

Written by VIBE (github.com/mkocabas/VIBE, ``demo.py``: ``vibe_results[person_id] = output_dict``,
``joblib.dump(vibe_results, 'vibe_output.pkl')``) and PARE (github.com/mkocabas/PARE,
``pare/core/tester.py`` ``run_on_video``: ``pare_results[person_id] = output_dict``, the same keys plus
``smpl_joints2d``). Per person over its N frames:

* ``pose``: (N, 72) axis-angle (VIBE), or (N, 24, 3, 3) rotation matrices (PARE's ``pred_pose``), in
  the SPIN camera convention (OpenCV axes: the body is upside down at zero rotation);
* ``betas`` (N, 10); ``frame_ids`` (N,) video frames; ``orig_cam`` (N, 4) ``[sx, sy, tx, ty]`` from
  ``convert_crop_cam_to_orig_img`` (``lib/utils/demo_utils.py``): the producer's renderer
  (``lib/utils/renderer.py``, ``WeakPerspectiveCamera``) draws SMPL's output vertices (no ``transl``)
  at ``u = W/2 (1 + sx (x + tx))``, ``v = H/2 (1 + sy (y + ty))`` in a ``W x H`` image.

The image size is not stored. A pinhole camera of focal ``f`` at the image centre draws a body at
depth ``tz`` with ``f / tz`` pixels per metre; matching the weak-perspective scale ``W sx / 2 = H sy / 2``
with smplik's 60-degree field of view over the larger side (``f = max(W, H) / 2 / tan 30°``) gives
``tz = 1 / (min(sx, sy) tan 30°)`` whatever the image size, so the camera-frame ``transl`` is
``(tx, ty, tz)`` (smplx's, the SMPL origin). The body's own depth variation is what weak perspective
ignores. ``--frame N`` keeps the rows whose ``frame_ids`` equal N.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from workflows.estimators import base
from workflows.estimators.base import EstimatedPerson, EstimateFormatError

FORMAT = "vibe"
FOV_DEG = 60.0
"""The field of view (over the larger image side) assumed for the pinhole camera; CameraInfo's default."""


def _is_person(d: Any) -> bool:
    return isinstance(d, dict) and "pose" in d and "orig_cam" in d


def matches(data: Any) -> bool:
    return isinstance(data, dict) and bool(data) and all(_is_person(v) for v in data.values())


def orig_cam_to_transl(orig_cam: np.ndarray, fov_deg: float = FOV_DEG) -> np.ndarray:
    """VIBE's full-image weak-perspective camera (N, 4) ``[sx, sy, tx, ty]`` -> camera-frame transl (N, 3)."""
    sx, sy, tx, ty = orig_cam.T
    scale = np.minimum(sx, sy)
    if not (scale > 0).all():
        raise EstimateFormatError(f"'orig_cam' scales must be positive, got {float(scale.min())}.")
    return np.stack([tx, ty, 1.0 / (scale * math.tan(math.radians(fov_deg) / 2))], 1)


def _pose(value: Any, where: str) -> np.ndarray:
    arr = base.finite(value, "pose", where)
    if arr.ndim == 4 and arr.shape[1:] == (24, 3, 3):  # PARE: rotation matrices
        return base.rotations_to_axis_angle(arr, "pose", where).reshape(-1, 72)
    return base.rows(arr, "pose", 72, where)


def from_data(data: dict[Any, Any], *, source: str = "<vibe>", frame: int = 0,
              max_people: int = base.MAX_PEOPLE) -> list[EstimatedPerson]:
    if not matches(data):
        raise EstimateFormatError(f"{source}: expected {{person_id: {{'pose', 'betas', 'orig_cam', 'frame_ids'}}}}.")
    base.check_people_count(len(data), max_people, source)
    poses, transl, betas, ids = [], [], [], []
    for pid, d in data.items():
        where = f"{source}[{pid!r}]"
        frames = base.frame_numbers(base.require(d, "frame_ids", where), "frame_ids", where)
        keep = np.nonzero(frames == frame)[0]
        if keep.size == 0:
            continue
        pose = _pose(base.require(d, "pose", where), where)
        N = pose.shape[0]
        if frames.shape[0] != N:
            raise EstimateFormatError(f"{where}: 'frame_ids' has {frames.shape[0]} entries for {N} poses.")
        cam = base.rows(base.require(d, "orig_cam", where), "orig_cam", 4, where, N)
        b = base.rows(base.require(d, "betas", where), "betas", tuple(range(1, 301)), where, N)
        poses.append(pose[keep])
        transl.append(orig_cam_to_transl(cam[keep]))
        betas.append(b[keep, :10] if b.shape[1] >= 10 else np.pad(b[keep], ((0, 0), (0, 10 - b.shape[1]))))
        ids += [str(pid)] * keep.size
    if not ids:
        raise EstimateFormatError(f"{source}: no person in frame {frame}.")
    return base.make_people(np.concatenate(poses), np.concatenate(transl), np.concatenate(betas),
                       frame_of_reference="camera", translation_kind="transl",
                       camera=base.CameraInfo(default_fov_deg=FOV_DEG),
                       person_ids=ids, frames=[str(frame)] * len(ids), source=f"{source} (vibe)",
                       max_people=max_people)
