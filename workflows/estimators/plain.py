"""A plain ``.npz``, ``.pt`` or JSON of SMPL (or SMPL-X/SMPL-H body) parameters, one or several people.

Keys (smplx's names): ``global_orient`` (3) or (N, 3); ``body_pose`` (23, 3), (69,), (N, 23, 3) or
(N, 69) for SMPL, or (N, 63) / (N, 21, 3) for the 21 body joints of SMPL-X/SMPL-H (SMPL's hand
joints then get zero rotation; the rest pelvis is SMPL-X's unless ``model_type`` says ``"smplh"``
or ``"smpl"``); optional ``transl`` (N, 3) and ``betas`` (N, >=1) (zeros when absent; smplx
``transl``); optional ``gender`` (a string, or one per person); optional ``model_type``
(``"smpl"``, ``"smplh"``, ``"smplx"``); optional ``frame``: ``"world"`` (default: smplik's y-up
world, used as is) or ``"camera"`` (OpenCV camera frame, converted like the estimators' outputs).

Camera intrinsics (camera frame only): ``K`` (3, 3), or ``focal_length`` (pixels; one number or
``[fx, fy]``) with ``image_size`` ``[width, height]`` (or ``width``/``height``), optional
``principal_point`` ``[cx, cy]``. Without them, a 60-degree field of view is assumed.

A JSON file may also be a list of such objects, one per person. The file is one frame: ``--frame``
must be 0.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from smplik.conventions import NUM_BETAS, Gender
from workflows.estimators.base import (
    MAX_PEOPLE,
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    finite,
    image_size_from,
    make_people,
    require,
    rows,
)

FORMAT = "plain"


def matches(data: Any) -> bool:
    if isinstance(data, list):
        return bool(data) and all(matches(d) for d in data)
    return isinstance(data, dict) and "global_orient" in data and "body_pose" in data


def _text(value: Any, name: str, source: str) -> str:
    arr = np.asarray(value)
    if arr.dtype.kind not in "UST" or arr.size != 1:
        if isinstance(value, str):
            return value
        raise EstimateFormatError(f"{source}: '{name}' must be a string.")
    item = arr.reshape(-1)[0]
    return item.decode() if isinstance(item, bytes) else str(item)


def _camera(data: dict[str, Any], source: str) -> CameraInfo:
    size = None
    if "image_size" in data:
        s = finite(data["image_size"], "image_size", source).reshape(-1)
        if s.size != 2:
            raise EstimateFormatError(f"{source}: 'image_size' must be [width, height].")
        size = image_size_from(s[0], s[1], source)
    elif "width" in data and "height" in data:
        size = image_size_from(data["width"], data["height"], source)
    if "K" in data:
        return CameraInfo.from_K(data["K"], size, source)
    if "focal_length" in data:
        f = finite(data["focal_length"], "focal_length", source).reshape(-1)
        if f.size not in (1, 2) or not (f > 0).all():
            raise EstimateFormatError(f"{source}: 'focal_length' must be one or two positive numbers.")
        if size is None:
            raise EstimateFormatError(f"{source}: 'focal_length' needs 'image_size' [width, height] (or "
                                      "'width'/'height') to place the principal point.")
        pp = None
        if "principal_point" in data:
            p = finite(data["principal_point"], "principal_point", source).reshape(-1)
            if p.size != 2:
                raise EstimateFormatError(f"{source}: 'principal_point' must be [cx, cy].")
            pp = (float(p[0]), float(p[1]))
        return CameraInfo(float(f.mean()), size, principal_px=pp)
    return CameraInfo(None, size)


def _one(data: dict[str, Any], source: str, max_people: int) -> list[EstimatedPerson]:
    go = rows(require(data, "global_orient", source), "global_orient", 3, source)
    N = go.shape[0]
    bp = finite(require(data, "body_pose", source), "body_pose", source)
    if bp.size == N * 69:
        bp, family = bp.reshape(N, 23, 3), "smpl"
    elif bp.size == N * 63:
        bp = np.concatenate([bp.reshape(N, 21, 3), np.zeros((N, 2, 3))], axis=1)
        family = "smplx"
    else:
        raise EstimateFormatError(f"{source}: 'body_pose' has shape {bp.shape}; expected ({N}, 23, 3), ({N}, 69) "
                                  f"or, for SMPL-X/SMPL-H, ({N}, 63).")
    if "model_type" in data:
        model = _text(data["model_type"], "model_type", source).lower()
        if model not in ("smpl", "smplh", "smplx"):
            raise EstimateFormatError(f"{source}: 'model_type' must be smpl, smplh or smplx, got {model!r}.")
        family = "smplx" if model == "smplx" else "smpl"
    transl = rows(data.get("transl", np.zeros((N, 3))), "transl", 3, source, N)
    betas = finite(data.get("betas", np.zeros((N, NUM_BETAS))), "betas", source)
    betas = betas.reshape(N, -1) if betas.size and betas.size % N == 0 else betas.reshape(1, -1).repeat(N, 0)
    g = data.get("gender", "neutral")
    g_list = [g] if isinstance(g, str) else np.asarray(g).reshape(-1).tolist()
    if len(g_list) not in (1, N):
        raise EstimateFormatError(f"{source}: 'gender' has {len(g_list)} entries for {N} people.")
    try:
        genders = [Gender.parse(x.decode() if isinstance(x, bytes) else str(x)) for x in
                   (g_list if len(g_list) == N else g_list[:1] * N)]
    except ValueError as exc:
        raise EstimateFormatError(f"{source}: 'gender': {exc}") from None
    frame = _text(data.get("frame", "world"), "frame", source)
    if frame not in ("world", "camera"):
        raise EstimateFormatError(f"{source}: 'frame' must be 'world' or 'camera', got {frame!r}.")
    pose = np.concatenate([go[:, None], bp], axis=1)
    return make_people(pose, transl, betas, frame_of_reference=frame, translation_kind="transl",  # type: ignore[arg-type]
                       body_family=family, genders=genders, camera=_camera(data, source),  # type: ignore[arg-type]
                       source=f"{source} (plain)", max_people=max_people)


def from_data(data: Any, *, source: str = "<plain>", frame: int = 0, max_people: int = MAX_PEOPLE
              ) -> list[EstimatedPerson]:
    if frame != 0:
        raise EstimateFormatError(f"{source}: a plain SMPL file is one frame; --frame must be 0, got {frame}.")
    if isinstance(data, list):
        if len(data) > max_people:
            raise EstimateFormatError(f"{source}: {len(data)} people exceeds the cap of {max_people}; pass "
                                      f"--max-people {len(data)} (max_people={len(data)}) if the file is right.")
        people = [p for i, d in enumerate(data) for p in _one(d, f"{source}[{i}]", max_people)]
        return [dataclasses.replace(p, person_id=str(i)) for i, p in enumerate(people)]
    return _one(data, source, max_people)
