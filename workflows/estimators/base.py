"""What every estimator reader returns, and the conversion they all share.

Image-based estimators give SMPL (or SMPL-X) parameters in the **camera frame** (OpenCV axes: x
right, y down, z forward, the camera at the origin). smplik's world is **y-up** (see
:mod:`smplik.conventions`). The readers turn the camera frame into the world by a rotation of
180 degrees about x, ``M = diag(1, -1, -1)``: the world origin is the camera centre, the camera
looks down -z, and world y is up in the image.

Placement (one rule for every reader, :func:`make_people`):

1. **The producer's pelvis.** An estimator's translation is relative to the rest pelvis of the
   body model *it* used, ``J0_est(beta, gender)`` (real SMPL or SMPL-X), never ours. smplx
   rotates the root about ``J0`` and adds ``transl`` afterwards, so the posed pelvis is
   ``pelvis = J0_est + transl`` (``translation_kind="transl"``); producers that root-align the
   mesh before adding their translation give the pelvis itself (``"pelvis"``). Each reader's
   docstring says which, from the producer's code.
2. **Our body there.** Root rotation ``R_world_root = M @ R_camera_root`` (body-relative rotations
   are unchanged) and our smplx ``transl = M @ pelvis - J0_ours(beta, gender)``, so the built-in
   (or configured) body's posed pelvis sits exactly at the producer's pelvis. World-frame outputs
   (WHAM world, GVHMR global, AIST++, AMASS) skip ``M`` but use the same two steps.

``J0_est``: from the configured real SMPL files (``--model-dir`` / ``$SMPLIK_MODEL_DIR``) when
present; otherwise the published rest pelvis of the SMPL neutral template at beta = 0
(:data:`SMPL_NEUTRAL_REST_JOINTS`), and SMPL-X's for SMPL-X producers
(:data:`SMPLX_NEUTRAL_REST_PELVIS`). Neglected without real files: the beta and gender
dependence of ``J0_est`` (a linear term ``J_dirs[0] @ beta``; on the built-in body, whose shape
directions mimic SMPL's, ``|beta| <= 2`` moves the rest pelvis by up to
:data:`J0_BETA_EFFECT_M` metres, which is the size of the error to expect for unusual shapes),
and the male/female templates (the neutral one is used for every gender). For SMPL-X producers the user's
``SMPLX_NEUTRAL.npz`` (``$SMPLIK_SMPLX_MODEL`` or the model folder) gives ``J0_est(beta)`` exactly and our
body the betas whose skeleton matches SMPL-X's (:mod:`workflows.estimators.smplx_shape`): SMPL-X betas
read as our betas are another body (against GVHMR's own render, a head up to 7 % of the body's image
height low).

An OpenGL camera at the world origin with identity rotation (x right, y up, looking down -z) is
then exactly the estimator's camera, so previews overlay the source image with
``T_world_camera = I`` and the estimator's intrinsics (:class:`CameraInfo`).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch

from smplik.conventions import NUM_BETAS, NUM_JOINTS, PARENTS, Gender
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from workflows.estimators.errors import EstimateFormatError

M_WORLD_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Rotation taking OpenCV camera axes (x right, y down, z forward) to smplik's y-up world."""

TranslationKind = Literal["transl", "pelvis"]
BodyFamily = Literal["smpl", "smplx"]
"""The body model a producer used: SMPL (also SMPL-H, whose body template is SMPL's) or SMPL-X."""

MAX_PEOPLE = 100
"""Default cap on the people read from one frame (``max_people`` / CLI ``--max-people`` raise it)."""

