"""Variants: K alternative poses for one static effector set (:meth:`smplik.solver.IKSolver.sample`).

The IK network is deterministic: for the joints the effectors leave free it gives the most likely pose. Variants
come from the same network, guided:

1. variant 0 is the ordinary :meth:`~smplik.solver.IKSolver.solve` result (the *base* pose);
2. ``candidates`` effector sets = the user's effectors + 1-3 *guide* effectors on joints the user did not constrain
   (:data:`GUIDE_JOINTS`, drawn at random), each a position effector at the base pose's joint plus a random offset
   of :data:`OFFSET_RANGE_M` kept within the limb's reach, with tolerance :data:`GUIDE_TOLERANCE`; all solved in
   one batch; then each guide is moved to where that solve put its joint (the random target is often out of the
   pose's reach) and the candidates are solved again in a second batch: the guides a variant stores are then near
   its pose, and re-solving the user's effectors + the guides gives that pose;
3. a candidate is kept when it still meets the user's effectors (:func:`meets_effectors`: each residual from
   :func:`smplik.solver.effector_residuals` within :func:`allowed_residual`, or no worse than the base pose's
   plus :data:`SLACK_MM` / :data:`SLACK_DEG` when the base itself cannot meet it) and is plausible
   (:func:`implausibility`: finite, the anomaly score of the tracking model's runtime,
   :func:`smplik.tracking.runtime.anomaly_scores`: joint rotations inside the CMU training range stored with the
   shipped tracking model, no crossed legs, no joint below ``floor`` when one is given);
4. K-1 of the kept ones are picked by farthest-point selection on the 24 joint positions (mean joint distance,
   metres), starting from the base pose; candidates closer than :data:`MIN_DISTANCE_M` to a picked pose are never
   picked. All random draws come from ``numpy.random.default_rng(seed)``: the same seed gives the same variants.

A :class:`Variant` holds its pose and the guides that produced it: the user's effectors + the guides re-solve to the
same pose (to within float32 rounding: a batch may run another network backend than one solve), so a variant is made
persistent by adding its guides to the effector set (``smplik scene variants``, the editor's "Keep variant").
The sampling itself is :meth:`smplik.solver.IKSolver.sample_variants`; this module holds its parts.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from smplik.conventions import JOINT_INDEX, PARENTS, EffectorType
from smplik.effectors import Effector
from smplik.pose import Pose

GUIDE_JOINTS: tuple[str, ...] = ("head", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
                                 "left_knee", "right_knee", "left_ankle", "right_ankle")
"""Joints a guide effector may pull (those the user's effectors do not target)."""
_LIMB_ROOT = {"head": "spine3", "left_elbow": "left_shoulder", "right_elbow": "right_shoulder",
              "left_wrist": "left_shoulder", "right_wrist": "right_shoulder", "left_knee": "left_hip",
              "right_knee": "right_hip", "left_ankle": "left_hip", "right_ankle": "right_hip"}
"""The joint a guide's limb hangs from: a guide target stays within the limb's length of it."""
MAX_GUIDES = 3
"""Each candidate has 1 to this many guide effectors."""
OFFSET_RANGE_M = (0.10, 0.40)
"""A guide target is the base pose's joint moved by a random direction times a length drawn in this range."""
REACH_FRACTION = 0.95
"""A guide target further than this fraction of the limb's length from the limb's root is pulled back to it."""
GUIDE_TOLERANCE = 0.8
"""Tolerance of the guide effectors: soft, so that they bend the free limbs without pulling the user's effectors."""
ALLOWED_MM = 10.0
"""A candidate meets a position effector when its residual is at most this plus 3 x the training sampler's noise at
the effector's tolerance (``3 * 0.1 * tolerance ** 13`` m): the allowance of the scene's conflict report
(:func:`workflows.scene.edits.allowance`), so a kept variant shows its user effectors as met."""
ALLOWED_DEG = 5.0
"""Same for rotation and look-at effectors, in degrees (plus ``3 * degrees(0.1 * tolerance ** 13)``)."""
SLACK_MM = 10.0
"""An effector the base pose cannot meet (unreachable) is met by a candidate no worse than the base + this."""
SLACK_DEG = 3.0
MIN_DISTANCE_M = 0.02
"""Least mean joint distance (metres) between two variants."""
ANOMALY_MAX = 0.02
"""Largest :func:`implausibility` of a kept candidate (the tracking runtime's anomaly threshold)."""


@dataclass(frozen=True)
class Variant:
    """One alternative pose for an effector set.

    Attributes:
        pose: the solved pose (SMPL space).
        guides: the guide effectors added to the user's (empty for variant 0, the plain solve).
        effectors: the user's effectors followed by ``guides``: the set that solves to ``pose``.
        distance_m: mean distance of the 24 joints to variant 0's (metres; 0 for variant 0).
    """

    pose: Pose
    guides: tuple[Effector, ...]
    effectors: tuple[Effector, ...]
    distance_m: float


def allowed_residual(effector: Effector) -> float:
    """The residual (mm for position effectors, degrees otherwise) a variant may leave on a user's effector."""
    noise = 0.1 * float(effector.tolerance) ** 13
    if effector.type == EffectorType.POSITION:
        return ALLOWED_MM + 3000.0 * noise
    return ALLOWED_DEG + 3.0 * float(np.degrees(noise))


def meets_effectors(residuals: Sequence[float], base: Sequence[float], effectors: Sequence[Effector]) -> bool:
    """Whether a candidate's residuals (mm / degrees, one per user effector) meet the user's effectors: each within
    :func:`allowed_residual`, or within the base pose's residual + slack when the base does not meet it."""
    for r, r0, e in zip(residuals, base, effectors, strict=True):
        slack = SLACK_MM if e.type == EffectorType.POSITION else SLACK_DEG
        if not (r <= allowed_residual(e) or r <= r0 + slack):
            return False
    return True


@lru_cache(maxsize=1)
def training_range() -> tuple[np.ndarray, np.ndarray] | None:
    """The 0.1 / 99.9 percentiles (24, 3) of the CMU training set's local axis-angle components, as stored with the
    shipped tracking model (:mod:`smplik.tracking.model_io`); None when that file is absent or unreadable (the range
    check is then skipped). The IK model file keeps no range of its own."""
    from smplik.tracking.model_io import DEFAULT_CHECKPOINT, read_tracking_file

    try:  # the one model-file reader: checked sizes, layout, shapes and finite values
        blob = read_tracking_file(DEFAULT_CHECKPOINT)
    except (OSError, ValueError):
        return None
    return blob["pose_lo"].double().numpy(), blob["pose_hi"].double().numpy()


def implausibility(poses: Sequence[Pose], floor: float | None = None) -> np.ndarray:
    """(N,) anomaly score of poses (0: plausible; inf: non-finite), see the module docstring.

    ``floor``: the floor's height (y, SMPL space) or None for no floor test."""
    from scipy.spatial.transform import Rotation

    from smplik.tracking.runtime import anomaly_scores

    aa = np.stack([np.concatenate([p.global_orient[None], p.body_pose]) for p in poses])  # (N, 24, 3)
    joints = np.stack([p.joints for p in poses])  # (N, 24, 3)
    finite = np.isfinite(aa).all((1, 2)) & np.isfinite(joints).all((1, 2))
    rng = training_range()
    lo, hi = rng if rng is not None else (np.full((24, 3), -np.inf), np.full((24, 3), np.inf))
    R = Rotation.from_rotvec(np.where(finite[:, None, None], aa, 0.0).reshape(-1, 3)).as_matrix().reshape(-1, 24, 3, 3)
    score = anomaly_scores(R, np.where(finite[:, None, None], joints, 0.0), lo, hi,
                           floor_y=-np.inf if floor is None else float(floor))
    return np.where(finite, score, np.inf)


def farthest_points(distance: np.ndarray | Callable[[int], np.ndarray], k: int, min_distance: float) -> list[int]:
    """Farthest-point selection: indices of up to ``k`` rows of a (N, N) distance matrix, starting with row 0 and
    each time adding the row farthest from those picked (the lowest index on ties); stops early when the
    farthest is closer than ``min_distance``. ``distance`` may be a function of a row index returning that row
    (N,): only the picked rows are then computed (k N instead of N^2)."""
    row = distance if callable(distance) else distance.__getitem__
    picked = [0]
    nearest = np.array(row(0), dtype=np.float64, copy=True)
    while len(picked) < k:
        j = int(np.argmax(nearest))
        if not nearest[j] >= min_distance:
            break
        picked.append(j)
        nearest = np.minimum(nearest, row(j))
    return picked


def check_count(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r:.40}.")
    return int(value)


def guide_effectors(base: Pose, free: Sequence[int], rng: np.random.Generator) -> tuple[Effector, ...]:
    """1 to :data:`MAX_GUIDES` guide effectors on joints drawn from ``free`` (joint indices), around ``base``."""
    n = int(rng.integers(1, min(MAX_GUIDES, len(free)) + 1))
    joints = rng.choice(np.asarray(free), size=n, replace=False)
    guides = []
    for j in sorted(int(x) for x in joints):
        direction = rng.normal(size=3)
        direction /= max(float(np.linalg.norm(direction)), 1e-9)
        target = base.joints[j] + direction * rng.uniform(*OFFSET_RANGE_M)
        root = JOINT_INDEX[_LIMB_ROOT[_NAMES[j]]]
        reach, k = 0.0, j
        while k != root:
            reach += float(np.linalg.norm(base.joints[k] - base.joints[PARENTS[k]]))
            k = PARENTS[k]
        v = target - base.joints[root]
        if np.linalg.norm(v) > REACH_FRACTION * reach:
            target = base.joints[root] + v * (REACH_FRACTION * reach / np.linalg.norm(v))
        guides.append(Effector.position(j, target, GUIDE_TOLERANCE))
    return tuple(guides)


_NAMES = {JOINT_INDEX[n]: n for n in GUIDE_JOINTS}


def free_guide_joints(effectors: Sequence[Effector]) -> list[int]:
    """The :data:`GUIDE_JOINTS` (indices) that no effector targets."""
    constrained = {e.joint for e in effectors}
    return [JOINT_INDEX[n] for n in GUIDE_JOINTS if JOINT_INDEX[n] not in constrained]


def pick_variants(base: Pose, poses: Sequence[Pose], keep: Sequence[int], k: int) -> list[tuple[int, float]]:
    """Farthest-point selection of up to ``k - 1`` of ``poses[keep]`` around ``base``: (index into ``poses``, mean
    joint distance to ``base`` in metres) in picking order."""
    joints = np.stack([base.joints] + [poses[m].joints for m in keep])  # (1 + kept, 24, 3)

    def distance(i: int) -> np.ndarray:  # row i of the (1 + kept, 1 + kept) mean joint distances, on demand
        return np.linalg.norm(joints[i][None] - joints, axis=-1).mean(-1)

    first = distance(0)
    return [(keep[i - 1], float(first[i])) for i in farthest_points(distance, k, MIN_DISTANCE_M)[1:]]
