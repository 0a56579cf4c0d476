"""mmhuman3d ``HumanData`` ``.npz`` (github.com/open-mmlab/mmhuman3d, ``mmhuman3d/data/data_structures/
human_data.py``): ``HumanData.dump`` writes ``np.savez_compressed(npz_path, **dict_to_dump)``, its values numpy
arrays and dicts (saved as 0-d object arrays, read through the project's restricted unpickler), ``__data_len__``
the number of instances (rows), ``image_path (N,)`` each row's image, ``bbox_xywh (N, 5)``, ``keypoints2d``, ...,
and the body parameters as a dict: ``smpl`` = ``{global_orient (N, 3), body_pose (N, 23, 3) or (N, 69), betas
(N, 10), transl (N, 3)}`` (or ``smplx`` with ``body_pose (N, 21, 3)``), one row per person instance.

Frames: the distinct ``image_path`` values in order of first appearance (frame k = the k-th image), its people
the rows of that image (person ids their order within it); without ``image_path`` every row is a frame of one
person. ``transl`` is smplx's, in the camera frame of the image (the converters' ``cam_param``); no intrinsics are
read, so overlays assume a 60-degree field of view.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from workflows.estimators import base

FORMAT = "humandata"
_BODY_KEYS = ("smpl", "smplx")


def _body(data: Any) -> tuple[str, dict] | None:
    if not isinstance(data, dict):
        return None
    for key in _BODY_KEYS:
        value = data.get(key)
        if isinstance(value, dict) and "global_orient" in value and "body_pose" in value:
            return key, value
    return None


def matches(data: Any) -> bool:
    return _body(data) is not None and ("__data_len__" in data or "image_path" in data or "bbox_xywh" in data)


def frames_of(data: dict) -> list[list[int]]:
    """Rows of each frame (module docstring)."""
    key, body = _body(data)  # type: ignore[misc]
    n = int(np.asarray(body["global_orient"]).reshape(-1, 3).shape[0])
    paths = data.get("image_path")
    if paths is None:
        return [[i] for i in range(n)]
    paths = [str(p) for p in np.asarray(paths).reshape(-1)]
    if len(paths) != n:
        raise base.EstimateFormatError(f"'image_path' has {len(paths)} rows for {n} rows of '{key}'.")
    order: dict[str, list[int]] = {}
    for i, p in enumerate(paths):
        order.setdefault(p, []).append(i)
    return list(order.values())


def from_data(data: Any, *, source: str = "<humandata>", frame: int = 0, max_people: int = base.MAX_PEOPLE
              ) -> list[base.EstimatedPerson]:
    found = _body(data)
    if found is None:
        raise base.EstimateFormatError(f"{source}: expected HumanData's 'smpl' (or 'smplx') dict with "
                                       "'global_orient' and 'body_pose'.")
    key, body = found
    try:
        frames = frames_of(data)
    except base.EstimateFormatError as exc:
        raise base.EstimateFormatError(f"{source}: {exc}") from None
    if not 0 <= frame < len(frames):
        raise base.EstimateFormatError(f"{source}: frame {frame} out of range (0..{len(frames) - 1}: its images).")
    rows = frames[frame]
    base.check_people_count(len(rows), max_people, source)
    go = base.rows(body["global_orient"], f"{key}.global_orient", 3, source)
    N = go.shape[0]
    bp = base.finite(body["body_pose"], f"{key}.body_pose", source).reshape(N, -1)
    if bp.shape[1] == 69:
        family, bp = "smpl", bp.reshape(N, 23, 3)
    elif bp.shape[1] == 63:
        family, bp = "smplx", np.concatenate([bp.reshape(N, 21, 3), np.zeros((N, 2, 3))], axis=1)
    else:
        raise base.EstimateFormatError(f"{source}: '{key}.body_pose' has {bp.shape[1] // 3} joints per row; "
                                       "expected 23 (SMPL) or 21 (SMPL-X).")
    transl = base.rows(body.get("transl", np.zeros((N, 3))), f"{key}.transl", 3, source, N)
    betas = base.finite(body.get("betas", np.zeros((N, 10))), f"{key}.betas", source).reshape(N, -1)
    pose = np.concatenate([go[:, None], bp], axis=1)[rows]
    people = base.make_people(pose, transl[rows], betas[rows], frame_of_reference="camera",
                              translation_kind="transl", body_family=family,  # type: ignore[arg-type]
                              camera=base.CameraInfo(), person_ids=[str(i) for i in range(len(rows))],
                              frames=[str(frame)] * len(rows), source=f"{source} (humandata)", max_people=max_people)
    return people
