"""Joint-position motion -> SMPL animation (``smplik scene animate`` on joints, not SMPL parameters).

Inputs (:func:`read_joint_motion`), every one y-up metres, the joints SMPL's first 22 in SMPL order
(pelvis .. right_wrist) unless said otherwise:

* **HumanML3D joints** ``(T, 22, 3)`` ``.npy``: HumanML3D's ``new_joints/*.npy`` (github.com/EricGuo5513/HumanML3D,
  ``motion_representation.ipynb``: ``np.save`` of the ``recover_from_ric`` positions), and what text-to-motion demos
  write: T2M-GPT's demo ``np.save('motion.npy', xyz)`` with ``xyz = recover_from_ric(...).reshape(1, -1, 22, 3)``
  (a leading batch axis: ``(N, T, 22, 3)`` is N tracks), MoMask's per-sample joint arrays. HumanML3D runs at 20
  frames/s: the default rate, with a note.
* **MDM's** ``results.npy`` (github.com/GuyTevet/motion-diffusion-model, ``sample/generate.py``:
  ``np.save(npy_path, {'motion': all_motions, 'text': all_text, 'lengths': all_lengths, 'num_samples': ...,
  'num_repetitions': ...})``, ``all_motions`` ``(N, 22, 3, T)``): an object ``.npy`` read through the project's
  restricted unpickler (:func:`smplik.safe_pickle.read_npy`: plain containers and numeric arrays only, never
  code). Each of the N motions is one track (``sample_<i>``), ``lengths[i]`` frames long.
* **HumanML3D features** ``(T, 263)``: the joints are recovered exactly as HumanML3D's own ``recover_from_ric``
  (:func:`recover_from_ric`). Features are usually normalised by the dataset's ``Mean.npy``/``Std.npy``:
  ``--mean FILE --std FILE`` undo it (``x * std + mean``); without them the features must be un-normalised
  (HumanML3D's ``new_joint_vecs/*.npy`` are).
* **A BVH whose body lives in its rotations** (MediaPipe-to-BVH tools write every OFFSET along one "up"
  vector): forward kinematics of every frame (:func:`smplik.data.bvh.read_bvh`), the joints mapped to SMPL by
  the rig reader (names, topology; :func:`shape_inversion.skeleton_io.prepare_character` on frame 0, whose
  units, up axis and facing are kept for every frame), then read as joint positions.

Per track (:func:`joints_to_clip`):

1. **Body**: SMPL-SI fits ``(beta, scale)`` to the motion's bone lengths (:func:`fit_body`): the median length
   of each of the 21 bones over the frames, laid along SMPL's rest bone directions, is a rest skeleton; its
   six features and its mapped rest joints go to :meth:`shape_inversion.estimator.ShapeEstimator.estimate`.
2. **Pose per frame**: the SMPL-IK solver (network + effector refinement) with a position effector on every
   given joint, all frames in one batch (SMPL space: the joints divided by the scale).
3. The poses then go through ``scene animate``'s steps (:func:`workflows.animation.clips.animation_from_clip`:
   glitch repair, cleaning, foot locks, keyframes, effectors) on the fitted body (or on ``--character``).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import JOINT_NAMES, NUM_BETAS, PARENTS, Gender
from workflows.estimators.base import EstimatedPerson

NUM_MOTION_JOINTS = 22
"""HumanML3D's joints: SMPL's first 22 (pelvis .. right_wrist, no hands), in SMPL order."""
HUMANML3D_FEATURES = 263
"""HumanML3D's feature width for 22 joints: 4 root + 21*3 ric + 21*6 rot + 22*3 velocity + 4 foot contacts."""
HUMANML3D_FPS = 20.0
"""HumanML3D (and the text-to-motion models trained on it) runs at 20 frames/s."""
MAX_COORD_M = 1000.0
"""Joint coordinates beyond this (metres) are refused (not metres, or garbage)."""
SOLVE_CHUNK = 512
"""Frames per solver batch."""
FORMATS = ("joints", "humanml3d_vec", "mdm", "bvh_joints")


class JointMotionError(ValueError):
    """Bad joint-position input (shape, values, mean/std files); one line naming the file."""


