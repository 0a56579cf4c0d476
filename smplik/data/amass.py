"""AMASS ``.npz`` pose sequences -> SMPL poses in our y-up world.

Layouts read (detected from the keys, never from the file name):

* **SMPL-H** (AMASS's original release): ``poses (T, 156)`` = root (3) + 21 body joints (63) +
  2 x 15 finger joints (90); ``trans (T, 3)``; ``betas (16,)``; ``gender``; ``mocap_framerate``.
* **SMPL-X** (AMASS "SMPL-X N/G"): ``poses (T, 165)`` = root + 21 body + jaw + 2 eyes + 2 x 15
  fingers, or the split keys ``root_orient (T, 3)`` / ``pose_body (T, 63)`` (preferred when
  present); ``trans``; ``betas``; ``gender``; ``mocap_frame_rate``.
* **plain SMPL**: ``poses (T, 72)`` = root + the 23 SMPL joints; ``trans``; optional ``betas``,
  ``gender``; the frame rate from ``mocap_framerate``, ``mocap_frame_rate`` or ``fps``.

What is kept:

* The root and SMPL's 21 body joints (``left_hip`` .. ``right_wrist``) are the same joints in
  SMPL, SMPL-H and SMPL-X. SMPL's two hand joints (``left_hand``, ``right_hand``, the knuckle
  joints of SMPL's rigid hands) have no single counterpart among the 15 finger joints of
  SMPL-H/X, so they are set to **zero rotation** (a flat hand) for those layouts. Plain SMPL
  files keep all 23 body joints.
* The first 10 betas. SMPL-H/X betas live in a different shape space than SMPL's; taking the
  first 10 is an approximation (the sampler adds unit noise to them anyway).

Frames: AMASS is z-up; our world is y-up (:mod:`smplik.conventions`). The world is rotated by
-90 degrees about x, ``R = R_x(-90 deg)``, which maps ``(x, y, z) -> (x, z, -y)``:
``global_orient' = R @ global_orient`` and, because smplx rotates the root about the rest
pelvis ``J0(beta)`` and adds ``transl`` afterwards, ``transl' = R (J0 + transl) - J0``
(:func:`z_up_to_y_up`). ``J0`` belongs to the body model the poses will be replayed on; pass it
as ``rest_pelvis`` (an array, or a callable of ``(betas, gender)``). Without it ``J0 = 0`` is
assumed, which keeps the pose and the motion exact but shifts every frame of the sequence by
the same constant ``(R - I) J0`` (harmless for translation-invariant training, wrong for
absolute placement).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smplik.conventions import NUM_BETAS, NUM_JOINTS, Gender
from smplik.validation import check_betas

__all__ = ["PoseSequence", "read_amass", "z_up_to_y_up", "R_YUP_ZUP", "RestPelvis"]

R_YUP_ZUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""``R_x(-90 deg)``: maps AMASS's z-up world coordinates to our y-up ones, ``(x, y, z) -> (x, z, -y)``."""

RestPelvis = np.ndarray | Callable[[np.ndarray | None, Gender | None], np.ndarray] | None
"""A rest pelvis ``J0 (3,)``, or a callable ``(betas (10,) | None, gender | None) -> J0 (3,)``, or None (zero)."""

_NUM_BODY = 21  # SMPL body joints shared with SMPL-H/X (left_hip .. right_wrist)
_FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps")


def _rate(value: object, path: object, key: str) -> float:
    """A frame rate within :data:`smplik.limits.MIN_FPS` .. ``MAX_FPS``, else :func:`_fail` naming the key."""
    from smplik.limits import LimitError, check_rate

    try:
        return check_rate(value, f"key '{key}'")
    except LimitError as exc:
        raise _fail(path, str(exc)) from None


