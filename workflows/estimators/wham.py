"""WHAM joblib ``.pkl`` results: one entry per tracked person (``{track_id: {...}}``), each over T frames.

* ``pose`` (T, 72), ``trans`` (T, 3): camera-frame SMPL (OpenCV axes; ``trans`` is smplx's ``transl``).
* ``pose_world`` (T, 72), ``trans_world`` (T, 3): WHAM's gravity-aligned y-up world; used as is
  (no camera conversion) when ``space="world"`` and present.
* ``betas`` (T, 10) or (10,); optional ``frame_ids`` (T,) video frame of each row.

A person is taken at video frame ``frame`` (default: the first frame any track covers); tracks that
do not cover that frame are skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from workflows.estimators.base import CameraInfo, EstimatedPerson, EstimateFormatError, make_people, require
from workflows.safe_pickle import load_pickle

FORMAT = "wham"


def matches(data: Any) -> bool:
    if not isinstance(data, dict) or not data:
        return False
    first = next(iter(data.values()))
    return isinstance(first, dict) and "pose" in first and ("trans" in first or "trans_world" in first)


def from_data(data: dict[Any, Any], *, source: str = "<wham>", frame: int | None = None,
              space: Literal["world", "camera"] = "world") -> list[EstimatedPerson]:
    if not matches(data):
        raise EstimateFormatError(f"{source}: expected {{track_id: {{'pose', 'trans', 'betas', ...}}}}.")
    tracks = []
    for tid, t in data.items():
        T = np.asarray(require(t, "pose", f"{source}[{tid!r}]")).reshape(-1, 72).shape[0]
        ids = np.asarray(t.get("frame_ids", np.arange(T))).reshape(-1).astype(np.int64)
        tracks.append((tid, t, ids))
    if frame is None:
        frame = int(min(ids.min() for _, _, ids in tracks if ids.size))
    people = []
    for tid, t, ids in tracks:
        rows = np.nonzero(ids == frame)[0]
        if rows.size == 0:
            continue
        r = int(rows[0])
        where = f"{source}[{tid!r}]"
        world = space == "world" and "pose_world" in t and "trans_world" in t
        pose = np.asarray(require(t, "pose_world" if world else "pose", where), dtype=np.float64).reshape(-1, 72)[r]
        trans = np.asarray(require(t, "trans_world" if world else "trans", where), dtype=np.float64).reshape(-1, 3)[r]
        betas = np.asarray(require(t, "betas", where), dtype=np.float64)
        betas = betas.reshape(-1, betas.shape[-1])[min(r, betas.reshape(-1, betas.shape[-1]).shape[0] - 1)]
        people += make_people(pose[None], trans[None], betas[None], frame_of_reference="world" if world else "camera",
                              translation_kind="transl", camera=CameraInfo(), person_ids=[str(tid)],
                              frames=[str(frame)], source=f"{source} (wham)")
    if not people:
        raise EstimateFormatError(f"{source}: no track covers frame {frame}.")
    return people


def read(path: str | Path, *, frame: int | None = None, trust_pickle: bool = False,
         space: Literal["world", "camera"] = "world") -> list[EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame, space=space)