# SMPL neutral template (basicModel_neutral_lbs_10_207_0_v1.0.0), rest joints J_regressor @ v_template
# at beta = 0, y-up metres, for the 22 joints pelvis..right_wrist as parent-relative offsets (pelvis
# absolute). These are the published values reproduced in many public repositories (e.g. as
# SMPL_BONE_OFFSETS_22 / J_ABSOLUTE_TPOSE tables in motion-retargeting and VR-pose code found by the
# code search); the pelvis matches the value quoted in DESIGN.md section 10 and issue 12,
# (-0.0018, -0.2233, 0.0282). SMPL-H's body template gives the same 22 joints.
_SMPL_NEUTRAL_OFFSETS_22 = np.array([
    [-0.001795, -0.223333, 0.028219], [0.069520, -0.091406, -0.006815], [-0.067670, -0.090522, -0.004320],
    [-0.002533, 0.108963, -0.026696], [0.034277, -0.375199, -0.004496], [-0.038290, -0.382569, -0.008850],
    [0.005487, 0.135180, 0.001092], [-0.013596, -0.397960, -0.043693], [0.015774, -0.398415, -0.042312],
    [0.001457, 0.052922, 0.025425], [0.026358, -0.055791, 0.119288], [-0.025372, -0.048144, 0.123348],
    [-0.002778, 0.213870, -0.042857], [0.078845, 0.121749, -0.034090], [-0.081759, 0.118833, -0.038615],
    [0.005152, 0.064970, 0.051349], [0.090977, 0.030469, -0.008868], [-0.096012, 0.032551, -0.009143],
    [0.259612, -0.012772, -0.027456], [-0.253742, -0.013329, -0.021401], [0.249234, 0.008986, -0.001171],
    [-0.255298, 0.007772, -0.005559],
])


def _absolute(offsets: np.ndarray) -> np.ndarray:
    out = np.zeros_like(offsets)
    for j in range(offsets.shape[0]):
        out[j] = offsets[j] if PARENTS[j] < 0 else out[PARENTS[j]] + offsets[j]
    return out


SMPL_NEUTRAL_REST_JOINTS = _absolute(_SMPL_NEUTRAL_OFFSETS_22)
"""(22, 3) published rest joints of the SMPL neutral template at beta = 0 (pelvis .. right_wrist)."""

SMPLX_NEUTRAL_REST_PELVIS = np.array([0.00312326, -0.35140744, 0.01203655])
"""Rest pelvis of the SMPL-X neutral model (SMPLX_NEUTRAL.npz, J_regressor @ v_template, beta = 0), as
reproduced in public code (e.g. a ``rest_pelvis`` constant of an SMPL-X IMU data loader); GVHMR's
``transl`` is relative to it."""

J0_BETA_EFFECT_M = 0.03
"""Order of magnitude (metres) of the rest pelvis' beta dependence neglected without real SMPL files."""


