"""HybrIK ``.pk`` results (a plain pickle, read by the restricted unpickler).

Written by HybrIK's demos (github.com/Jeff-sjtu/HybrIK): ``scripts/demo_video.py`` collects one
entry per video frame in ``res_db`` (``res_db['pred_thetas'].append(...)`` etc.) and writes it with
``pk.dump(res_db, fid)`` to ``res.pk``; ``scripts/demo_image.py`` writes the same keys for one image.
HybrIK tracks one person, so row ``N`` is video frame ``N`` and the person id is ``"0"``.

Each key is ``np.stack``-ed over the frames before ``pk.dump``:

* ``pred_thetas`` (T, 216) rotation matrices (``pred_theta_mats``; (T, 24, 3, 3) and quaternion
  (T, 96) layouts, scalar first, are read too), OpenCV camera frame.
* ``pred_betas`` (T, 10).
* ``transl`` (T, 3): the camera-frame **pelvis** position: HybrIK's SMPL layer returns vertices
  root-aligned at the pelvis (``vertices - joints_from_verts[:, root]``) and the demo renders
  ``render_mesh(vertices, translation=transl, focal_length=focal)``.
* ``bbox`` (T, 4) xyxy: the demo's focal length is ``focal = 1000 / 256 * (x2 - x1)``, principal
  point the image centre; ``height``/``width`` (T,) image size. A ``focal`` / ``f`` key, when
  present, wins over the bbox rule.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import NUM_JOINTS
from smplik.safe_pickle import load_pickle
from workflows.estimators import base

FORMAT = "hybrik"


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "pred_thetas" in data


def _stack(value: Any, name: str, source: str) -> np.ndarray:
    """An array, or a list of per-frame arrays, as (T, -1) finite rows."""
    if isinstance(value, (list, tuple)):
        if not value:
            raise base.EstimateFormatError(f"{source}: '{name}' is empty.")
        parts = [base.finite(v, name, source).reshape(1, -1) for v in value]
        if len({p.shape[1] for p in parts}) != 1:
            raise base.EstimateFormatError(f"{source}: '{name}' entries have different sizes.")
        return np.concatenate(parts)
    arr = base.finite(value, name, source)
    return arr.reshape(arr.shape[0], -1) if arr.ndim >= 2 else arr.reshape(1, -1)


def from_data(data: dict[str, Any], *, source: str = "<hybrik>", frame: int = 0,
              max_people: int = base.MAX_PEOPLE) -> list[base.EstimatedPerson]:
    thetas = base.rows(_stack(base.require(data, "pred_thetas", source), "pred_thetas", source), "pred_thetas",
                       (NUM_JOINTS * 9, NUM_JOINTS * 4), source)
    T = thetas.shape[0]
    betas = base.rows(_stack(base.require(data, "pred_betas", source), "pred_betas", source), "pred_betas", (10, 11),
                      source, T)
    transl = base.rows(_stack(base.require(data, "transl", source), "transl", source), "transl", 3, source, T)
    if not 0 <= frame < T:
        raise base.EstimateFormatError(f"{source}: frame {frame} out of range (0..{T - 1}).")
    size = None
    if "width" in data and "height" in data:
        w, h = (_stack(data[k], k, source).reshape(-1) for k in ("width", "height"))
        size = base.image_size_from(w[min(frame, w.size - 1)], h[min(frame, h.size - 1)], source)
    focal = None
    for key in ("focal", "f"):
        if key in data:
            values = _stack(data[key], key, source).reshape(-1)
            focal = float(values[min(frame, values.size - 1)])
            break
    if focal is None and "bbox" in data:
        bbox = base.rows(_stack(data["bbox"], "bbox", source), "bbox", 4, source)
        focal = 1000.0 / 256.0 * float(bbox[min(frame, bbox.shape[0] - 1), 2] - bbox[min(frame, bbox.shape[0] - 1), 0])
    if focal is not None and not focal > 0:
        raise base.EstimateFormatError(f"{source}: HybrIK focal length {focal} must be positive.")
    row = thetas[frame]
    if row.shape[0] == NUM_JOINTS * 4:
        import torch

        from smplik.rotations import quaternion_to_matrix

        R = quaternion_to_matrix(torch.as_tensor(row.reshape(NUM_JOINTS, 4))).numpy()
    else:
        R = row.reshape(NUM_JOINTS, 3, 3)
    aa = base.rotations_to_axis_angle(R[None], "pred_thetas", source)
    return base.make_people(aa, transl[frame:frame + 1], betas[frame:frame + 1], frame_of_reference="camera",
                            translation_kind="pelvis", camera=base.CameraInfo(focal, size), person_ids=["0"],
                            frames=[str(frame)], source=f"{source} (hybrik)", max_people=max_people)


def read(path: str | Path, *, frame: int = 0, trust_pickle: bool = False) -> list[base.EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
