"""WHAM joblib ``.pkl`` results: one entry per tracked person (``{track_id: {...}}``), each over T frames.

Written by WHAM (github.com/yohanshin/WHAM, ``demo.py``, ``run``: ``results[_id]['pose'] = ...``,
``joblib.dump(results, osp.join(output_pth, "wham_output.pkl"))``):

* ``pose`` (T, 72) camera-frame SMPL (root from ``poses_root_cam``, OpenCV axes), ``trans`` (T, 3)
  ``= trans_cam - network.output.offset``: the pelvis minus the rest-pelvis offset, i.e. smplx's
  ``transl``.
* ``pose_world`` (T, 72), ``trans_world`` (T, 3): WHAM's gravity-aligned y-up world (replayed as
  smplx ``transl`` by ``lib/vis/run_vis.py``); used (no camera) with ``space="world"``.
* ``betas`` (T, 10); ``verts``; ``frame_ids`` (T,) video frame of each row.

``--frame N`` is video frame ``N``: every track that covers it gives one person keyed by its track
id; tracks that do not cover it are skipped. Camera: WHAM's default intrinsics without a
calibration file, focal = the image diagonal in pixels, principal point the image centre
(``lib/utils/imutils.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from smplik.safe_pickle import load_pickle
from workflows.estimators import base

FORMAT = "wham"


def matches(data: Any) -> bool:
    if not isinstance(data, dict) or not data:
        return False
    first = next(iter(data.values()))
    return isinstance(first, dict) and "pose" in first and ("trans" in first or "trans_world" in first)


def from_data(data: dict[Any, Any], *, source: str = "<wham>", frame: int = 0,
              space: Literal["world", "camera"] = "world", max_people: int = base.MAX_PEOPLE
              ) -> list[base.EstimatedPerson]:
    if not matches(data):
        raise base.EstimateFormatError(f"{source}: expected {{track_id: {{'pose', 'trans', 'betas', ...}}}}.")
    base.check_people_count(len(data), max_people, source)
    people: list[base.EstimatedPerson] = []
    covered: list[int] = []
    for tid, t in data.items():
        where = f"{source}[{tid!r}]"
        if not isinstance(t, dict):
            raise base.EstimateFormatError(f"{where}: expected a dict of arrays.")
        world = space == "world" and "pose_world" in t and "trans_world" in t
        pose = base.rows(base.require(t, "pose_world" if world else "pose", where), "pose", 72, where)
        T = pose.shape[0]
        trans = base.rows(base.require(t, "trans_world" if world else "trans", where), "trans", 3, where, T)
        betas = base.finite(base.require(t, "betas", where), "betas", where)
        betas = betas.reshape(1, -1) if betas.ndim == 1 else betas.reshape(betas.shape[0], -1)
        ids = base.frame_numbers(t.get("frame_ids", np.arange(T)), "frame_ids", where)
        if ids.shape[0] != T:
            raise base.EstimateFormatError(f"{where}: 'frame_ids' has {ids.shape[0]} entries for {T} poses.")
        covered += [int(ids.min()), int(ids.max())] if T else []
        hit = np.nonzero(ids == frame)[0]
        if hit.size == 0:
            continue
        r = int(hit[0])
        people += base.make_people(pose[r:r + 1], trans[r:r + 1], betas[min(r, betas.shape[0] - 1)][None],
                                   frame_of_reference="world" if world else "camera", translation_kind="transl",
                                   camera=base.CameraInfo(focal_rule="diagonal"), person_ids=[str(tid)],
                                   frames=[str(frame)], source=f"{source} (wham)")
    if not people:
        span = f" (tracks cover frames {min(covered)}..{max(covered)})" if covered else ""
        raise base.EstimateFormatError(f"{source}: no track covers frame {frame}{span}.")
    return people


def read(path: str | Path, *, frame: int = 0, trust_pickle: bool = False,
         space: Literal["world", "camera"] = "world") -> list[base.EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame, space=space)
