"""TRAM per-track results: ``results/<seq>/hps/hps_track_<k>.npy`` beside ``results/<seq>/camera.npy``.

Written by TRAM (github.com/yufu-wang/tram): ``scripts/estimate_humans.py`` saves, per track ``k`` (tracks
sorted longest first), ``np.save(f'{hps_folder}/hps_track_{k}.npy', results)`` where ``results`` is the
dict of **torch tensors** that ``lib/models/hmr_vimo.py`` ``HMR_VIMO.inference`` returns:

* ``pred_rotmat (T, 24, 3, 3)`` SMPL rotations (root first, OpenCV camera frame); ``pred_pose (T, 144)``
  the same as 6D; ``pred_shape (T, 10)`` betas; ``pred_cam (T, 3)`` crop weak-perspective camera;
* ``pred_trans (T, 1, 3)``: ``get_trans``'s full-image camera translation, smplx's ``transl`` of SMPL
  (``lib/pipeline/visualization.py`` ``visualize_tram`` renders ``smpl(..., betas=mean shape,
  transl=pred_trans.squeeze())``; the track's mean ``pred_shape`` is used here too);
* ``frame (T,)``: the video frame of each row.

``scripts/estimate_camera.py`` saves ``np.save(f'{seq_folder}/camera.npy', camera)`` with ``img_focal``
(pixels) and ``img_center`` (the principal point; the image is taken to be twice its size), plus the
metric SLAM trajectory ``pred_cam_R (F, 3, 3)``/``pred_cam_T (F, 3)``, camera to world per video frame
(``visualize_tram`` draws ``pred_cam_R[frame] @ vertices + pred_cam_T[frame]``).

``space``: ``"camera"`` (default; the overlay camera) or ``"world"``: TRAM's SLAM world, whose axes are
the first frame's OpenCV camera axes, turned y-up like every camera frame (180 degrees about x). TRAM's
own renderer then levels the floor with a fit to all meshes (``fit_to_ground_easy``), which needs the
meshes and is not applied: "up" is the first frame's camera up.

Both files are ``np.save`` of a dict, i.e. pickles: they are read by the restricted unpickler
(:func:`smplik.safe_pickle.read_npy`), which rebuilds torch tensors as numpy arrays without torch.
``--frame N`` gives every track of the folder (``hps_track_*.npy`` beside the given file) with a row for
video frame N, one person per track (``person_<k>``).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.conventions import Gender
from workflows.estimators import base
from workflows.estimators.base import EstimatedPerson, EstimateFormatError

FORMAT = "tram"
_TRACK = re.compile(r"hps_track_(\d+)\.npy$")


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "pred_rotmat" in data and "pred_trans" in data


def _camera(track_folder: Path, source: str) -> tuple[base.CameraInfo, dict | None, Path]:
    """The camera of ``<seq>/camera.npy`` (TRAM's layout: the track files sit in ``<seq>/hps/``), else of a
    ``camera.npy`` beside the track files."""
    from smplik.safe_pickle import read_npy
    from workflows.estimators.pose_array import EstimateNote

    path = next((p for p in (track_folder.parent / "camera.npy", track_folder / "camera.npy") if p.is_file()),
                track_folder.parent / "camera.npy")
    if not path.is_file():
        warnings.warn(f"{source}: no TRAM camera.npy at {path}; the focal length is unknown, a 60-degree field "
                      "of view is assumed for overlays.", EstimateNote, stacklevel=3)
        return base.CameraInfo(), None, path
    cam = read_npy(path)
    where = str(path)
    focal = base.scalar(base.require(cam, "img_focal", where), "img_focal", where)
    center = base.finite(base.require(cam, "img_center", where), "img_center", where).reshape(-1)
    if center.shape[0] != 2 or not (0 < center[0] < 50_000 and 0 < center[1] < 50_000):
        raise EstimateFormatError(f"{where}: 'img_center' must be two positive numbers, got {center.tolist()}.")
    if not 0 < focal < 1e6:
        raise EstimateFormatError(f"{where}: 'img_focal' must be a positive focal length in pixels, got {focal}.")
    return base.CameraInfo(focal, (round(2 * center[0]), round(2 * center[1])),
                           principal_px=(float(center[0]), float(center[1])), focal_rule="intrinsics"), cam, path


def _world_pose(pose: np.ndarray, pelvis_cam: np.ndarray, cam: dict, frame: int, where: str
                ) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame root (24, 3 axis-angle) and pelvis (3,) -> TRAM's SLAM world at video ``frame`` (OpenCV
    axes, as the camera frame; :func:`base.make_people` turns them y-up)."""
    R_all = base.finite(base.require(cam, "pred_cam_R", where), "pred_cam_R", where)
    T_all = base.finite(base.require(cam, "pred_cam_T", where), "pred_cam_T", where)
    if R_all.ndim != 3 or R_all.shape[1:] != (3, 3) or T_all.reshape(-1, 3).shape[0] != R_all.shape[0]:
        raise EstimateFormatError(f"{where}: 'pred_cam_R' (F, 3, 3) and 'pred_cam_T' (F, 3) expected, got "
                                  f"{R_all.shape} and {T_all.shape}.")
    if not 0 <= frame < R_all.shape[0]:
        raise EstimateFormatError(f"{where}: the camera trajectory has {R_all.shape[0]} frames; no frame {frame}.")
    R_world_cam = R_all[frame]
    base.rotations_to_axis_angle(R_world_cam[None], f"pred_cam_R[{frame}]", where)  # a rotation, or one line
    root = base.rotations_to_axis_angle((R_world_cam @ Rotation.from_rotvec(pose[0]).as_matrix())[None],
                                        f"pred_cam_R[{frame}]", where)
    return np.concatenate([root, pose[1:]]), R_world_cam @ pelvis_cam + T_all.reshape(-1, 3)[frame]


def _row(data: Any, frame: int, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(pose (24, 3), transl (3,), betas (10,)) of the row for video frame ``frame``, or None."""
    if not matches(data):
        found = ", ".join(map(str, data)) if isinstance(data, dict) else type(data).__name__
        raise EstimateFormatError(f"{where}: expected TRAM's dict with 'pred_rotmat', 'pred_trans', 'pred_shape', "
                                  f"'frame' (found: {found}).")
    R = base.finite(data["pred_rotmat"], "pred_rotmat", where)
    if R.ndim != 4 or R.shape[1:] != (24, 3, 3):
        raise EstimateFormatError(f"{where}: 'pred_rotmat' has shape {R.shape}; expected (T, 24, 3, 3).")
    T = R.shape[0]
    trans = base.rows(data["pred_trans"], "pred_trans", 3, where, T)
    shape = base.rows(base.require(data, "pred_shape", where), "pred_shape", 10, where, T)
    frames = base.frame_numbers(data.get("frame", np.arange(T)), "frame", where)
    if frames.shape[0] != T:
        raise EstimateFormatError(f"{where}: 'frame' has {frames.shape[0]} entries for {T} rows.")
    hit = np.nonzero(frames == frame)[0]
    if hit.size == 0:
        return None
    r = int(hit[0])  # the track's mean shape, as TRAM's own renderer (lib/pipeline/visualization.py) uses it
    return base.rotations_to_axis_angle(R[r], "pred_rotmat", where), trans[r], shape.mean(axis=0)


def read(path: str | Path, data: Any, *, frame: int = 0, max_people: int = base.MAX_PEOPLE,
         space: Literal["camera", "world"] = "camera") -> list[EstimatedPerson]:
    """Every track of ``path``'s folder that covers video ``frame`` (see the module docstring)."""
    from smplik.safe_pickle import read_npy

    path = Path(path)
    source = str(path)
    match = _TRACK.search(path.name)
    tracks = sorted((int(m.group(1)), p) for p in path.parent.glob("hps_track_*.npy") if (m := _TRACK.search(p.name)))
    files = [p for _, p in tracks] if match else [path]
    poses, transl, betas, ids = [], [], [], []
    for f in files:
        row = _row(data if f == path else read_npy(f), frame, str(f))
        if row is None:
            continue
        poses.append(row[0])
        transl.append(row[1])
        betas.append(row[2])
        ids.append(str(int(m.group(1))) if (m := _TRACK.search(f.name)) else "0")
    if not ids:
        raise EstimateFormatError(f"{source}: no TRAM track of {path.parent} has frame {frame}.")
    camera, cam, cam_path = _camera(path.parent, source)
    pose, translation, shape = np.stack(poses), np.stack(transl), np.stack(betas)
    kind: base.TranslationKind = "transl"
    if space == "world":
        if cam is None:
            raise EstimateFormatError(f"{source}: --space world needs TRAM's camera.npy (its SLAM trajectory) at "
                                      f"{cam_path}.")
        pelvis = translation + base.estimator_rest_pelvis(shape, Gender.NEUTRAL, "smpl")
        for i in range(len(ids)):
            pose[i], pelvis[i] = _world_pose(pose[i], pelvis[i], cam, frame, str(cam_path))
        translation, kind = pelvis, "pelvis"
    return base.make_people(pose, translation, shape, frame_of_reference="camera", translation_kind=kind,
                            camera=camera if space != "world" else None, person_ids=ids,
                            frames=[str(frame)] * len(ids), source=f"{source} (tram)", max_people=max_people)
