"""PyMAF-X joblib ``.pkl`` results (demo output), flat or per person.

* Flat: ``pose`` (N, 72) axis-angle (OpenCV camera frame), ``betas`` (N, 10), ``orig_cam_t`` (N, 3)
  camera translation of the full image (smplx ``transl``); optional ``frame_ids`` and ``person_ids`` (N,).
* Per person (VIBE-style): ``{person_id: {the same keys over that person's frames}}``.

``frame`` picks the rows of one video frame (default: the first frame present).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from workflows.estimators.base import CameraInfo, EstimatedPerson, EstimateFormatError, make_people, require
from workflows.safe_pickle import load_pickle

FORMAT = "pymafx"


def _is_flat(data: Any) -> bool:
    return isinstance(data, dict) and "pose" in data and "orig_cam_t" in data


def matches(data: Any) -> bool:
    if _is_flat(data):
        return True
    return isinstance(data, dict) and bool(data) and all(_is_flat(v) for v in data.values())


def from_data(data: dict[Any, Any], *, source: str = "<pymafx>", frame: int | None = None) -> list[EstimatedPerson]:
    parts = [(None, data)] if _is_flat(data) else list(data.items()) if matches(data) else None
    if parts is None:
        raise EstimateFormatError(f"{source}: expected keys 'pose', 'betas', 'orig_cam_t' (flat or per person).")
    rows_pose, rows_t, rows_b, ids, frames = [], [], [], [], []
    for pid, d in parts:
        pose = np.asarray(require(d, "pose", source), dtype=np.float64).reshape(-1, 72)
        N = pose.shape[0]
        t = np.asarray(require(d, "orig_cam_t", source), dtype=np.float64).reshape(N, 3)
        b = np.asarray(require(d, "betas", source), dtype=np.float64).reshape(N, -1)
        f = np.asarray(d.get("frame_ids", np.zeros(N)), dtype=np.int64).reshape(N)
        p = np.asarray(d["person_ids"]).reshape(N) if "person_ids" in d else np.full(N, pid if pid is not None else -1)
        for i in range(N):
            rows_pose.append(pose[i])
            rows_t.append(t[i])
            rows_b.append(b[i])
            ids.append(str(p[i]) if pid is not None or "person_ids" in d else str(i))
            frames.append(int(f[i]))
    if not rows_pose:
        raise EstimateFormatError(f"{source}: no people.")
    frame = min(frames) if frame is None else frame
    keep = [i for i, f in enumerate(frames) if f == frame]
    if not keep:
        raise EstimateFormatError(f"{source}: no person in frame {frame} (frames {min(frames)}..{max(frames)}).")
    return make_people(np.stack([rows_pose[i] for i in keep]), np.stack([rows_t[i] for i in keep]),
                       np.stack([rows_b[i] for i in keep]), frame_of_reference="camera", translation_kind="transl",
                       camera=CameraInfo(), person_ids=[ids[i] for i in keep], frames=[str(frame)] * len(keep),
                       source=f"{source} (pymafx)")


def read(path: str | Path, *, frame: int | None = None, trust_pickle: bool = False) -> list[EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