@dataclass(frozen=True)
class CameraInfo:
    """The estimator's pinhole camera, world frame = camera centre at the origin (see module docstring).

    Attributes:
        focal_px: focal length in pixels, when the file gives it (or implies it with ``image_size``).
        image_size: ``(width, height)`` of the source image, when known.
        default_fov_deg: field of view (over the larger image side) the estimator assumes when no focal
            length is stored; used with the image size to build a camera for overlays.
        principal_px: ``(cx, cy)`` principal point in pixels of ``image_size`` (None: the image centre).
        focal_rule: where the focal length comes from. Without ``focal_px``: ``"fov"`` (from
            ``default_fov_deg``) or ``"diagonal"`` (focal = the image diagonal in pixels, WHAM's default
            camera). With it: ``"intrinsics"`` (the file's intrinsics matrix, :meth:`from_K`) or ``"given"``
            (the user's ``--focal``, in pixels of the ``--image``).
    """

    focal_px: float | None = None
    image_size: tuple[int, int] | None = None
    default_fov_deg: float = 60.0
    principal_px: tuple[float, float] | None = None
    focal_rule: Literal["fov", "diagonal", "intrinsics", "given"] = "fov"

    def __post_init__(self) -> None:
        if self.focal_px is not None and not (math.isfinite(self.focal_px) and self.focal_px > 0):
            raise EstimateFormatError(f"camera focal length must be a positive finite number, got {self.focal_px}.")
        if self.image_size is not None and not (len(self.image_size) == 2 and all(
                isinstance(v, int) and 0 < v < 1_000_000 for v in self.image_size)):
            raise EstimateFormatError(f"camera image size must be two positive integers, got {self.image_size}.")
        if not (math.isfinite(self.default_fov_deg) and 0 < self.default_fov_deg < 180):
            raise EstimateFormatError(f"camera field of view must be in (0, 180) degrees, got {self.default_fov_deg}.")
        if self.principal_px is not None and not (len(self.principal_px) == 2 and all(
                math.isfinite(v) for v in self.principal_px)):
            raise EstimateFormatError(f"camera principal point must be two finite numbers, got {self.principal_px}.")
        if self.focal_rule not in ("fov", "diagonal", "intrinsics", "given"):
            raise EstimateFormatError(f"camera focal_rule must be 'fov', 'diagonal', 'intrinsics' or 'given', "
                                      f"got {self.focal_rule!r}.")

    @classmethod
    def from_K(cls, K: Any, image_size: tuple[int, int] | None, source: str) -> CameraInfo:
        """A camera from a 3x3 intrinsics matrix (mean of ``fx, fy``; without ``image_size`` the intrinsics are
        used as they are, for an image of the size the estimator saw)."""
        K = finite(K, "K", source)
        if K.shape != (3, 3):
            raise EstimateFormatError(f"{source}: 'K' has shape {K.shape}; expected (3, 3).")
        fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
        if not (fx > 0 and fy > 0):
            raise EstimateFormatError(f"{source}: 'K' has a non-positive focal length ({fx}, {fy}).")
        return cls((fx + fy) / 2.0, image_size, principal_px=(cx, cy), focal_rule="intrinsics")

    def focal_for(self, width: int, height: int) -> float:
        """Focal length (pixels) for an image of this size: ``focal_px`` rescaled, else from the rule."""
        if self.focal_px is not None:
            if self.image_size is not None:
                return float(self.focal_px) * max(width, height) / max(self.image_size)
            return float(self.focal_px)
        if self.focal_rule == "diagonal":
            return float(math.hypot(width, height))
        return max(width, height) / 2.0 / np.tan(np.radians(self.default_fov_deg) / 2.0)

    def principal_for(self, width: int, height: int) -> tuple[float, float]:
        """Principal point (pixels) for an image of this size: ``principal_px`` rescaled, else the centre."""
        if self.principal_px is not None:
            s = 1.0 if self.image_size is None else max(width, height) / max(self.image_size)
            return self.principal_px[0] * s, self.principal_px[1] * s
        return width / 2.0, height / 2.0

    def to_dict(self) -> dict:
        return {"focal_px": self.focal_px, "image_size": None if self.image_size is None else list(self.image_size),
                "default_fov_deg": self.default_fov_deg,
                "principal_px": None if self.principal_px is None else [float(v) for v in self.principal_px],
                "focal_rule": self.focal_rule}

    @classmethod
    def from_dict(cls, data: dict) -> CameraInfo:
        allowed = {"focal_px", "image_size", "default_fov_deg", "principal_px", "focal_rule"}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise EstimateFormatError(f"unknown camera key(s) {unknown}; allowed: {sorted(allowed)}.")
        size = data.get("image_size")
        focal = data.get("focal_px")
        pp = data.get("principal_px")
        return cls(None if focal is None else float(focal), None if size is None else (int(size[0]), int(size[1])),
                   float(data.get("default_fov_deg", 60.0)), None if pp is None else (float(pp[0]), float(pp[1])),
                   str(data.get("focal_rule", "fov")))  # type: ignore[arg-type]


