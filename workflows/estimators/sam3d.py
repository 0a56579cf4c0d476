"""SAM-3D-Body results (MHR skeleton, not SMPL): the SMPL pose is FITTED by the SMPL-IK solver.

Producer: SAM-3D-Body (github.com/facebookresearch/sam-3d-body). ``SAM3DBodyEstimator.process_one_image``
(``sam_3d_body/sam_3d_body_estimator.py``) returns a **list with one dict per detected person**, each
with numpy float32 arrays: ``bbox (4,)``, ``focal_length ()``, ``pred_keypoints_3d (70, 3)``,
``pred_keypoints_2d (70, 2)``, ``pred_vertices (18439, 3)``, ``pred_cam_t (3,)``, ``pred_pose_raw (266,)``,
``global_rot (3,)``, ``body_pose_params (133,)``, ``hand_pose_params (108,)``, ``scale_params (28,)``,
``shape_params (45,)``, ``expr_params (72,)``, ``mask`` (None without a segmentor),
``pred_joint_coords (127, 3)``, ``pred_global_rots (127, 3, 3)``, ``mhr_model_params (204,)``, ``lhand_bbox`` /
``rhand_bbox (4,)`` float64. ``demo.py`` only renders; files are saved by the user: this reader takes that
list (``.pkl`` through the restricted unpickler, ``.pt`` through :func:`smplik.model_io.read_torch_file`, or an
``.npz`` holding it under one key, ``np.savez(path, outputs=outputs)``), one such dict, or one person per
``.npz`` with the dict's keys, the layout of the sample outputs in
github.com/facebookresearch/MHR ``tools/mhr_smpl_conversion/data/sam3d_body_outputs/img_subj0*.npz``
(read by ``tools/mhr_smpl_conversion/example.py::example_sam3d_output_to_smplx`` with ``np.load``;
they have no ``focal_length`` and no ``mask``).

Frame (``sam_3d_body/models/heads/mhr_head.py::MHRHead.forward``): MHR is y-up; the head flips
``jcoords[..., [1, 2]] *= -1`` ("camera system difference") for joints, keypoints and vertices, so
``pred_joint_coords`` are OpenCV camera axes (x right, y down, z forward) relative to the camera
translation: ``joint_cam = pred_joint_coords + pred_cam_t``
(``sam_3d_body/models/heads/camera_head.py::PerspectiveHead.perspective_projection``:
``j3d_cam = points_3d + pred_cam_t``, ``j2d = perspective_projection(j3d_cam, cam_int)``, i.e.
``u = f x / z + cx``, ``v = f y / z + cy``, ``sam_3d_body/models/modules/geometry_utils.py``). Without a
FOV estimator the intrinsics are ``f`` = the image diagonal, principal point the image centre
(``sam_3d_body/data/utils/prepare_batch.py``). ``pred_global_rots`` are NOT flipped (the rig's own
y-up frame, which is our world's axes).

Camera here: ``focal_length`` when stored; ``f, cx, cy`` are otherwise recovered from
``pred_keypoints_2d`` and ``pred_keypoints_3d + pred_cam_t`` (the producer's own projection, least
squares; on the MHR sample files the residual is 1e-4 px), the image size being twice the principal
point; with neither, the producer's default (``focal_rule="diagonal"``).

MHR joints (127, ``pred_joint_coords[0]`` is ``body_world``): names and order of the MHR rig as
listed by the maintainers in sam-3d-body issue #34 (``get_joint_names()`` of the MHR TorchScript
model) and reproduced in public code (a table extracted from ``mhr_model.pt``, e.g.
AmmarkoV/SAM3DBody-cpp ``src/mhr_joint_table.h``); consistent with sam-3d-body's
``sam_3d_body/models/meta_arch/sam3d_body.py`` (lower arms 76 / 40, wrist twists 77 / 41, left /
right) and checked on the MHR sample outputs: joints 2, 18 (``l_upleg``, ``r_upleg``), 3, 19
(``*_lowleg``), 75, 39 (``*_uparm``) and 78, 42 (``*_wrist``) coincide with the named MHR-70 keypoints
(``sam_3d_body/metadata/mhr70.py``) left/right hip, knee, shoulder and wrist to 0.0 cm, ``*_foot``
(4, 20) with the ankles to 1 cm.

Mapping to SMPL (:data:`MHR_FOR_SMPL`): every SMPL joint but ``spine3`` has an MHR counterpart
(``root`` -> pelvis, ``c_spine1/2`` -> spine1/2, ``c_neck``, ``c_head``, ``*_clavicle`` -> collars,
``*_uparm`` -> shoulders, ``*_lowarm`` -> elbows, ``*_wrist``, ``*_middle1`` (knuckle) -> hands,
``*_upleg`` -> hips, ``*_lowleg`` -> knees, ``*_foot`` -> ankles, ``*_ball`` -> feet). MHR's
``c_spine3`` sits at collar height, well above SMPL's spine3, so spine3 gets no target. The 23 targets,
turned into our y-up world like every camera-frame reader (``M = diag(1, -1, -1)``), are **position
effectors** solved by the SMPL-IK model (:class:`smplik.solver.IKSolver`: the shipped one, or the
solver passed in, e.g. the scene command's ``--checkpoint``; one ``solve_batch`` for all people, with its
refinement). **Positions only**: MHR joint frames have
rest orientations of their own (the rig's pre-rotations, stored in the MHR model asset, not in the
output), so ``pred_global_rots`` cannot be related to SMPL's joint frames reliably and are not used.

Shape: ``betas`` stay 0 (the built-in body); the MHR identity (``shape_params``/``scale_params``) is
not converted. Where the person's proportions differ from ours, the refinement spreads the residual
over the joints: on the four MHR sample outputs the fitted joints are 2.1-4.4 cm from their targets
(mean over the 23, max 6.7-8.2 cm at the collars, whose MHR joints sit nearer the neck than SMPL's),
and the pelvis lands about 4 cm above MHR's ``root`` (which sits lower relative to the hips than SMPL's
pelvis). On fixtures built from a pose of our own body the fit is 4 mm (mean over the 24 joints).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from smplik.conventions import JOINT_NAMES, NUM_BETAS, Gender
from workflows.estimators import base

FORMAT = "sam3d"
NUM_MHR_JOINTS = 127

MHR_JOINTS: dict[str, int] = {
    "body_world": 0, "root": 1,
    "l_upleg": 2, "l_lowleg": 3, "l_foot": 4, "l_ball": 8,
    "r_upleg": 18, "r_lowleg": 19, "r_foot": 20, "r_ball": 24,
    "c_spine0": 34, "c_spine1": 35, "c_spine2": 36, "c_spine3": 37,
    "r_clavicle": 38, "r_uparm": 39, "r_lowarm": 40, "r_wrist_twist": 41, "r_wrist": 42, "r_middle1": 52,
    "l_clavicle": 74, "l_uparm": 75, "l_lowarm": 76, "l_wrist_twist": 77, "l_wrist": 78, "l_middle1": 88,
    "c_neck": 110, "c_head": 113,
}
"""Indices into ``pred_joint_coords`` of the MHR joints used here (names as in the MHR rig)."""

MHR_FOR_SMPL: dict[str, str] = {
    "pelvis": "root", "left_hip": "l_upleg", "right_hip": "r_upleg", "spine1": "c_spine1",
    "left_knee": "l_lowleg", "right_knee": "r_lowleg", "spine2": "c_spine2",
    "left_ankle": "l_foot", "right_ankle": "r_foot", "left_foot": "l_ball", "right_foot": "r_ball",
    "neck": "c_neck", "left_collar": "l_clavicle", "right_collar": "r_clavicle", "head": "c_head",
    "left_shoulder": "l_uparm", "right_shoulder": "r_uparm", "left_elbow": "l_lowarm", "right_elbow": "r_lowarm",
    "left_wrist": "l_wrist", "right_wrist": "r_wrist", "left_hand": "l_middle1", "right_hand": "r_middle1",
}
"""SMPL joint -> the MHR joint whose position is its target (SMPL's spine3 has none)."""

SMPL_TARGETS: tuple[str, ...] = tuple(j for j in JOINT_NAMES if j in MHR_FOR_SMPL)
"""The 23 SMPL joints that get a position effector, in SMPL order."""

_MHR_INDEX = np.array([MHR_JOINTS[MHR_FOR_SMPL[j]] for j in SMPL_TARGETS])
_MAX_COORD_M = 20.0  # MHR joints relative to pred_cam_t: a body is ~2 m across
_MAX_CAM_T_M = 900.0  # plus the coordinates, within the effectors' 1 km range (smplik.validation)


def _is_person(item: Any) -> bool:
    return isinstance(item, dict) and "pred_joint_coords" in item and "pred_cam_t" in item


def _unwrap(data: Any) -> Any:
    """The person list of a one-key wrapper (``np.savez(path, outputs=outputs)``: an object array), else ``data``."""
    if isinstance(data, dict) and len(data) == 1 and not _is_person(data):
        inner = next(iter(data.values()))
        if isinstance(inner, np.ndarray) and inner.dtype == object:
            inner = inner.tolist() if inner.ndim else inner.item()
        if isinstance(inner, (list, tuple, dict)):
            return inner
    return data


def matches(data: Any) -> bool:
    data = _unwrap(data)
    if isinstance(data, (list, tuple)):
        return bool(data) and all(_is_person(p) for p in data)
    return _is_person(data)


def smpl_targets_world(joint_coords: np.ndarray, cam_t: np.ndarray) -> np.ndarray:
    """MHR joints (N, 127, 3) relative to ``cam_t`` (N, 3), camera frame -> (N, 23, 3) targets of
    :data:`SMPL_TARGETS` in our y-up world (``M @ (coords + cam_t)``)."""
    return (joint_coords[:, _MHR_INDEX] + cam_t[:, None]) @ base.M_WORLD_CAMERA.T


def intrinsics_from_keypoints(kp3d_cam: np.ndarray, kp2d: np.ndarray) -> tuple[float, float, float, float]:
    """``f, cx, cy`` of ``u = f x/z + cx, v = f y/z + cy`` by least squares, and the max residual (px).

    ``kp3d_cam (K, 3)`` camera-frame points (``pred_keypoints_3d + pred_cam_t``), ``kp2d (K, 2)``.
    """
    z = kp3d_cam[:, 2]
    if kp3d_cam.shape[0] < 3 or (z <= 1e-6).any():
        return float("nan"), float("nan"), float("nan"), float("inf")
    K = kp3d_cam.shape[0]
    A = np.zeros((2 * K, 3))
    A[0::2, 0], A[0::2, 1] = kp3d_cam[:, 0] / z, 1.0
    A[1::2, 0], A[1::2, 2] = kp3d_cam[:, 1] / z, 1.0
    b = kp2d.reshape(-1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return float(sol[0]), float(sol[1]), float(sol[2]), float(np.abs(A @ sol - b).max())


def _camera(person: dict, cam_t: np.ndarray, where: str) -> base.CameraInfo:
    """The producer's camera: ``focal_length``; f, cx, cy from the keypoints; else its default (diagonal)."""
    focal = None
    if person.get("focal_length") is not None:
        focal = base.scalar(person["focal_length"], "focal_length", where)
        if not 0 < focal < 1e7:
            raise base.EstimateFormatError(f"{where}: 'focal_length' {focal} must be positive.")
    kp3d, kp2d = person.get("pred_keypoints_3d"), person.get("pred_keypoints_2d")
    if kp3d is not None and kp2d is not None:
        kp3d = base.finite(kp3d, "pred_keypoints_3d", where)
        kp2d = base.finite(kp2d, "pred_keypoints_2d", where)
        if kp3d.ndim == 2 and kp3d.shape[1] == 3 and kp2d.shape == kp3d.shape[:1] + (2,):
            f, cx, cy, residual = intrinsics_from_keypoints(kp3d + cam_t, kp2d)
            if residual < 1.0 and f > 0 and cx > 0 and cy > 0 and np.isfinite([f, cx, cy]).all():
                size = (int(round(2 * cx)), int(round(2 * cy)))
                return base.CameraInfo(f if focal is None else focal, size, principal_px=(cx, cy))
    if focal is not None:
        return base.CameraInfo(focal)
    return base.CameraInfo(focal_rule="diagonal")


@functools.lru_cache(maxsize=1)
def _solver():
    from smplik.solver import IKSolver

    return IKSolver.load()


def fit_smpl(targets_world: np.ndarray, source: str = "<sam3d>", solver: Any = None):
    """SMPL poses (our body, betas 0) fitted to (N, 23, 3) world targets of :data:`SMPL_TARGETS`.

    One :meth:`smplik.solver.IKSolver.solve_batch` call with 23 position effectors per person, on
    ``solver`` (default: the shipped model, loaded once).
    """
    from smplik.effectors import Effector

    if solver is None:
        try:
            solver = _solver()
        except (FileNotFoundError, ValueError) as exc:
            raise base.EstimateFormatError(f"{source}: fitting SMPL to MHR joints needs the SMPL-IK model "
                                           f"({' '.join(str(exc).split())[:200]}).") from None
    rows = [[Effector.position(j, t[k]) for k, j in enumerate(SMPL_TARGETS)] for t in targets_world]
    return solver.solve_batch(rows, betas=np.zeros((len(rows), NUM_BETAS)), gender=Gender.NEUTRAL)


def _people_list(data: Any, source: str) -> list[dict]:
    people = list(data) if isinstance(data, (list, tuple)) else [data]
    for i, p in enumerate(people):
        if not isinstance(p, dict):
            raise base.EstimateFormatError(f"{source}: person {i} is a {type(p).__name__}; expected a dict of arrays.")
    return people


def from_data(data: Any, *, source: str = "<sam3d>", frame: int = 0, max_people: int = base.MAX_PEOPLE,
              solver: Any = None) -> list[base.EstimatedPerson]:
    """The people of a SAM-3D-Body result, their SMPL poses fitted by ``solver`` (an
    :class:`smplik.solver.IKSolver`; default the shipped model); see the module docstring."""
    if frame != 0:
        raise base.EstimateFormatError(f"{source}: a SAM-3D-Body result is one image and has only frame 0, "
                                       f"got --frame {frame}.")
    data = _unwrap(data)
    people = _people_list(data, source)
    if not people:
        raise base.EstimateFormatError(f"{source}: no people found.")
    base.check_people_count(len(people), max_people, source)
    coords, cam_ts, cameras = [], [], []
    for i, p in enumerate(people):
        where = source if len(people) == 1 and not isinstance(data, (list, tuple)) else f"{source}[{i}]"
        c = base.finite(base.require(p, "pred_joint_coords", where), "pred_joint_coords", where)
        if c.shape != (NUM_MHR_JOINTS, 3):
            raise base.EstimateFormatError(f"{where}: 'pred_joint_coords' has shape {c.shape}; expected "
                                           f"({NUM_MHR_JOINTS}, 3) (the MHR rig's joints).")
        if np.abs(c).max() > _MAX_COORD_M:
            raise base.EstimateFormatError(f"{where}: 'pred_joint_coords' reach {np.abs(c).max():.3g} m from "
                                           f"pred_cam_t; a body is about 2 m across (expected metres).")
        t = base.finite(base.require(p, "pred_cam_t", where), "pred_cam_t", where).reshape(-1)
        if t.shape != (3,):
            raise base.EstimateFormatError(f"{where}: 'pred_cam_t' has {t.shape[0]} numbers; expected 3.")
        if np.abs(t).max() > _MAX_CAM_T_M:
            raise base.EstimateFormatError(f"{where}: 'pred_cam_t' of {np.abs(t).max():.3g} m is outside the physical "
                                           f"range (|t| <= {_MAX_CAM_T_M:g} m).")
        coords.append(c)
        cam_ts.append(t)
        cameras.append(_camera(p, t, where))
    targets = smpl_targets_world(np.stack(coords), np.stack(cam_ts))
    poses = fit_smpl(targets, source, solver)
    label = f"{source} (sam3d)"
    out = []
    for i, pose in enumerate(poses):
        if not (np.isfinite(pose.global_orient).all() and np.isfinite(pose.body_pose).all()
                and np.isfinite(pose.transl).all()):
            raise base.EstimateFormatError(f"{source}: the SMPL fit of person {i} is not finite.")
        out.append(base.EstimatedPerson(pose.global_orient, pose.body_pose, pose.transl, pose.betas, Gender.NEUTRAL,
                                        cameras[i], str(i), "0", label))
    return out