@dataclass(frozen=True)
class JointMotion:
    """Joint positions of one or more motions, read from one file.

    Attributes:
        tracks: track id -> (T, J, 3) joint positions, y-up metres, the columns SMPL joints ``joints``.
        joints: (J,) SMPL joint index of each column.
        fps: the frame rate the file states (BVH) or its format fixes (HumanML3D 20), or None.
        format: one of :data:`FORMATS`.
        notes: lines saying what the reading found.
        fps_assumed: whether ``fps`` is the format's rate rather than the file's (said when ``--fps`` is not given).
    """

    tracks: dict[str, np.ndarray]
    joints: np.ndarray
    fps: float | None
    format: str
    notes: tuple[str, ...] = ()
    fps_assumed: bool = False


@dataclass(frozen=True)
class FittedBody:
    """The SMPL body SMPL-SI fitted to a motion's bone lengths (what ``animation_from_clip`` takes as a character)."""

    betas: np.ndarray
    gender: Gender
    scale: float
    bone_residual_m: float
    """Mean |bone length of scale * J(betas) - the motion's median bone length| over the bones (metres)."""


# ----------------------------------------------------------------------------- HumanML3D's recover_from_ric


def _qrot_y(angle: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v (..., 3) by the quaternion ``qinv((cos a, 0, sin a, 0))``: HumanML3D's ``qrot(qinv(r_rot_quat), v)``
    for its y-axis root quaternions, written out. angle (...,) broadcast against v's leading axes."""
    # q = (w, x, y, z) = (cos a, 0, -sin a, 0); qrot: v + 2 (w (q_v x v) + q_v x (q_v x v))
    w, s = np.cos(angle), -np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    uv = np.stack([s * z, np.zeros_like(y), -s * x], axis=-1)          # (0, s, 0) x v
    uuv = np.stack([s * uv[..., 2], np.zeros_like(y), -s * uv[..., 0]], axis=-1)
    return v + 2.0 * (w[..., None] * uv + uuv)


def recover_from_ric(data: np.ndarray, joints_num: int = NUM_MOTION_JOINTS) -> np.ndarray:
    """HumanML3D features (..., T, 263) -> joint positions (..., T, joints_num, 3), y-up metres.

    A numpy re-implementation of HumanML3D's ``recover_root_rot_pos`` + ``recover_from_ric``
    (github.com/EricGuo5513/HumanML3D ``common/motion_process.py``; the same code in MDM's
    ``data_loaders/humanml/scripts/motion_process.py``): the root's y rotation is the cumulative sum of the
    rotation velocity ``data[..., 0]`` shifted by one frame; the root's xz path the cumulative sum of the
    velocities ``data[..., 1:3]`` (shifted by one frame) turned by that rotation's inverse; its height
    ``data[..., 3]``; the other joints the root-relative positions ``data[..., 4:4 + 3 (J - 1)]`` turned by the
    same inverse rotation, plus the root's x and z.
    """
    data = np.asarray(data, dtype=np.float64)
    rot_vel = data[..., 0]
    r_rot_ang = np.zeros_like(rot_vel)
    r_rot_ang[..., 1:] = rot_vel[..., :-1]
    r_rot_ang = np.cumsum(r_rot_ang, axis=-1)
    r_pos = np.zeros(data.shape[:-1] + (3,))
    r_pos[..., 1:, 0] = data[..., :-1, 1]
    r_pos[..., 1:, 2] = data[..., :-1, 2]
    r_pos = np.cumsum(_qrot_y(r_rot_ang, r_pos), axis=-2)
    r_pos[..., 1] = data[..., 3]
    positions = data[..., 4:(joints_num - 1) * 3 + 4].reshape(data.shape[:-1] + (joints_num - 1, 3))
    positions = _qrot_y(r_rot_ang[..., None], positions)
    positions[..., 0] += r_pos[..., None, 0]
    positions[..., 2] += r_pos[..., None, 2]
    return np.concatenate([r_pos[..., None, :], positions], axis=-2)


# ----------------------------------------------------------------------------- reading


def joint_motion_kind(data: Any) -> str | None:
    """Which joint-motion layout a loaded ``.npy`` holds (:data:`FORMATS`), or None."""
    if isinstance(data, np.ndarray) and data.dtype.kind in "fiu":
        if data.ndim in (3, 4) and data.shape[-2:] == (NUM_MOTION_JOINTS, 3):
            return "joints"
        if data.ndim == 2 and data.shape[1] == HUMANML3D_FEATURES:
            return "humanml3d_vec"
        return None
    if isinstance(data, dict) and isinstance(data.get("motion"), np.ndarray):
        m = data["motion"]
        if m.ndim == 4 and m.shape[1:3] == (NUM_MOTION_JOINTS, 3) and m.dtype.kind in "fiu":
            return "mdm"
    return None


def _checked(joints: np.ndarray, source: str) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape[0] < 1:
        raise JointMotionError(f"{source}: no frames.")
    if not np.isfinite(joints).all():
        raise JointMotionError(f"{source}: joint positions contain NaN or inf.")
    if np.abs(joints).max() > MAX_COORD_M:
        raise JointMotionError(f"{source}: joint coordinates up to {np.abs(joints).max():.3g}; expected metres "
                               f"(within {MAX_COORD_M:g} m).")
    return joints


def _vector_file(path: str | Path, name: str) -> np.ndarray:
    from smplik.safe_pickle import read_npy

    try:
        arr = read_npy(path)
    except ValueError as exc:
        raise JointMotionError(f"--{name}: {' '.join(str(exc).split())[:200]}") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu" or arr.reshape(-1).shape != (HUMANML3D_FEATURES,):
        shape = getattr(arr, "shape", type(arr).__name__)
        raise JointMotionError(f"--{name} {path}: expected {HUMANML3D_FEATURES} numbers (HumanML3D's "
                               f"{name.capitalize()}.npy), got {shape}.")
    arr = arr.reshape(-1).astype(np.float64)
    if not np.isfinite(arr).all():
        raise JointMotionError(f"--{name} {path}: contains NaN or inf.")
    return arr


def joint_motion_from_data(data: Any, source: str, *, mean: str | Path | None = None,
                           std: str | Path | None = None) -> JointMotion | None:
    """The joint motion of a loaded ``.npy`` (module docstring), or None when it is not one."""
    kind = joint_motion_kind(data)
    if kind is None:
        if mean is not None or std is not None:
            raise JointMotionError(f"{source}: --mean/--std apply to HumanML3D features (T, 263) only.")
        return None
    joints = np.arange(NUM_MOTION_JOINTS)
    note = f"{source}: {{what}}."
    if kind == "joints":  # (T, 22, 3), or (N, T, 22, 3): T2M-GPT's motion.npy is (1, T, 22, 3)
        batch = data if data.ndim == 4 else data[None]
        tracks = {str(i): _checked(m, source if len(batch) == 1 else f"{source}[{i}]") for i, m in enumerate(batch)}
        what = (f"HumanML3D joint positions ({batch.shape[1]} frames, 22 SMPL joints, y-up metres"
                f"{'' if len(batch) == 1 else f'; {len(batch)} motions, each a track'})")
        return JointMotion(tracks, joints, HUMANML3D_FPS, kind, (note.format(what=what),), True)
    if kind == "humanml3d_vec":
        if (mean is None) != (std is None):
            raise JointMotionError("--mean and --std go together (HumanML3D's Mean.npy and Std.npy).")
        feats = np.asarray(data, dtype=np.float64)
        if not np.isfinite(feats).all():
            raise JointMotionError(f"{source}: features contain NaN or inf.")
        said = "un-normalised (no --mean/--std)"
        if mean is not None and std is not None:
            feats = feats * _vector_file(std, "std") + _vector_file(mean, "mean")
            said = "de-normalised by --mean/--std"
        return JointMotion({"0": _checked(recover_from_ric(feats), source)}, joints, HUMANML3D_FPS, kind,
                           (note.format(what=f"HumanML3D features ({feats.shape[0]} frames, {said}), joints "
                                        "recovered as HumanML3D's recover_from_ric"),), True)
    motion = np.asarray(data["motion"], dtype=np.float64)  # (N, 22, 3, T)
    n, T = motion.shape[0], motion.shape[3]
    lengths = data.get("lengths")
    lens = np.full(n, T) if lengths is None else np.asarray(lengths).reshape(-1)
    if lens.shape != (n,) or lens.dtype.kind not in "iuf" or not np.all((lens >= 1) & (lens <= T)):
        raise JointMotionError(f"{source}: 'lengths' must hold {n} frame counts within 1..{T} (MDM results.npy).")
    tracks = {f"{i}": _checked(motion[i, :, :, :int(lens[i])].transpose(2, 0, 1), f"{source}: motion[{i}]")
              for i in range(n)}
    return JointMotion(tracks, joints, HUMANML3D_FPS, kind,
                       (note.format(what=f"MDM results: {n} motion(s) of 22 joints, each a track"),), True)


def read_bvh_joints(path: str | Path, options: Any = None) -> JointMotion:
    """A BVH whose body lives in its rotations: every frame's joints by forward kinematics, mapped to SMPL joints
    (module docstring). ``options``: :class:`shape_inversion.options.CharacterOptions` (rig, map, units, up)."""
    from shape_inversion.options import CharacterOptions
    from shape_inversion.skeleton_io import SkeletonError, bvh_skeleton, prepare_character
    from smplik.data.bvh import BVHError
    from smplik.data.bvh import read_bvh as bvh_read

    o = CharacterOptions() if options is None else options
    try:
        motion = bvh_read(path)
    except BVHError as exc:
        raise JointMotionError(str(exc)) from None
    if motion.num_frames < 1:
        raise JointMotionError(f"{path}: no MOTION frames.")
    try:
        char = prepare_character(bvh_skeleton(motion, "frame0"), rig=o.rig, map_file=o.map, units=o.units,
                                 up=o.up, root=o.root)
    except (SkeletonError, ValueError) as exc:
        raise JointMotionError(f"{path}: its frame 0 cannot be mapped to SMPL joints: "
                               f"{' '.join(str(exc).split())[:300]}") from None
    cols = [(j, char.smpl_joints[name]) for j, name in enumerate(JOINT_NAMES[:NUM_MOTION_JOINTS])
            if name in char.smpl_joints]
    joints = np.array([j for j, _ in cols])
    P = char.units_m * motion.positions[:, [k for _, k in cols]] @ char.R_canon_file.T - char.shift
    fps = 1.0 / motion.frame_time if motion.frame_time > 0 else None
    missing = [JOINT_NAMES[j] for j in range(NUM_MOTION_JOINTS) if j not in set(joints.tolist())]
    note = (f"{path}: a BVH read as joint positions (forward kinematics of its {motion.num_frames} frames; "
            f"{len(cols)} SMPL joints mapped{'' if not missing else ', no ' + ', '.join(missing)}; "
            f"{char.units_m:g} m per unit"
            f"{'; its OFFSETs all point one way: the body lives in its rotations' if _one_direction(motion) else ''})")
    return JointMotion({"0": _checked(P, str(path))}, joints, fps, "bvh_joints", (note,))


def offsets_share_one_direction(path: str | Path) -> bool:
    """Whether a BVH's joints' non-zero OFFSETs all point one way (MediaPipe-to-BVH tools: the body exists only once
    the rotations are applied; its OFFSET pose is a vertical line)."""
    from smplik.data.bvh import BVHError
    from smplik.data.bvh import read_bvh as bvh_read

    try:
        return _one_direction(bvh_read(path))
    except BVHError:
        return False


def _one_direction(motion: Any) -> bool:
    off = np.asarray(motion.offsets, dtype=np.float64)[1:]
    lengths = np.linalg.norm(off, axis=-1)
    off = off[lengths > 1e-9] / lengths[lengths > 1e-9, None]
    return len(off) >= 5 and bool(np.all(off @ off[0] > 0.999))


# ----------------------------------------------------------------------------- fitting


def bone_lengths(joints: np.ndarray, cols: np.ndarray) -> dict[int, float]:
    """Median length over the frames of every bone (SMPL joint -> its length to its SMPL parent) whose both ends
    are columns of joints (T, J, 3)."""
    where = {int(j): k for k, j in enumerate(cols)}
    out = {}
    for j, k in where.items():
        p = PARENTS[j]
        if p >= 0 and p in where:
            out[j] = float(np.median(np.linalg.norm(joints[:, k] - joints[:, where[p]], axis=-1)))
    return out


def fit_body(joints: np.ndarray, cols: np.ndarray, gender: Gender = Gender.NEUTRAL) -> FittedBody:
    """SMPL-SI's ``(beta, scale)`` for a motion's bone lengths (module docstring, step 1).

    joints: (T, J, 3) positions, metres; cols: (J,) their SMPL joints.
    """
    from shape_inversion.estimator import ShapeInversionError
    from shape_inversion.features import FEATURE_PAIRS
    from shape_inversion.joint_fit import MappedRest
    from smplik.body_model import load_body_model
    from smplik.conventions import JOINT_INDEX

    lengths = bone_lengths(joints, cols)
    model = load_body_model(gender)
    J0 = model.J_template.double().numpy()  # (24, 3) SMPL's rest joints at beta 0
    rest = J0.copy()
    for j in range(1, len(J0)):  # SMPL's rest bone directions, the motion's lengths (SMPL's where unknown)
        d = J0[j] - J0[PARENTS[j]]
        rest[j] = rest[PARENTS[j]] + d / np.linalg.norm(d) * lengths.get(j, np.linalg.norm(d))
    need = {JOINT_INDEX[n] for pair in FEATURE_PAIRS for n in pair}
    have = set(int(c) for c in cols)
    missing = sorted(JOINT_NAMES[j] for j in need - have)
    if missing:
        raise JointMotionError(f"the motion lacks the joints SMPL-SI measures: {', '.join(missing)}.")
    feats = np.array([np.linalg.norm(rest[JOINT_INDEX[a]] - rest[JOINT_INDEX[b]]) for a, b in FEATURE_PAIRS])
    mapped = MappedRest(np.array(sorted(have)), rest[sorted(have)],
                        np.array([sorted(have).index(PARENTS[j]) if PARENTS[j] in have else -1 for j in sorted(have)]))
    estimator = _estimator(gender)
    try:
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = estimator.estimate(feats, mapped)
    except ShapeInversionError as exc:
        raise JointMotionError(f"the motion's bone lengths are not a human's: {exc}") from None
    J = est.scale * (estimator.joint_template + estimator.joint_dirs @ est.betas)
    fitted = [abs(np.linalg.norm(J[j] - J[PARENTS[j]]) - L) for j, L in lengths.items()]
    return FittedBody(np.asarray(est.betas, dtype=np.float64), gender, float(est.scale), float(np.mean(fitted)))


@functools.lru_cache(maxsize=3)
def _estimator(gender: Gender):
    """SMPL-SI's estimator of ``gender`` (its sample bank loaded once per process)."""
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model

    return ShapeEstimator.build(load_body_model(gender))


def solve_frames(solver: Any, joints: np.ndarray, cols: np.ndarray, body: FittedBody) -> list:
    """Per frame, the SMPL pose (SMPL space of ``body``) whose joints reach ``joints`` (T, J, 3): one position
    effector per column, solved in batches of :data:`SOLVE_CHUNK` (module docstring, step 2)."""
    from smplik.effectors import Effector

    targets = joints / body.scale
    poses = []
    for start in range(0, len(targets), SOLVE_CHUNK):
        rows = [[Effector.position(int(j), t[k]) for k, j in enumerate(cols)]
                for t in targets[start:start + SOLVE_CHUNK]]
        poses += solver.solve_batch(rows, betas=np.broadcast_to(body.betas, (len(rows), NUM_BETAS)).copy(),
                                    gender=body.gender)
    return poses


def people_of(poses: list, body: FittedBody, track: str, source: str) -> list[tuple[int, EstimatedPerson]]:
    """Solved poses (SMPL space of ``body``) as world-frame estimator rows of one track: each pelvis where the
    scaled body puts it (``scale * (J0 + transl)``), the person at scale 1 on the same betas."""
    from workflows.estimators.base import rest_pelvis

    J0 = rest_pelvis(body.betas[None], body.gender)[0]
    return [(f, EstimatedPerson(np.asarray(p.global_orient, dtype=np.float64),
                                np.asarray(p.body_pose, dtype=np.float64).reshape(23, 3),
                                body.scale * (J0 + np.asarray(p.transl, dtype=np.float64)) - J0,
                                body.betas.copy(), body.gender, None, track, str(f), source))
            for f, p in enumerate(poses)]


def joints_to_clip(motion: JointMotion, solver: Any, source: str, track: str,
                   frames: tuple[int, int] | None = None):
    """One track of a joint motion -> (a world-frame :class:`workflows.animation.clips.Clip` of its solved poses,
    the :class:`FittedBody`)."""
    from workflows.animation.clips import AnimationError, Clip

    joints = motion.tracks[track]
    T = len(joints)
    if frames is not None:
        if frames[1] > T:
            raise AnimationError(f"{source}: --frames {frames[0]}:{frames[1]} is outside the clip (frames "
                                 f"0..{T - 1}).")
    body = fit_body(joints, motion.joints)
    start, stop = frames if frames is not None else (0, T)
    poses = solve_frames(solver, joints[start:stop], motion.joints, body)
    rows = [(start + f, p) for f, p in people_of(poses, body, track, source)]
    rows = [(f, dataclasses.replace(p, frame=str(f))) for f, p in rows]
    return Clip(source, motion.format, T, {track: rows}, motion.fps, "world", motion.notes), body