@dataclass(frozen=True)
class EstimatedPerson:
    """One person from an estimator, in smplik's y-up world (numpy float64), placed on OUR body model.

    Attributes:
        global_orient: (3,) axis-angle root rotation, world frame.
        body_pose: (23, 3) axis-angle local rotations.
        transl: (3,) smplx translation for our body model, world frame (pelvis = J0_ours(betas) + transl).
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
    """J0(betas) of OUR body model (configured SMPL files or the built-in body). betas (N, 10) -> (N, 3)."""
    from smplik.body_model import load_body_model

    model = load_body_model(gender)
    return model.rest_joints(torch.as_tensor(betas, dtype=torch.float64).float())[..., 0, :].double().numpy()


def estimator_rest_pelvis(betas: np.ndarray, gender: Gender, family: BodyFamily = "smpl") -> np.ndarray:
    """J0_est: the rest pelvis of the body model the PRODUCER used (see the module docstring). (N, 10) -> (N, 3).

    SMPL: the configured real SMPL files when present, else :data:`SMPL_NEUTRAL_REST_JOINTS` ``[0]``;
    SMPL-X: from the user's ``SMPLX_NEUTRAL.npz`` in the model folder when present
    (:mod:`workflows.estimators.smplx_shape`), else :data:`SMPLX_NEUTRAL_REST_PELVIS`.
    """
    betas = np.asarray(betas, dtype=np.float64).reshape(-1, NUM_BETAS)
    if family == "smpl":
        from smplik.body_model import resolve_model_dir

        if resolve_model_dir(None) is not None:
            return rest_pelvis(betas, gender)
        return np.broadcast_to(SMPL_NEUTRAL_REST_JOINTS[0], betas.shape[:1] + (3,)).copy()
    from workflows.estimators.smplx_shape import smplx_model_path, smplx_rest_joints

    path = smplx_model_path()
    if path is not None:
        return smplx_rest_joints(betas, path)[:, 0]
    return np.broadcast_to(SMPLX_NEUTRAL_REST_PELVIS, betas.shape[:1] + (3,)).copy()


def camera_to_world(global_orient_cam: np.ndarray, pelvis_cam: np.ndarray,
                    J0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame root rotation and pelvis -> world root rotation and smplx ``transl`` of our body.

    Args: global_orient_cam (N, 3) axis-angle, pelvis_cam (N, 3) posed pelvis, J0 (N, 3) OUR rest pelvis.
    Returns: global_orient_world (N, 3), transl_world (N, 3) with ``transl = M pelvis_cam - J0``.
    """
    R_cam = axis_angle_to_matrix(torch.as_tensor(global_orient_cam, dtype=torch.float64))
    R_world = torch.as_tensor(M_WORLD_CAMERA) @ R_cam
    go = matrix_to_axis_angle(R_world).numpy()
    return go, pelvis_cam @ M_WORLD_CAMERA.T - J0


_FINITE_CACHE: dict[int, tuple[Any, np.ndarray]] | None = None


@contextlib.contextmanager
def reading_frames() -> Iterator[None]:
    """While active, :func:`finite` converts and checks each array once: reading a clip frame by frame calls a
    reader with the whole file per frame, and converting every array again made that quadratic in the frames
    (100,000 AIST++ frames: 0.1 s a frame). Arrays are keyed by identity and kept alive until the end."""
    global _FINITE_CACHE
    previous, _FINITE_CACHE = _FINITE_CACHE, {}
    try:
        yield
    finally:
        _FINITE_CACHE = previous


def finite(value: Any, name: str, source: str) -> np.ndarray:
    """``value`` as a finite float64 array, or an :class:`EstimateFormatError` naming ``name``."""
    cache = _FINITE_CACHE
    if cache is not None and isinstance(value, np.ndarray):
        hit = cache.get(id(value))
        if hit is not None and hit[0] is value:
            return hit[1]
        arr = _finite(value, name, source)  # shared by every frame (as a float64 input always was)
        cache[id(value)] = (value, arr)
        return arr
    return _finite(value, name, source)


