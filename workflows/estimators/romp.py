"""ROMP / BEV (simple_romp) ``.npz`` results.

Written by ``simple_romp`` (github.com/Arthur151/ROMP, ``simple_romp/romp/main.py``: ``save_results``
``np.savez(path, results=outputs)``; BEV: ``simple_romp/bev/main.py``), the dict stored as a pickled
0-d object array (read by the restricted unpickler). Video runs (``romp/utils.py``
``save_video_results``) store ``results = {frame_name: outputs}``; frame ``N`` is the N-th name in
sorted order. The same keys at the top level of the ``.npz`` are accepted too.

* ``smpl_thetas`` (N, 72) float32: axis-angle, root first, OpenCV camera frame.
* ``smpl_betas`` (N, 10), or (N, 11) for BEV, whose 11th component (SMPL+A age offset) is dropped.
* ``cam_trans`` (N, 3): ``convert_cam_to_3d_trans(cam)``, added to the vertices of the SMPL output
  without ``transl`` (``root_align=False``, simple_romp's default), i.e. smplx's ``transl``
  (``translation_kind="pelvis"`` for files produced with ``--root_align``).
* optional ``track_ids`` (N,) with ``--show_tracking``: the person ids.

ROMP/BEV assume a 60-degree field of view over the larger image side; no focal length is stored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.safe_pickle import read_npz
from workflows.estimators.base import (
    MAX_PEOPLE,
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    TranslationKind,
    make_people,
    require,
    rows,
)

FORMAT = "romp"


def unwrap(data: Any) -> Any:
    """The ``results`` dict, or the top level when the keys are there."""
    inner = data.get("results", data) if isinstance(data, dict) else data
    return inner if isinstance(inner, dict) else data


def _is_video(res: Any) -> bool:
    return isinstance(res, dict) and bool(res) and "smpl_thetas" not in res and all(
        isinstance(v, dict) and "smpl_thetas" in v for v in res.values())


def matches(data: Any) -> bool:
    res = unwrap(data)
    return isinstance(res, dict) and ("smpl_thetas" in res or _is_video(res))


def from_data(data: dict[str, Any], *, source: str = "<romp>", frame: int = 0,
              translation_kind: TranslationKind = "transl", max_people: int = MAX_PEOPLE) -> list[EstimatedPerson]:
    res = unwrap(data)
    frame_name = "0"
    if _is_video(res):
        names = sorted(res, key=str)
        if not 0 <= frame < len(names):
            raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{len(names) - 1}).")
        frame_name, res = str(names[frame]), res[names[frame]]
    elif frame != 0:
        raise EstimateFormatError(f"{source}: a single-image ROMP result has only frame 0, got --frame {frame}.")
    thetas = rows(require(res, "smpl_thetas", source), "smpl_thetas", 72, source)
    N = thetas.shape[0]
    betas = rows(require(res, "smpl_betas", source), "smpl_betas", (10, 11), source, N)
    trans = rows(require(res, "cam_trans", source), "cam_trans", 3, source, N)
    ids = None
    if "track_ids" in res:
        tid = np.asarray(res["track_ids"]).reshape(-1)
        if tid.shape[0] != N:
            raise EstimateFormatError(f"{source}: 'track_ids' has {tid.shape[0]} entries for {N} people.")
        ids = [str(t) for t in tid.tolist()]
    return make_people(thetas, trans, betas, frame_of_reference="camera", translation_kind=translation_kind,
                       camera=CameraInfo(default_fov_deg=60.0), person_ids=ids, frames=[frame_name] * N,
                       source=f"{source} (romp)", max_people=max_people)


def read(path: str | Path, *, frame: int = 0, translation_kind: TranslationKind = "transl") -> list[EstimatedPerson]:
    return from_data(read_npz(path), source=str(path), frame=frame, translation_kind=translation_kind)
