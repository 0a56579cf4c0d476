"""4D-Humans / PHALP joblib ``.pkl`` tracking results.

Written by PHALP (github.com/brjathu/PHALP, ``phalp/trackers/PHALP.py``, ``PHALP.track``:
``joblib.dump(final_visuals_dic, pkl_path, compress=3)``), which 4D-Humans' ``track.py`` runs. One
entry per frame, keyed by the frame's name, each a dict of per-detection lists; ``--frame N`` is the
N-th frame name in sorted order and people are keyed by ``tid``:

* ``smpl``: list of dicts with ``global_orient`` (1, 3, 3), ``body_pose`` (23, 3, 3) rotation
  matrices (OpenCV camera frame) and ``betas`` (10,).
* ``camera``: list of (3,) camera translations of the full image, added to the SMPL output without
  ``transl`` (smplx ``transl``).
* ``tid``: track ids; ``size``: list of the image size (two numbers; only their maximum is used);
  ``time``: frame number.

4D-Humans renders with a focal length of 5000 px for a 256 px crop, scaled to the image's larger
side: ``focal = 5000 / 256 * max(width, height)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import NUM_JOINTS
from smplik.safe_pickle import load_pickle
from workflows.estimators import base

FORMAT = "phalp"
FOCAL_PER_PIXEL = 5000.0 / 256.0


def matches(data: Any) -> bool:
    if not isinstance(data, dict) or not data:
        return False
    first = next(iter(data.values()))
    return isinstance(first, dict) and "smpl" in first and "camera" in first


def from_data(data: dict[str, Any], *, source: str = "<phalp>", frame: int | str = 0,
              max_people: int = base.MAX_PEOPLE) -> list[base.EstimatedPerson]:
    if not isinstance(data, dict) or not data:
        raise base.EstimateFormatError(f"{source}: expected a dict of frames.")
    names = sorted(data, key=str)
    if isinstance(frame, str):
        if frame not in data:
            raise base.EstimateFormatError(
                f"{source}: no frame {frame!r} (first frames: {', '.join(map(str, names[:5]))}).")
        key = frame
    else:
        if not 0 <= frame < len(names):
            raise base.EstimateFormatError(f"{source}: frame {frame} out of range (0..{len(names) - 1}).")
        key = names[frame]
    entry = data[key]
    where = f"{source}[{key!r}]"
    smpl, cams = base.require(entry, "smpl", where), base.require(entry, "camera", where)
    if not isinstance(smpl, (list, tuple)) or not isinstance(cams, (list, tuple, np.ndarray)):
        raise base.EstimateFormatError(f"{where}: 'smpl' and 'camera' must be lists (one entry per person).")
    if len(smpl) != len(cams):
        raise base.EstimateFormatError(f"{where}: {len(smpl)} 'smpl' entries but {len(cams)} 'camera' entries.")
    if not smpl:
        raise base.EstimateFormatError(f"{where}: no people in this frame (choose another --frame).")
    base.check_people_count(len(smpl), max_people, where)
    R = np.zeros((len(smpl), NUM_JOINTS, 3, 3))
    betas = np.zeros((len(smpl), 10))
    for i, s in enumerate(smpl):
        at = f"{where}.smpl[{i}]"
        R[i, 0] = _matrices(base.require(s, "global_orient", at), 1, "global_orient", at)[0]
        R[i, 1:] = _matrices(base.require(s, "body_pose", at), 23, "body_pose", at)
        b = base.finite(base.require(s, "betas", at), "betas", at).reshape(-1)
        if b.size < 10:
            raise base.EstimateFormatError(f"{at}: 'betas' has {b.size} values; expected 10.")
        betas[i] = b[:10]
    camera = base.rows(cams, "camera", 3, where, len(smpl))
    sizes = entry.get("size")
    size = None
    if sizes is not None and len(sizes):
        first = base.finite(sizes[0], "size", where).reshape(-1)
        if first.size != 2:
            raise base.EstimateFormatError(f"{where}: 'size' entries must be two numbers.")
        size = base.image_size_from(first[0], first[1], where)
    focal = FOCAL_PER_PIXEL * max(size) if size else None
    tid = entry.get("tid", list(range(len(smpl))))
    tids = [str(t) for t in (tid.tolist() if isinstance(tid, np.ndarray) else list(tid))]
    if len(tids) != len(smpl):
        raise base.EstimateFormatError(f"{where}: {len(tids)} 'tid' entries for {len(smpl)} people.")
    return base.make_people(base.rotations_to_axis_angle(R, "smpl", where), camera, betas, frame_of_reference="camera",
                            translation_kind="transl", camera=base.CameraInfo(focal, size), person_ids=tids,
                            frames=[str(key)] * len(smpl), source=f"{source} (phalp)", max_people=max_people)


def _matrices(value: Any, count: int, name: str, source: str) -> np.ndarray:
    arr = base.finite(value, name, source)
    if arr.size != count * 9:
        raise base.EstimateFormatError(f"{source}: '{name}' has shape {arr.shape}; expected ({count}, 3, 3).")
    return arr.reshape(count, 3, 3)


def read(path: str | Path, *, frame: int | str = 0, trust_pickle: bool = False) -> list[base.EstimatedPerson]:
    return from_data(load_pickle(path, trust_pickle=trust_pickle), source=str(path), frame=frame)
