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

A JSON file may also be a list of such objects, one per person. Such a file is one frame: ``--frame``
must be 0.

**A sequence**: N > 1 poses with ONE shape (``betas`` of one row, (1, K) or (K,)) are one person over N
frames, not N people (:func:`sequence_length`): what a video's SMPL fit saves, e.g. a ROMP run refined by
InstantAvatar (``global_orient (T, 3)``, ``body_pose (T, 69)``, ``transl (T, 3)``, ``betas (1, 10)``).
``--frame N`` is row N (0..T-1), the person id is ``"0"`` in every frame (one track for ``scene animate``),
and the reader says so once (:class:`~workflows.estimators.pose_array.EstimateNote`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from smplik.conventions import NUM_BETAS, Gender
from workflows.estimators import base

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
        raise base.EstimateFormatError(f"{source}: '{name}' must be a string.")
    item = arr.reshape(-1)[0]
    return item.decode() if isinstance(item, bytes) else str(item)


def _camera(data: dict[str, Any], source: str) -> base.CameraInfo:
    size = None
    if "image_size" in data:
        s = base.finite(data["image_size"], "image_size", source).reshape(-1)
        if s.size != 2:
            raise base.EstimateFormatError(f"{source}: 'image_size' must be [width, height].")
        size = base.image_size_from(s[0], s[1], source)
    elif "width" in data and "height" in data:
        size = base.image_size_from(data["width"], data["height"], source)
    if "K" in data:
        return base.CameraInfo.from_K(data["K"], size, source)
    if "focal_length" in data:
        f = base.finite(data["focal_length"], "focal_length", source).reshape(-1)
        if f.size not in (1, 2) or not (f > 0).all():
            raise base.EstimateFormatError(f"{source}: 'focal_length' must be one or two positive numbers.")
        if size is None:
            raise base.EstimateFormatError(f"{source}: 'focal_length' needs 'image_size' [width, height] (or "
                                           "'width'/'height') to place the principal point.")
        pp = None
        if "principal_point" in data:
            p = base.finite(data["principal_point"], "principal_point", source).reshape(-1)
            if p.size != 2:
                raise base.EstimateFormatError(f"{source}: 'principal_point' must be [cx, cy].")
            pp = (float(p[0]), float(p[1]))
        return base.CameraInfo(float(f.mean()), size, principal_px=pp)
    return base.CameraInfo(None, size)


def sequence_length(data: Any) -> int | None:
    """T when ``data`` is one person over T > 1 frames (T poses, one ``betas`` row), else None."""
    if not isinstance(data, dict) or "betas" not in data or "global_orient" not in data:
        return None
    try:
        go, betas = np.asarray(data["global_orient"]), np.asarray(data["betas"])
    except (TypeError, ValueError):
        return None
    if go.dtype.kind not in "fiu" or betas.dtype.kind not in "fiu" or go.ndim != 2 or go.shape[1] != 3:
        return None
    one_shape = betas.ndim == 1 or (betas.ndim == 2 and betas.shape[0] == 1)
    return int(go.shape[0]) if one_shape and go.shape[0] > 1 else None


def _one(data: dict[str, Any], source: str, max_people: int) -> list[base.EstimatedPerson]:
    go = base.rows(base.require(data, "global_orient", source), "global_orient", 3, source)
    N = go.shape[0]
    bp = base.finite(base.require(data, "body_pose", source), "body_pose", source)
    if bp.size == N * 69:
        bp, family = bp.reshape(N, 23, 3), "smpl"
    elif bp.size == N * 63:
        bp = np.concatenate([bp.reshape(N, 21, 3), np.zeros((N, 2, 3))], axis=1)
        family = "smplx"
    else:
        raise base.EstimateFormatError(f"{source}: 'body_pose' has shape {bp.shape}; expected ({N}, 23, 3), ({N}, 69) "
                                       f"or, for SMPL-X/SMPL-H, ({N}, 63).")
    if "model_type" in data:
        model = _text(data["model_type"], "model_type", source).lower()
        if model not in ("smpl", "smplh", "smplx"):
            raise base.EstimateFormatError(f"{source}: 'model_type' must be smpl, smplh or smplx, got {model!r}.")
        family = "smplx" if model == "smplx" else "smpl"
    transl = base.rows(data.get("transl", np.zeros((N, 3))), "transl", 3, source, N)
    betas = base.finite(data.get("betas", np.zeros((N, NUM_BETAS))), "betas", source)
    one_shape = betas.ndim == 1 or (betas.ndim == 2 and betas.shape[0] == 1)
    betas = betas.reshape(1, -1).repeat(N, 0) if one_shape or not betas.size % N == 0 else betas.reshape(N, -1)
    g = data.get("gender", "neutral")
    g_list = [g] if isinstance(g, str) else np.asarray(g).reshape(-1).tolist()
    if len(g_list) not in (1, N):
        raise base.EstimateFormatError(f"{source}: 'gender' has {len(g_list)} entries for {N} people.")
    try:
        genders = [Gender.parse(x.decode() if isinstance(x, bytes) else str(x)) for x in
                   (g_list if len(g_list) == N else g_list[:1] * N)]
    except ValueError as exc:
        raise base.EstimateFormatError(f"{source}: 'gender': {exc}") from None
    frame = _text(data.get("frame", "world"), "frame", source)
    if frame not in ("world", "camera"):
        raise base.EstimateFormatError(f"{source}: 'frame' must be 'world' or 'camera', got {frame!r}.")
    pose = np.concatenate([go[:, None], bp], axis=1)
    return base.make_people(pose, transl, betas, frame_of_reference=frame, translation_kind="transl",  # type: ignore[arg-type]
                            body_family=family, genders=genders, camera=_camera(data, source),  # type: ignore[arg-type]
                            source=f"{source} (plain)", max_people=max_people)


def _sequence_frame(data: dict[str, Any], T: int, source: str, frame: int) -> dict[str, Any]:
    """Row ``frame`` of a sequence file as a one-person record (per-frame keys sliced, the rest kept)."""
    import warnings

    from workflows.estimators.pose_array import EstimateNote

    if not 0 <= frame < T:
        raise base.EstimateFormatError(f"{source}: frame {frame} out of range (0..{T - 1}): a sequence of {T} frames "
                                       f"(one 'betas' with {T} poses).")
    warnings.warn(f"{source}: one 'betas' with {T} poses: one person over {T} frames (0..{T - 1}); from-estimate "
                  "reads --frame N, scene animate all of them.", EstimateNote, stacklevel=3)
    out = dict(data)
    out["global_orient"] = base.finite(data["global_orient"], "global_orient", source)[frame:frame + 1]
    bp = base.finite(base.require(data, "body_pose", source), "body_pose", source)
    if bp.shape[0] != T:
        raise base.EstimateFormatError(
            f"{source}: 'body_pose' has {bp.shape[0]} rows for {T} frames of 'global_orient'.")
    out["body_pose"] = bp[frame:frame + 1]
    if "transl" in data:
        out["transl"] = base.rows(data["transl"], "transl", 3, source, T)[frame:frame + 1]
    return out


def from_data(data: Any, *, source: str = "<plain>", frame: int = 0, max_people: int = base.MAX_PEOPLE
              ) -> list[base.EstimatedPerson]:
    T = sequence_length(data)
    if T is not None:
        people = _one(_sequence_frame(data, T, source, frame), source, max_people)
        return [dataclasses.replace(p, person_id="0", frame=str(frame)) for p in people]
    if frame != 0:
        raise base.EstimateFormatError(f"{source}: a plain SMPL file is one frame; --frame must be 0, got {frame}.")
    if isinstance(data, list):
        if len(data) > max_people:
            raise base.EstimateFormatError(f"{source}: {len(data)} people exceeds the cap of {max_people}; pass "
                                           f"--max-people {len(data)} (max_people={len(data)}) if the file is right.")
        people = [p for i, d in enumerate(data) for p in _one(d, f"{source}[{i}]", max_people)]
        return [dataclasses.replace(p, person_id=str(i)) for i, p in enumerate(people)]
    return _one(data, source, max_people)