@dataclass(frozen=True)
class PoseSequence:
    """A clip of SMPL poses in our y-up world (numpy, float32), from any reader.

    Attributes:
        global_orient: (T, 3) axis-angle root rotation.
        body_pose: (T, 23, 3) axis-angle local rotations of joints 1..23.
        transl: (T, 3) smplx translation (the pelvis is at ``J0(beta) + transl``), metres.
        betas: (10,) shape of the recorded subject, or None when the source has none (BVH).
        gender: the recorded subject's gender, or None when unknown.
        fps: frames per second.
        source: where the clip came from (a path), for messages.
    """

    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    betas: np.ndarray | None
    gender: Gender | None
    fps: float
    source: str

    def __post_init__(self) -> None:
        T = self.global_orient.shape[0]
        if self.global_orient.shape != (T, 3):
            raise ValueError(f"{self.source}: global_orient has shape {self.global_orient.shape}; expected (T, 3).")
        if self.body_pose.shape != (T, NUM_JOINTS - 1, 3):
            raise ValueError(f"{self.source}: body_pose has shape {self.body_pose.shape}; expected ({T}, 23, 3).")
        if self.transl.shape != (T, 3):
            raise ValueError(f"{self.source}: transl has shape {self.transl.shape}; expected ({T}, 3).")
        if self.betas is not None:
            check_betas(self.betas, where=f"{self.source}: betas")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"{self.source}: invalid frame rate {self.fps}.")

    @property
    def num_frames(self) -> int:
        return int(self.global_orient.shape[0])

    @property
    def pose(self) -> np.ndarray:
        """(T, 24, 3) axis-angle local rotations, root first."""
        return np.concatenate([self.global_orient[:, None], self.body_pose], axis=1)


