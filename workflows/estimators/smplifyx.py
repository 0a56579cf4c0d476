"""SMPLify-X result pickles (github.com/vchoutas/smplify-x, ``smplifyx/fit_single_frame.py``): one person fitted
to one photo, in the fitting camera's frame.

``fit_single_frame`` pickles ``{'camera_' + name: value for camera.named_parameters()}`` plus the body model's
parameters: ``camera_rotation (1, 3, 3)`` (fixed at the identity), ``camera_translation (1, 3)``, ``betas (1, 10)``,
``global_orient (1, 3)``, ``body_pose (1, 63)`` (SMPL-X; ``(1, 69)`` for SMPL; with VPoser the original writes the
32-number pose embedding there, which needs VPoser to decode: refused with that said), hand PCA poses, ``jaw_pose``,
``leye_pose``, ``reye_pose``, ``expression``. The body model is created without ``transl``
(``create_transl=False``): the camera's translation places it. Its ``PerspectiveCamera`` (``smplifyx/camera.py``)
projects a model point X as ``x = f (R X + t)_xy / (R X + t)_z + c`` with ``f`` the config's ``focal_length``
(5000 px by default, ``cfg_files/fit_smplx.yaml``; forks that store ``camera_focal_length_x/_y`` and
``camera_center`` are read with them) and ``c`` the image centre: the model frame is an OpenCV camera frame (y
down), which is why SMPLify-X's renderer turns the mesh 180 degrees about x for OpenGL. So: root rotation
``R @ global_orient``, pelvis ``R J0_est + t`` (``J0_est``: the producer's rest pelvis), camera frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from workflows.estimators import base

FORMAT = "smplifyx"
DEFAULT_FOCAL = 5000.0
"""SMPLify-X's default ``focal_length`` (pixels)."""


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "camera_translation" in data and "global_orient" in data


def from_data(data: Any, *, source: str = "<smplifyx>", frame: int = 0, max_people: int = base.MAX_PEOPLE
              ) -> list[base.EstimatedPerson]:
    import warnings

    from scipy.spatial.transform import Rotation

    from workflows.estimators.pose_array import EstimateNote

    if frame != 0:
        raise base.EstimateFormatError(f"{source}: a SMPLify-X result is one photo; --frame must be 0, got {frame}.")
    go = base.rows(base.require(data, "global_orient", source), "global_orient", 3, source, 1)[0]
    bp = base.finite(base.require(data, "body_pose", source), "body_pose", source).reshape(-1)
    if bp.size == 32:
        raise base.EstimateFormatError(f"{source}: 'body_pose' holds 32 numbers: SMPLify-X's VPoser pose embedding, "
                                       "which needs VPoser to decode; refit with --use_vposer False or save the "
                                       "decoded pose (vposer.decode(pose_embedding, output_type='aa')).")
    if bp.size == 63:
        family, body = "smplx", np.concatenate([bp.reshape(21, 3), np.zeros((2, 3))])
    elif bp.size == 69:
        family, body = "smpl", bp.reshape(23, 3)
    else:
        raise base.EstimateFormatError(f"{source}: 'body_pose' has {bp.size} numbers; expected 63 (SMPL-X) or 69 "
                                       "(SMPL).")
    t = base.rows(data["camera_translation"], "camera_translation", 3, source, 1)[0]
    R = np.eye(3)
    if "camera_rotation" in data:
        R = base.finite(data["camera_rotation"], "camera_rotation", source).reshape(-1, 3, 3)[0]
        with np.errstate(all="ignore"):  # 1e308 entries overflow to inf: not a rotation
            orthogonal = np.abs(R.T @ R - np.eye(3)).max() <= 1e-3
        if not orthogonal:
            raise base.EstimateFormatError(f"{source}: 'camera_rotation' is not a rotation matrix.")
    betas = np.zeros((1, 10))
    b = base.finite(data.get("betas", np.zeros(10)), "betas", source).reshape(-1)
    betas[0, :min(10, b.size)] = b[:10]
    J0 = base.estimator_rest_pelvis(betas, base.Gender.NEUTRAL, family)[0]  # type: ignore[arg-type]
    pelvis = R @ J0 + t
    root = (Rotation.from_matrix(R) * Rotation.from_rotvec(go)).as_rotvec()
    if "camera_focal_length_x" in data:
        fx = base.scalar(data["camera_focal_length_x"], "camera_focal_length_x", source)
        fy = base.scalar(data.get("camera_focal_length_y", fx), "camera_focal_length_y", source)
        focal = (fx + fy) / 2
    else:
        focal = DEFAULT_FOCAL
        warnings.warn(f"{source}: SMPLify-X stores no focal length; its default {DEFAULT_FOCAL:g} px is used, with "
                      "the principal point at the image centre (as fit_single_frame's camera).", EstimateNote,
                      stacklevel=2)
    center = None
    if "camera_center" in data:
        c = base.finite(data["camera_center"], "camera_center", source).reshape(-1)
        if c.size == 2:
            center = (float(c[0]), float(c[1]))
    camera = base.CameraInfo(float(focal), None, principal_px=center, focal_rule="intrinsics")
    pose = np.concatenate([root[None], body])[None]
    return base.make_people(pose, pelvis[None], betas, frame_of_reference="camera", translation_kind="pelvis",
                            body_family=family, camera=camera,  # type: ignore[arg-type]
                            source=f"{source} (smplifyx)", max_people=max_people)
