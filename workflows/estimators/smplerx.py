"""SMPLer-X per-person results: ``<out>/smplx/{frame:05}_{bbox_id}.npz`` with ``<out>/meta/{frame:05}_{bbox_id}.json``.

Written by SMPLer-X (github.com/caizhongang/SMPLer-X, ``main/inference.py`` ``main``): for every detected
person of every frame, ``np.savez(npz_path, **smplx_pred)`` with ``global_orient (1, 3)``, ``body_pose
(21, 3)`` (SMPL-X body joints), ``left_hand_pose``/``right_hand_pose (15, 3)``, ``jaw_pose``, ``leye_pose``,
``reye_pose (1, 3)``, ``betas (1, 10)``, ``expression (1, 10)`` and ``transl (1, 3)`` = the network's
``cam_trans``; and ``meta/{frame:05}_{bbox_id}.json`` with ``focal [fx, fy]`` and ``princpt [cx, cy]`` (full
image pixels, ``cfg.focal`` scaled to the person's box), ``bbox``, ``bbox_mmdet``, ``bbox_id``, ``img_path``.

``main/SMPLer_X.py`` ``get_coord`` renders ``smplx_layer(...).vertices + cam_trans`` (no ``transl`` in the
layer call): ``transl`` is smplx's translation of **SMPL-X**, in the OpenCV camera of that person's meta
``focal``/``princpt``. Each person has its own camera (its box's), while a scene has one: the first person's
camera (lowest ``bbox_id``) is the scene's, and every other person is moved along its own viewing ray so
that its pelvis projects to the same pixel at the same apparent size (depth scaled by the focal ratio).

The people of a frame are all ``{frame:05}_*.npz`` files beside the given one (``person_<bbox_id>``);
``--frame N`` (N > 0) reads frame N's files from the same folder instead. Without the meta json the crop
camera is unknown: a 60-degree field of view is assumed (said once). SMPL's two hand joints have no SMPL-X
body counterpart and get zero rotation; the hands, jaw, eyes and expression are not used.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import Gender
from workflows.estimators import base
from workflows.estimators.base import EstimatedPerson, EstimateFormatError

FORMAT = "smplerx"
KEYS = ("global_orient", "body_pose", "jaw_pose", "expression", "transl")
"""The keys of ``smplx_pred`` that identify a SMPLer-X file (a plain SMPL-X npz lacks the face keys)."""
_NAME = re.compile(r"^(\d+)_(\d+)$")


def matches(data: Any) -> bool:
    """SMPLer-X's keys with ONE person of one frame (``global_orient`` 3 numbers): an SMPL-X sequence in the same
    smplx-layer keys (``global_orient (T, 3)``, one ``betas`` row) is the plain reader's sequence."""
    if not (isinstance(data, dict) and all(k in data for k in KEYS)):
        return False
    try:
        return np.asarray(data["global_orient"]).size == 3
    except (TypeError, ValueError):
        return True  # the reader names the problem


