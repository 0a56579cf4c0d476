"""What every estimator reader returns, and the camera-to-world conversion they share.

Image-based estimators give SMPL parameters in the **camera frame** (OpenCV axes: x right,
y down, z forward, the camera at the origin). smplik's world is **y-up** (see
:mod:`smplik.conventions`). The readers turn the camera frame into the world by a rotation of
180 degrees about x, ``M = diag(1, -1, -1)``: the world origin is the camera centre, the camera
looks down -z, and world y is up in the image.

* Root rotation: ``R_world_root = M @ R_camera_root`` (body-relative rotations are unchanged).
* Translation: smplx rotates the root about the rest pelvis ``J0(beta)`` and adds ``transl``
  afterwards, so the posed pelvis is ``J0 + t``. Re-orienting by ``M`` keeps the pelvis where
  ``M`` sends it: ``t' = M (J0 + t) - J0``.
* Some estimators give the **pelvis position** rather than smplx's ``transl`` (their mesh is
  root-aligned before the camera translation is added); the readers document which, and
  ``pelvis_cam = J0 + t`` covers both.

An OpenGL camera at the world origin with identity rotation (x right, y up, looking down -z) is
then exactly the estimator's camera, so previews overlay the source image with
``T_world_camera = I`` (:class:`CameraInfo`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from smplik.conventions import NUM_BETAS, NUM_JOINTS, Gender
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle

M_WORLD_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Rotation taking OpenCV camera axes (x right, y down, z forward) to smplik's y-up world."""

TranslationKind = Literal["transl", "pelvis"]


class EstimateFormatError(ValueError):
    """An estimator output file does not have the layout its reader expects (the message names the key)."""


@dataclass(frozen=True)
class CameraInfo:
    """The estimator's pinhole camera, world frame = camera centre at the origin (see module docstring).

    Attributes:
        focal_px: focal length in pixels, when the file gives it (or implies it with ``image_size``).
        image_size: ``(width, height)`` of the source image, when known.
        default_fov_deg: field of view (over the larger image side) the estimator assumes when no focal
            length is stored; used with the image size to build a camera for overlays.
    """

    focal_px: float | None = None
    image_size: tuple[int, int] | None = None
    default_fov_deg: float = 60.0

    def focal_for(self, width: int, height: int) -> float:
        """Focal length (pixels) for an image of this size: ``focal_px`` rescaled, else from the FOV."""
        if self.focal_px is not None:
            if self.image_size is not None:
                return float(self.focal_px) * max(width, height) / max(self.image_size)
            return float(self.focal_px)
        return max(width, height) / 2.0 / np.tan(np.radians(self.default_fov_deg) / 2.0)

    def to_dict(self) -> dict:
        return {"focal_px": self.focal_px, "image_size": None if self.image_size is None else list(self.image_size),
                "default_fov_deg": self.default_fov_deg}

    @classmethod
    def from_dict(cls, data: dict) -> CameraInfo:
        size = data.get("image_size")
        focal = data.get("focal_px")
        return cls(None if focal is None else float(focal), None if size is None else (int(size[0]), int(size[1])),
                   float(data.get("default_fov_deg", 60.0)))


@dataclass(frozen=True)
class EstimatedPerson:
    """One person from an estimator, in smplik's y-up world (numpy float64).

    Attributes:
        global_orient: (3,) axis-angle root rotation, world frame.
        body_pose: (23, 3) axis-angle local rotations.
        transl: (3,) smplx translation, world frame (pelvis = J0(betas) + transl).
        betas: (10,) shape.
        gender: body model gender.
        camera: the source camera (None when the output is already in a world frame).
        person_id: the estimator's track / detection id.
        frame: frame index or name the person comes from.
        source: file and format, for messages.
    """

    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    betas: np.ndarray
    gender: Gender = Gender.NEUTRAL
    camera: CameraInfo | None = None
    person_id: str = "0"
    frame: str = "0"
    source: str = ""

    def to_pose(self):
        """This person as a :class:`smplik.pose.Pose` (no joints)."""
        from smplik.pose import Pose

        return Pose(self.global_orient.copy(), self.body_pose.copy(), self.transl.copy(), self.betas.copy(),
                    self.gender)


def rest_pelvis(betas: np.ndarray, gender: Gender) -> np.ndarray:
    """J0(betas) of the body model. betas (N, 10) -> (N, 3)."""
    from smplik.body_model import load_body_model

    model = load_body_model(gender)
    return model.rest_joints(torch.as_tensor(betas, dtype=torch.float64).float())[..., 0, :].double().numpy()


