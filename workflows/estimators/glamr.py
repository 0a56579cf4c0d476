"""GLAMR results ``.pkl``: ``{"person_data": {person_id: {...}}, "cam_pose": ..., "meta": ...}``.

Written by GLAMR (github.com/NVlabs/GLAMR, ``global_recon/run_demo.py`` pickles the ``data`` dict that
``global_recon/models/global_recon_model.py`` ``GlobalReconOptimizer`` builds and optimises). Per person,
over the video's frames (``frames = arange(max_len)``, invisible frames in-filled):

* ``smpl_pose (T, 69)`` body axis-angle; ``smpl_beta (T, 10)``;
* ``smpl_orient_cam (T, 3)``, ``root_trans_cam (T, 3)``: the root rotation and the **root joint's
  position** (HybrIK's ``root_trans``: the pelvis itself, not smplx's ``transl``) in the OpenCV camera
  frame; ``cam_K (T, 3, 3)`` the intrinsics;
* ``smpl_orient_world``, ``root_trans_world``: the same in GLAMR's world (``transform_rot`` /
  ``transform_trans`` by ``cam_pose_inv``), **z-up** (its trajectory losses use ``cam_pose_inv[:, 2]``
  as up), turned into smplik's y-up world here.

``space``: ``"world"`` (default, GLAMR's point) or ``"camera"``. ``--frame N`` is row N of every person
that has one. Torch tensors in the pickle are rebuilt as numpy arrays by the restricted loader.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from workflows.estimators import base
from workflows.estimators.base import EstimatedPerson, EstimateFormatError
from workflows.estimators.easymocap import R_YUP_ZUP

FORMAT = "glamr"


def matches(data: Any) -> bool:
    people = data.get("person_data") if isinstance(data, dict) else None
    return isinstance(people, dict) and bool(people) and all(
        isinstance(p, dict) and "smpl_pose" in p for p in people.values())


def from_data(data: Any, *, source: str = "<glamr>", frame: int = 0, space: Literal["camera", "world"] = "world",
              max_people: int = base.MAX_PEOPLE) -> list[EstimatedPerson]:
    if not matches(data):
        raise EstimateFormatError(f"{source}: expected 'person_data': {{id: {{'smpl_pose', 'smpl_beta', ...}}}}.")
    people = data["person_data"]
    base.check_people_count(len(people), max_people, source)
    suffix = "world" if space == "world" else "cam"
    poses, pelvis, betas, ids, camera = [], [], [], [], None
    for pid, d in people.items():
        where = f"{source}.person_data[{pid!r}]"
        body = base.rows(base.require(d, "smpl_pose", where), "smpl_pose", 69, where)
        T = body.shape[0]
        if frame >= T:
            continue
        orient = base.rows(base.require(d, f"smpl_orient_{suffix}", where), f"smpl_orient_{suffix}", 3, where, T)
        root = base.rows(base.require(d, f"root_trans_{suffix}", where), f"root_trans_{suffix}", 3, where, T)
        b = base.rows(base.require(d, "smpl_beta", where), "smpl_beta", 10, where)
        go, p = orient[frame], root[frame]
        if space == "world":
            go, p = (R_YUP_ZUP * Rotation.from_rotvec(go)).as_rotvec(), R_YUP_ZUP.apply(p)
        elif camera is None and "cam_K" in d:
            K = base.finite(d["cam_K"], "cam_K", where).reshape(-1, 3, 3)
            camera = base.CameraInfo.from_K(K[min(frame, K.shape[0] - 1)], None, f"{where}.cam_K")
        poses.append(np.concatenate([go, body[frame]]))
        pelvis.append(p)
        betas.append(b[min(frame, b.shape[0] - 1)])
        ids.append(str(pid))
    if not ids:
        raise EstimateFormatError(f"{source}: no person has frame {frame}.")
    if space != "world" and camera is None:
        camera = base.CameraInfo()
    return base.make_people(np.stack(poses), np.stack(pelvis), np.stack(betas),
                            frame_of_reference="world" if space == "world" else "camera", translation_kind="pelvis",
                            camera=camera, person_ids=ids, frames=[str(frame)] * len(ids),
                            source=f"{source} (glamr)", max_people=max_people)