def z_up_to_y_up(global_orient: np.ndarray, transl: np.ndarray, rest_pelvis: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Re-express a z-up SMPL root in our y-up world (rotate the world by ``R_x(-90 deg)``).

    Args:
        global_orient: (T, 3) axis-angle root rotation in the z-up world.
        transl: (T, 3) smplx translation in the z-up world.
        rest_pelvis: (3,) rest pelvis ``J0(beta)`` of the body model (default zero).

    Returns:
        ``(global_orient' (T, 3), transl' (T, 3))`` with ``R' = R_x(-90) R`` and
        ``t' = R_x(-90) (J0 + t) - J0`` (float64).
    """
    from scipy.spatial.transform import Rotation

    J0 = np.zeros(3) if rest_pelvis is None else np.asarray(rest_pelvis, dtype=np.float64).reshape(3)
    R_root = Rotation.from_rotvec(np.asarray(global_orient, dtype=np.float64)).as_matrix()
    go = Rotation.from_matrix(R_YUP_ZUP @ R_root).as_rotvec()
    t = (np.asarray(transl, dtype=np.float64) + J0) @ R_YUP_ZUP.T - J0
    return go, t


def _fail(path: Path, message: str) -> ValueError:
    return ValueError(f"{path}: {message}")


def _array(npz: np.lib.npyio.NpzFile, key: str, path: Path) -> np.ndarray:
    try:
        value = npz[key]
    except ValueError as exc:  # object arrays need pickle, which we refuse
        raise _fail(path, f"key '{key}' cannot be read without pickle ({exc}).") from None
    if value.dtype.kind not in "fiub" and key != "gender":
        raise _fail(path, f"key '{key}' has dtype {value.dtype}; expected numbers.")
    return value


def _finite(value: np.ndarray, key: str, path: Path) -> np.ndarray:
    value = np.asarray(value, dtype=np.float64)
    if not np.isfinite(value).all():
        bad = int((~np.isfinite(value)).any(axis=tuple(range(1, value.ndim))).sum()) if value.ndim > 1 else -1
        where = f" in {bad} frame(s)" if bad >= 0 else ""
        raise _fail(path, f"key '{key}' contains NaN or infinite values{where}.")
    return value


def _frames(value: np.ndarray, key: str, width: int | tuple[int, ...], path: Path) -> np.ndarray:
    widths = (width,) if isinstance(width, int) else width
    if value.ndim != 2 or value.shape[1] not in widths:
        expected = " or ".join(f"(T, {w})" for w in widths)
        raise _fail(path, f"key '{key}' has shape {value.shape}; expected {expected}.")
    if value.shape[0] == 0:
        raise _fail(path, f"key '{key}' has no frames.")
    return _finite(value, key, path)


def _gender(value: np.ndarray, path: Path) -> Gender:
    raw = value.item() if value.ndim == 0 else (value.reshape(-1)[0] if value.size == 1 else None)
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    if not isinstance(raw, str):
        raise _fail(path, f"key 'gender' has value {value!r}; expected a string.")
    try:
        return Gender.parse(raw)
    except ValueError as exc:
        raise _fail(path, f"key 'gender': {exc}") from None


def read_amass(path: str | Path, *, rest_pelvis: RestPelvis = None, fps: float | None = None) -> PoseSequence:
    """Read an AMASS-style ``.npz`` (SMPL-H, SMPL-X or plain SMPL) into y-up SMPL poses.

    Args:
        path: the ``.npz`` file (read with ``allow_pickle=False``).
        rest_pelvis: the rest pelvis ``J0 (3,)`` of the body model the poses will be replayed
            on, or a callable ``(betas (10,) | None, gender | None) -> J0 (3,)`` called with the
            file's values; None assumes ``J0 = 0`` (see the module docstring).
        fps: frame rate to use when the file has none (a file's own rate always wins).

    Returns:
        A :class:`PoseSequence` (float32) with the first 10 betas (None if the file has none)
        and the file's gender (None if it has none).

    Raises:
        ValueError: unreadable file, unknown layout, missing/misshaped key, NaN values (the
            message names the file and the key). FileNotFoundError: no such file.
    """
    from smplik.limits import open_checked_npz

    path = Path(path)
    npz_file = open_checked_npz(path, "AMASS file not found",
                                lambda exc: _fail(path, f"not a readable .npz file ({exc})."))
    if not isinstance(npz_file, np.lib.npyio.NpzFile):
        raise _fail(path, "not an .npz archive (a single .npy array).")
    with npz_file as npz:
        keys = set(npz.files)
        if "root_orient" in keys and "pose_body" in keys:
            root = _frames(_array(npz, "root_orient", path), "root_orient", 3, path)
            body21 = _frames(_array(npz, "pose_body", path), "pose_body", 63, path)
            if body21.shape[0] != root.shape[0]:
                raise _fail(path, f"key 'pose_body' has {body21.shape[0]} frames but 'root_orient' has "
                                  f"{root.shape[0]}.")
            body = np.concatenate([body21.reshape(-1, _NUM_BODY, 3), np.zeros((root.shape[0], 2, 3))], axis=1)
        elif "poses" in keys:
            poses = _frames(_array(npz, "poses", path), "poses", (72, 156, 165), path)
            root = poses[:, :3]
            if poses.shape[1] == 72:
                body = poses[:, 3:].reshape(-1, NUM_JOINTS - 1, 3)
            else:  # SMPL-H (156) or SMPL-X (165): 21 body joints, then hands/face
                body21 = poses[:, 3 : 3 + 3 * _NUM_BODY].reshape(-1, _NUM_BODY, 3)
                body = np.concatenate([body21, np.zeros((poses.shape[0], 2, 3))], axis=1)
        else:
            raise _fail(path, f"unknown layout: no 'poses' and no 'root_orient'/'pose_body' keys "
                              f"(keys: {', '.join(sorted(keys)) or 'none'}).")
        T = root.shape[0]
        if "trans" not in keys:
            raise _fail(path, "missing key 'trans' (T, 3).")
        trans = _frames(_array(npz, "trans", path), "trans", 3, path)
        if trans.shape[0] != T:
            raise _fail(path, f"key 'trans' has {trans.shape[0]} frames but the poses have {T}.")
        betas: np.ndarray | None = None
        if "betas" in keys:
            raw_betas = _finite(_array(npz, "betas", path), "betas", path)
            if raw_betas.ndim == 2 and raw_betas.shape[0] >= 1:  # some exports store (1, B) or (T, B)
                raw_betas = raw_betas[0]
            if raw_betas.ndim != 1 or raw_betas.shape[0] < 1:
                raise _fail(path, f"key 'betas' has shape {raw_betas.shape}; expected (B,).")
            betas = np.zeros(NUM_BETAS)
            n = min(NUM_BETAS, raw_betas.shape[0])
            betas[:n] = raw_betas[:n]
        gender = _gender(_array(npz, "gender", path), path) if "gender" in keys else None
        rate: float | None = None
        for key in _FPS_KEYS:
            if key in keys:
                value = _array(npz, key, path)
                if value.size != 1 or value.dtype.kind not in "iuf":
                    raise _fail(path, f"key '{key}' has value {value!r:.60}; expected one number.")
                rate = _rate(value.reshape(-1)[0].item(), path, key)
                break
        if rate is None:
            if fps is None:
                raise _fail(path, f"missing frame rate: none of the keys {', '.join(_FPS_KEYS)} (pass fps=).")
            rate = _rate(fps, path, "fps")

    J0 = rest_pelvis(betas, gender) if callable(rest_pelvis) else rest_pelvis
    go, transl = z_up_to_y_up(root, trans, J0)
    return PoseSequence(
        global_orient=go.astype(np.float32),
        body_pose=body.astype(np.float32),
        transl=transl.astype(np.float32),
        betas=None if betas is None else betas.astype(np.float32),
        gender=gender,
        fps=rate,
        source=str(path),
    )