def camera_to_world(global_orient_cam: np.ndarray, pelvis_cam: np.ndarray,
                    J0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame root rotation and pelvis -> world root rotation and smplx ``transl``.

    Args: global_orient_cam (N, 3) axis-angle, pelvis_cam (N, 3) posed pelvis, J0 (N, 3) rest pelvis.
    Returns: global_orient_world (N, 3), transl_world (N, 3) with ``transl = M pelvis_cam - J0``.
    """
    R_cam = axis_angle_to_matrix(torch.as_tensor(global_orient_cam, dtype=torch.float64))
    R_world = torch.as_tensor(M_WORLD_CAMERA) @ R_cam
    go = matrix_to_axis_angle(R_world).numpy()
    return go, pelvis_cam @ M_WORLD_CAMERA.T - J0


def _as_float(name: str, value, shape_tail: tuple[int, ...], source: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise EstimateFormatError(f"{source}: '{name}' must be numbers.") from None
    if arr.shape[1:] != shape_tail:
        raise EstimateFormatError(f"{source}: '{name}' has shape {arr.shape}; expected (N, "
                                  f"{', '.join(map(str, shape_tail))}).")
    if not np.isfinite(arr).all():
        raise EstimateFormatError(f"{source}: '{name}' contains NaN or inf.")
    return arr


def rotations_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle (projected to the nearest rotation first)."""
    R = np.asarray(R, dtype=np.float64)
    u, _, vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, -1] *= d[..., None]
    return matrix_to_axis_angle(torch.as_tensor(u @ vt)).numpy()


def make_people(
    pose_aa: np.ndarray,
    translation: np.ndarray,
    betas: np.ndarray,
    *,
    frame_of_reference: Literal["camera", "world"],
    translation_kind: TranslationKind,
    genders: list[Gender] | None = None,
    camera: CameraInfo | None = None,
    person_ids: list[str] | None = None,
    frames: list[str] | None = None,
    source: str = "",
) -> list[EstimatedPerson]:
    """Validate, convert to the y-up world and wrap.

    Args:
        pose_aa: (N, 24, 3) axis-angle (root first), or (N, 72).
        translation: (N, 3) smplx ``transl`` or pelvis position (``translation_kind``).
        betas: (N, >=10); extra components (BEV's age) are dropped.
        frame_of_reference: ``"camera"`` (OpenCV axes, converted) or ``"world"`` (already y-up).
    """
    pose_aa = np.asarray(pose_aa, dtype=np.float64)
    if pose_aa.ndim == 2 and pose_aa.shape[1] == 3 * NUM_JOINTS:
        pose_aa = pose_aa.reshape(-1, NUM_JOINTS, 3)
    pose_aa = _as_float("pose", pose_aa, (NUM_JOINTS, 3), source)
    N = pose_aa.shape[0]
    betas = np.asarray(betas, dtype=np.float64)
    if betas.ndim == 1:
        betas = np.broadcast_to(betas, (N, betas.shape[0]))
    if betas.ndim != 2 or betas.shape[1] < NUM_BETAS:
        raise EstimateFormatError(f"{source}: 'betas' has shape {betas.shape}; expected (N, {NUM_BETAS}).")
    betas = _as_float("betas", betas[:, :NUM_BETAS], (NUM_BETAS,), source)
    translation = _as_float("translation", translation, (3,), source)
    if translation.shape[0] != N or betas.shape[0] != N:
        raise EstimateFormatError(f"{source}: {N} poses but {translation.shape[0]} translations and "
                                  f"{betas.shape[0]} betas.")
    genders = genders or [Gender.NEUTRAL] * N
    J0 = np.stack([rest_pelvis(betas[i:i + 1], genders[i])[0] for i in range(N)]) if N else np.zeros((0, 3))
    pelvis = translation + J0 if translation_kind == "transl" else translation
    if frame_of_reference == "camera":
        go, transl = camera_to_world(pose_aa[:, 0], pelvis, J0)
    else:
        go, transl = pose_aa[:, 0], pelvis - J0
    ids = person_ids or [str(i) for i in range(N)]
    frames = frames or ["0"] * N
    return [EstimatedPerson(go[i], pose_aa[i, 1:].copy(), transl[i], betas[i].copy(), genders[i],
                            camera if frame_of_reference == "camera" else None, ids[i], frames[i], source)
            for i in range(N)]


def require(data: dict, key: str, source: str):
    """``data[key]`` or an :class:`EstimateFormatError` naming the key and the keys present."""
    if not isinstance(data, dict) or key not in data:
        keys = ", ".join(map(str, data)) if isinstance(data, dict) else type(data).__name__
        raise EstimateFormatError(f"{source}: missing key '{key}' (found: {keys}).")
    return data[key]