def _finite(value: Any, name: str, source: str) -> np.ndarray:
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise EstimateFormatError(f"{source}: '{name}' must be numbers, got {type(value).__name__}.")
    try:
        with np.errstate(all="ignore"):
            arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise EstimateFormatError(f"{source}: '{name}' must be numbers.") from None
    if not np.isfinite(arr).all():
        raise EstimateFormatError(f"{source}: '{name}' contains NaN or inf.")
    return arr


def rows(value: Any, name: str, width: int | tuple[int, ...], source: str, count: int | None = None) -> np.ndarray:
    """``value`` as finite (N, width) rows (a single row of ``width`` numbers is (1, width))."""
    widths = (width,) if isinstance(width, int) else width
    arr = finite(value, name, source)
    if arr.ndim == 1 and arr.shape[0] in widths:
        arr = arr[None]
    if arr.ndim > 2 and arr.shape[0] > 0:
        arr = arr.reshape(arr.shape[0], -1)
    if arr.ndim != 2 or arr.shape[1] not in widths:
        raise EstimateFormatError(f"{source}: '{name}' has shape {arr.shape}; expected (N, "
                                  f"{' or '.join(map(str, widths))}).")
    if count is not None and arr.shape[0] != count:
        raise EstimateFormatError(f"{source}: '{name}' has {arr.shape[0]} rows; expected {count}.")
    return arr


def _as_float(name: str, value, shape_tail: tuple[int, ...], source: str) -> np.ndarray:
    arr = finite(value, name, source)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise EstimateFormatError(f"{source}: '{name}' has shape {arr.shape}; expected (N, "
                                  f"{', '.join(map(str, shape_tail))}).")
    return arr


MAX_ROTATION_ENTRY = 2.0
"""A rotation matrix's entries lie in [-1, 1]; an estimator's (float32, not quite orthonormal) within this."""
ROTATION_SINGULAR_RANGE = (0.5, 1.5)
"""Singular values a stored rotation matrix may have (1 for a rotation): a zero, rank-deficient or scaled
matrix is not a rotation, and projecting it to the "nearest" one would invent a pose."""


