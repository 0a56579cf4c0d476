"""PyMAF-X joblib ``.pkl`` results (demo output), flat or per person.

Written by PyMAF-X's demo (github.com/HongwenZhang/PyMAF-X, ``apps/demo_smplx.py``: the per-frame
``pred_results`` collected into ``joblib.dump(..., 'output.pkl')``, VIBE's layout);
``orig_cam_t`` is the full-image translation of the SMPL output without ``transl`` (smplx's
``transl``). ``--frame N`` keeps the rows whose ``frame_ids`` equal N.

* Flat: ``pose`` (N, 72) axis-angle (OpenCV camera frame), ``betas`` (N, 10), ``orig_cam_t`` (N, 3)
  camera translation of the full image (smplx ``transl``); optional ``frame_ids`` and ``person_ids`` (N,).
* Per person (VIBE-style): ``{person_id: {the same keys over that person's frames}}``.

"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.safe_pickle import load_pickle
from workflows.estimators import base

FORMAT = "pymafx"


def _is_flat(data: Any) -> bool:
    return isinstance(data, dict) and "pose" in data and "orig_cam_t" in data


def matches(data: Any) -> bool:
    if _is_flat(data):
        return True
    return isinstance(data, dict) and bool(data) and all(_is_flat(v) for v in data.values())


def from_data(data: dict[Any, Any], *, source: str = "<pymafx>", frame: int = 0,
              max_people: int = base.MAX_PEOPLE) -> list[base.EstimatedPerson]:
    parts = [(None, data)] if _is_flat(data) else list(data.items()) if matches(data) else None
    if parts is None:
        raise base.EstimateFormatError(f"{source}: expected keys 'pose', 'betas', 'orig_cam_t' (flat or per person).")
    base.check_people_count(len(parts), max_people, source)
    pose_rows, t_rows, b_rows, ids = [], [], [], []
    for pid, d in parts:
        where = source if pid is None else f"{source}[{pid!r}]"
        pose = base.rows(base.require(d, "pose", where), "pose", 72, where)
        N = pose.shape[0]
        t = base.rows(base.require(d, "orig_cam_t", where), "orig_cam_t", 3, where, N)
        b = base.finite(base.require(d, "betas", where), "betas", where)
        b = (np.broadcast_to(b.reshape(1, -1), (N, b.size)) if b.ndim == 1
             else base.rows(b, "betas", b.shape[-1], where, N))
        f = base.frame_numbers(d.get("frame_ids", np.zeros(N)), "frame_ids", where)
        if f.shape[0] != N:
            raise base.EstimateFormatError(f"{where}: 'frame_ids' has {f.shape[0]} entries for {N} poses.")
        if "person_ids" in d:
            p = np.asarray(d["person_ids"]).reshape(-1)
            if p.shape[0] != N:
                raise base.EstimateFormatError(f"{where}: 'person_ids' has {p.shape[0]} entries for {N} poses.")
            pid_of = [str(x) for x in p.tolist()]
        else:
            pid_of = [str(pid) if pid is not None else str(i) for i in range(N)]
        keep = np.nonzero(f == frame)[0]
        pose_rows += [pose[keep]]
        t_rows += [t[keep]]
        b_rows += [np.asarray(b)[keep]]
        ids += [pid_of[i] for i in keep]
    if not ids:
        raise base.EstimateFormatError(f"{source}: no person in frame {frame}.")
    widths = {b.shape[1] for b in b_rows if b.size}
    if len(widths) > 1:
        raise base.EstimateFormatError(f"{source}: 'betas' widths differ between people ({sorted(widths)}).")
    betas = np.concatenate([b for b in b_rows if b.size])
    return base.make_people(np.concatenate(pose_rows), np.concatenate(t_rows), betas,
                            frame_of_reference="camera", translation_kind="transl", camera=base.CameraInfo(),
                            person_ids=ids, frames=[str(frame)] * len(ids), source=f"{source} (pymafx)",
                            max_people=max_people)


def read(path: str | Path, *, frame: int = 0, trust_pickle: bool = False) -> list[base.EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
