"""AGORA prediction pickles: ``<image>_personId_<k>.pkl``, one person each, SMPL or SMPL-X parameters.

The layout of github.com/pixelite1201/agora_evaluation (``docs/prediction_format.md``, checked by
``agora_evaluation/check_pred_format.py``): a dict with ``params`` = ``{transl (1, 3), betas (1, num_betas),
global_orient, body_pose, ...}`` (SMPL-X adds ``left_hand_pose``, ``right_hand_pose``, ``jaw_pose``, ``leye_pose``,
``reye_pose``, ``expression``), ``pose2rot`` (True, the default: axis-angle, ``global_orient (1, 3)`` or
``(1, 1, 3)``, ``body_pose (1, 63)`` SMPL-X / ``(1, 23, 3)`` SMPL; False: rotation matrices ``(1, 1, 3, 3)``,
``(1, 21 | 23, 3, 3)``), ``joints (24, 2)`` (the projected joints in 3840 x 2160 pixels, used by the evaluation only
to match people), optional ``gender``, ``age``, ``num_betas``. ``transl`` is smplx's, in the camera frame (the
evaluation compares camera-frame joints after root alignment); no camera is stored, so overlays assume a 60-degree
field of view.

The people of one image are the sibling files ``<image>_personId_*.pkl`` (person ids their ``k``); ``--frame`` must
be 0 (AGORA predictions are per image).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import Gender
from workflows.estimators import base

FORMAT = "agora"
_NAME = re.compile(r"^(.*)_personId_(\d+)$")


def matches(data: Any) -> bool:
    return (isinstance(data, dict) and isinstance(data.get("params"), dict)
            and "global_orient" in data["params"] and "body_pose" in data["params"])


def _person(data: Any, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, Gender]:
    """(pose (24, 3) SMPL order, transl (3,), betas, family, gender) of one AGORA prediction dict."""
    if not matches(data):
        raise base.EstimateFormatError(f"{where}: expected AGORA's 'params' dict with 'global_orient' and "
                                       "'body_pose' (agora_evaluation docs/prediction_format.md).")
    p = data["params"]
    pose2rot = bool(np.asarray(data.get("pose2rot", True)).reshape(-1)[0])
    go = base.finite(p["global_orient"], "params.global_orient", where)
    bp = base.finite(p["body_pose"], "params.body_pose", where)
    if pose2rot:
        go, bp = go.reshape(-1), bp.reshape(-1)
        if go.size != 3:
            raise base.EstimateFormatError(f"{where}: 'params.global_orient' has {go.size} numbers; expected 3 "
                                           "(pose2rot True: axis-angle).")
    else:
        go = base.rotations_to_axis_angle(go.reshape(-1, 3, 3)[:1], "params.global_orient", where).reshape(-1)
        bp = base.rotations_to_axis_angle(bp.reshape(-1, 3, 3), "params.body_pose", where).reshape(-1)
    if bp.size == 69:
        family, body = "smpl", bp.reshape(23, 3)
    elif bp.size == 63:
        family, body = "smplx", np.concatenate([bp.reshape(21, 3), np.zeros((2, 3))])
    else:
        raise base.EstimateFormatError(f"{where}: 'params.body_pose' has {bp.size // 3} joints; expected 23 (SMPL) "
                                       "or 21 (SMPL-X).")
    transl = base.rows(base.require(p, "transl", where), "params.transl", 3, where, 1)[0]
    betas = base.finite(p.get("betas", np.zeros(10)), "params.betas", where).reshape(-1)
    g = data.get("gender", "neutral")
    g = g.decode() if isinstance(g, bytes) else str(np.asarray(g).reshape(-1)[0])
    try:
        gender = Gender.parse(g)
    except ValueError as exc:
        raise base.EstimateFormatError(f"{where}: 'gender': {exc}") from None
    return np.concatenate([go[None], body]), transl, betas, family, gender


def read(path: str | Path, data: Any, *, frame: int = 0, max_people: int = base.MAX_PEOPLE
         ) -> list[base.EstimatedPerson]:
    """The people of the file's image (module docstring)."""
    from smplik.safe_pickle import load_pickle

    path = Path(path)
    source = str(path)
    if frame != 0:
        raise base.EstimateFormatError(f"{source}: AGORA predictions are per image; --frame must be 0, got {frame}.")
    named = _NAME.match(path.stem)
    files = [(0, path)]
    if named:
        files = sorted((int(m.group(2)), p) for p in path.parent.glob(f"{glob_escape(named.group(1))}_personId_*"
                                                                      f"{path.suffix}")
                       if (m := _NAME.match(p.stem)) and m.group(1) == named.group(1))
    base.check_people_count(len(files), max_people, source)
    people = [_person(data if f == path else load_pickle(f), str(f)) for _, f in files]
    families = {p[3] for p in people}
    if len(families) > 1:
        raise base.EstimateFormatError(f"{source}: the image's predictions mix SMPL and SMPL-X bodies.")
    betas = np.zeros((len(people), 10))
    for i, p in enumerate(people):
        betas[i, :min(10, p[2].size)] = p[2][:10]
    return base.make_people(np.stack([p[0] for p in people]), np.stack([p[1] for p in people]), betas,
                            frame_of_reference="camera", translation_kind="transl", body_family=families.pop(),
                            genders=[p[4] for p in people], camera=base.CameraInfo(),
                            person_ids=[str(k) for k, _ in files], source=f"{source} (agora)", max_people=max_people)


def glob_escape(text: str) -> str:
    """``text`` with glob's special characters escaped."""
    import glob

    return glob.escape(text)