def _meta(npz: Path, source: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(focal (2,), princpt (2,)) from ``meta/<stem>.json`` beside the ``smplx`` folder, or None."""
    path = npz.parent.parent / "meta" / f"{npz.stem}.json"
    if not path.is_file():
        return None
    from smplik.limits import JSON_BYTES, read_bounded

    try:
        meta = json.loads(read_bounded(path, JSON_BYTES).decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise EstimateFormatError(f"{path}: cannot read JSON ({type(exc).__name__}).") from None
    focal = base.finite(base.require(meta, "focal", str(path)), "focal", str(path)).reshape(-1)
    princpt = base.finite(base.require(meta, "princpt", str(path)), "princpt", str(path)).reshape(-1)
    if focal.shape != (2,) or princpt.shape != (2,) or not (focal > 0).all():
        raise EstimateFormatError(f"{path}: 'focal' and 'princpt' must be two numbers each (focal positive).")
    return focal, princpt


def _person(data: Any, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose (24, 3) SMPL order, transl (3,), betas (10,)) of one ``smplx_pred`` dict."""
    if not matches(data):
        found = ", ".join(map(str, data)) if isinstance(data, dict) else type(data).__name__
        raise EstimateFormatError(f"{where}: expected SMPLer-X's keys {', '.join(KEYS)} (found: {found}).")
    go = base.rows(data["global_orient"], "global_orient", 3, where, 1)[0]
    body = base.finite(data["body_pose"], "body_pose", where).reshape(-1)
    if body.shape[0] != 63:
        raise EstimateFormatError(f"{where}: 'body_pose' has {body.shape[0]} numbers; expected 21 x 3.")
    transl = base.rows(data["transl"], "transl", 3, where, 1)[0]
    betas = base.finite(base.require(data, "betas", where), "betas", where).reshape(-1)
    return np.concatenate([go, body, np.zeros(6)]).reshape(24, 3), transl, betas


def read(path: str | Path, data: Any, *, frame: int = 0, max_people: int = base.MAX_PEOPLE
         ) -> list[EstimatedPerson]:
    """The people of one frame (see the module docstring)."""
    from smplik.safe_pickle import read_npz
    from workflows.estimators.pose_array import EstimateNote

    path = Path(path)
    source = str(path)
    named = _NAME.match(path.stem)
    files = [path]
    if named:
        prefix = f"{frame:05d}" if frame > 0 else named.group(1)
        found = sorted((int(m.group(2)), p) for p in path.parent.glob(f"{prefix}_*.npz")
                       if (m := _NAME.match(p.stem)) and m.group(1) == prefix)
        files = [p for _, p in found]
    elif frame > 0:
        raise EstimateFormatError(f"{source}: one person of one image (not named <frame>_<bbox_id>.npz): "
                                  f"--frame must be 0, got {frame}.")
    if not files:
        raise EstimateFormatError(f"{source}: no SMPLer-X file {frame:05d}_*.npz in {path.parent}.")
    base.check_people_count(len(files), max_people, source)
    people = [_person(data if f == path else read_npz(f), str(f)) for f in files]
    pose = np.stack([p[0] for p in people])
    transl = np.stack([p[1] for p in people])
    betas = np.zeros((len(people), 10))
    for i, p in enumerate(people):
        betas[i, :min(10, p[2].shape[0])] = p[2][:10]
    pelvis = transl + base.estimator_rest_pelvis(betas, Gender.NEUTRAL, "smplx")
    metas = [_meta(f, source) for f in files]
    if metas[0] is None:
        warnings.warn(f"{source}: no SMPLer-X meta json beside the smplx folder; the camera is unknown, a "
                      "60-degree field of view is assumed for overlays.", EstimateNote, stacklevel=2)
        camera = base.CameraInfo()
    else:
        f0, c0 = metas[0]
        camera = base.CameraInfo(float(f0.mean()), None, principal_px=(float(c0[0]), float(c0[1])),
                                 focal_rule="intrinsics")
        for i, meta in enumerate(metas[1:], start=1):
            if meta is None:
                raise EstimateFormatError(f"{files[i]}: its meta json is missing while {files[0].name}'s is present.")
            pelvis[i] = move_to_camera(pelvis[i], meta, (f0, c0))
    ids = [m.group(2) if (m := _NAME.match(f.stem)) else "0" for f in files]
    label = str(int(named.group(1))) if named and frame == 0 else str(frame)
    return base.make_people(pose, pelvis, betas, frame_of_reference="camera", translation_kind="pelvis",
                            body_family="smplx", camera=camera, person_ids=[str(int(i)) for i in ids],
                            frames=[label] * len(ids), source=f"{source} (smplerx)", max_people=max_people)


def move_to_camera(point_cam: np.ndarray, camera_from: tuple[np.ndarray, np.ndarray],
                   camera_to: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """A camera-frame point (3,) seen by pinhole ``camera_from`` = ``(focal (2,), principal point (2,))``, moved
    so that ``camera_to`` sees it at the same pixel and the same apparent size (depth scaled by the focal ratio)."""
    (f_a, c_a), (f_b, c_b) = camera_from, camera_to
    x, y, z = point_cam
    pixel = f_a * np.array([x, y]) / z + c_a
    z_b = z * float(f_b.mean()) / float(f_a.mean())
    return np.array([*((pixel - c_b) * z_b / f_b), z_b])