def rotations_to_axis_angle(R: np.ndarray, name: str = "rotation matrices", where: str = "") -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle (projected to the nearest rotation first).

    Raises :class:`EstimateFormatError` naming ``where`` (the file) and ``name`` (its key) on a non-finite
    matrix, an entry beyond :data:`MAX_ROTATION_ENTRY` (checked before the SVD, which numpy may fail to
    converge on) or singular values outside :data:`ROTATION_SINGULAR_RANGE`.
    """
    R = np.asarray(R, dtype=np.float64)
    what = f"{where}: '{name}'" if where else name
    if not np.isfinite(R).all():
        raise EstimateFormatError(f"{what} contain NaN or inf.")
    flat = R.reshape(-1, 3, 3)
    big = np.abs(flat).max(axis=(1, 2), initial=0.0)
    if (big > MAX_ROTATION_ENTRY).any():
        k = int(np.argmax(big > MAX_ROTATION_ENTRY))
        raise EstimateFormatError(f"{what}: matrix {k} is not a rotation (an entry of {float(big[k]):.3g}; "
                                  f"rotation entries lie in [-1, 1]).")
    u, sv, vt = np.linalg.svd(R)
    lo, hi = ROTATION_SINGULAR_RANGE
    bad = ((sv < lo) | (sv > hi)).reshape(-1, 3).any(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise EstimateFormatError(f"{what}: matrix {k} is not a rotation (singular values "
                                  f"{np.round(sv.reshape(-1, 3)[k], 3).tolist()}; a rotation's are 1).")
    d = np.sign(np.linalg.det(u @ vt))
    d[d == 0] = 1.0
    u[..., :, -1] *= d[..., None]
    return matrix_to_axis_angle(torch.as_tensor(u @ vt)).numpy()


def frame_numbers(value: Any, name: str, source: str) -> np.ndarray:
    """Video frame numbers (N,) int64: finite, whole and within +-1e9, or an error naming ``name``."""
    arr = finite(value, name, source).reshape(-1)
    if arr.size and (np.abs(arr).max() > 1e9 or not np.array_equal(arr, np.round(arr))):
        raise EstimateFormatError(f"{source}: '{name}' must hold whole frame numbers.")
    return arr.astype(np.int64)


def check_people_count(n: int, max_people: int, source: str) -> None:
    """Refuse more than ``max_people`` people in one frame (a clear error with the option to raise it)."""
    if n > max_people:
        raise EstimateFormatError(f"{source}: {n} people in one frame exceeds the cap of {max_people}; pass "
                                  f"--max-people {n} (max_people={n}) if the file is right.")


def make_people(
    pose_aa: np.ndarray,
    translation: np.ndarray,
    betas: np.ndarray,
    *,
    frame_of_reference: Literal["camera", "world"],
    translation_kind: TranslationKind,
    body_family: BodyFamily = "smpl",
    genders: list[Gender] | None = None,
    camera: CameraInfo | None = None,
    person_ids: list[str] | None = None,
    frames: list[str] | None = None,
    source: str = "",
    max_people: int = MAX_PEOPLE,
) -> list[EstimatedPerson]:
    """Validate, place on our body in the y-up world (module docstring) and wrap.

    Args:
        pose_aa: (N, 24, 3) axis-angle (root first), or (N, 72).
        translation: (N, 3) the producer's smplx ``transl`` or its pelvis position (``translation_kind``).
        betas: (N, >=10); extra components (BEV's age, SMPL-X's 11..) are dropped; (N, <10) is zero-padded.
        frame_of_reference: ``"camera"`` (OpenCV axes, converted) or ``"world"`` (already y-up).
        body_family: the producer's body model, for its rest pelvis ``J0_est``.
    """
    pose_aa = finite(pose_aa, "pose", source)
    if pose_aa.ndim == 2 and pose_aa.shape[1] == 3 * NUM_JOINTS:
        pose_aa = pose_aa.reshape(-1, NUM_JOINTS, 3)
    pose_aa = _as_float("pose", pose_aa, (NUM_JOINTS, 3), source)
    if pose_aa.size and np.abs(pose_aa).max() > 1e3:
        raise EstimateFormatError(f"{source}: pose angles up to {np.abs(pose_aa).max():.3g} rad are not rotations "
                                  "(expected axis-angle within a few pi).")
    N = pose_aa.shape[0]
    if N == 0:
        raise EstimateFormatError(f"{source}: no people found.")
    check_people_count(N, max_people, source)
    betas = finite(betas, "betas", source)
    if betas.ndim == 1:
        betas = np.broadcast_to(betas, (N, betas.shape[0]))
    if betas.ndim != 2 or betas.shape[1] < 1:
        raise EstimateFormatError(f"{source}: 'betas' has shape {betas.shape}; expected (N, {NUM_BETAS}).")
    if betas.shape[1] < NUM_BETAS:
        betas = np.concatenate([betas, np.zeros((betas.shape[0], NUM_BETAS - betas.shape[1]))], axis=1)
    betas = np.ascontiguousarray(betas[:, :NUM_BETAS])
    if np.abs(betas).max() > 100:
        raise EstimateFormatError(f"{source}: 'betas' has values up to {np.abs(betas).max():.3g}; SMPL shapes lie "
                                  "within about +-5.")
    translation = _as_float("translation", translation, (3,), source)
    if translation.shape[0] != N or betas.shape[0] != N:
        raise EstimateFormatError(f"{source}: {N} poses but {translation.shape[0]} translations and "
                                  f"{betas.shape[0]} betas.")
    if np.abs(translation).max() > 1000:
        raise EstimateFormatError(f"{source}: translation of {np.abs(translation).max():.3g} m is outside the "
                                  "physical range (|t| <= 1 km).")
    genders = genders or [Gender.NEUTRAL] * N
    J0_est = np.concatenate([estimator_rest_pelvis(betas[i:i + 1], genders[i], body_family) for i in range(N)])
    if body_family == "smplx":  # SMPL-X betas are another body: our closest one, when the SMPL-X file is there
        from workflows.estimators.smplx_shape import fit_our_betas, smplx_model_path

        smplx_path = smplx_model_path()
        if smplx_path is not None:
            betas = np.concatenate([fit_our_betas(betas[i:i + 1], genders[i], smplx_path) for i in range(N)])
    J0_ours = np.concatenate([rest_pelvis(betas[i:i + 1], genders[i]) for i in range(N)])
    pelvis = translation + J0_est if translation_kind == "transl" else translation
    if frame_of_reference == "camera":
        go, transl = camera_to_world(pose_aa[:, 0], pelvis, J0_ours)
    else:
        go, transl = pose_aa[:, 0], pelvis - J0_ours
    if not (np.isfinite(go).all() and np.isfinite(transl).all()):
        raise EstimateFormatError(f"{source}: the root rotation or translation is not finite after conversion.")
    ids = person_ids or [str(i) for i in range(N)]
    frames = frames or ["0"] * N
    return [EstimatedPerson(go[i], pose_aa[i, 1:].copy(), transl[i], betas[i].copy(), genders[i],
                            camera if frame_of_reference == "camera" else None, ids[i], frames[i], source)
            for i in range(N)]


PERSON_BOUNDS = {"global_orient": ((3,), 1e3), "body_pose": ((23, 3), 1e3), "transl": ((3,), 1e5),
                 "betas": ((NUM_BETAS,), 1e3)}
"""Shape and largest magnitude (radians, metres, shape units) of each array of an :class:`EstimatedPerson`."""


def check_people(people: list[EstimatedPerson], source: str) -> None:
    """The generic value check every reader's output passes (:func:`workflows.estimators.people_from_data`):
    each array of each person has its shape and holds finite numbers within :data:`PERSON_BOUNDS`, whatever
    the reader converted (non-finite values, wrong ndim, absurd magnitudes become one error naming the key)."""
    for person in people:
        who = f"{source}: person {person.person_id!r} (frame {person.frame})"
        for key, (shape, bound) in PERSON_BOUNDS.items():
            arr = np.asarray(getattr(person, key))
            if arr.shape != shape or arr.dtype.kind not in "fiu":
                raise EstimateFormatError(f"{who}: '{key}' has shape {arr.shape}; expected {shape}.")
            if not (np.isfinite(arr).all() and np.abs(arr).max() <= bound):
                raise EstimateFormatError(f"{who}: '{key}' holds non-finite values or values beyond ±{bound:g}.")


def require(data: Any, key: str, source: str):
    """``data[key]`` or an :class:`EstimateFormatError` naming the key and the keys present."""
    if not isinstance(data, dict) or key not in data:
        keys = ", ".join(map(str, list(data)[:20])) if isinstance(data, dict) else type(data).__name__
        raise EstimateFormatError(f"{source}: missing key '{key}' (found: {keys}).")
    return data[key]


def scalar(value: Any, name: str, source: str) -> float:
    """One finite number (first element of an array), or an error naming ``name``."""
    arr = finite(value, name, source).reshape(-1)
    if arr.size < 1:
        raise EstimateFormatError(f"{source}: '{name}' is empty.")
    return float(arr[0])


def image_size_from(width: Any, height: Any, source: str) -> tuple[int, int]:
    """``(width, height)`` as positive integers, or an error."""
    w, h = scalar(width, "width", source), scalar(height, "height", source)
    if not (0 < w < 1e6 and 0 < h < 1e6):
        raise EstimateFormatError(f"{source}: image size ({w}, {h}) must be positive.")
    return int(round(w)), int(round(h))
