"""Dragging any joint: a local solve of the joints between the dragged joint and an anchor, from the current pose.

A drag of an elbow, knee, the head, the neck, a spine joint or the pelvis moves only the chain that a person
would move (:func:`drag_plan`), solved by damped Gauss-Newton (Levenberg-Marquardt) on the local rotations of
that chain, starting from (and regularised towards) the pose the drag started from. No network runs: the
rest of the body is exactly where it was, except what the chain carries.

* **elbow / knee**: the shoulder (and, stiffer, the collar) or the hip turn and the elbow/knee bends so the
  wrist or ankle stays where it was (the limb's swivel about the shoulder-wrist / hip-ankle axis when the
  target is on it); the hand or foot keeps its world orientation. Any twist of the elbow/knee about its
  parent bone is handed to the shoulder/hip.
* **head / neck**: the spine bends (the neck most, spine1 least); the pelvis and legs do not move; the head
  keeps its world orientation on a neck drag.
* **spine1..3 / pelvis**: the spine joints below the dragged one, then the root (translation first,
  rotation stiffer); legs whose foot is *planted* (a held effector on the leg, or the foot within
  :data:`CONTACT_M` of the lower foot) are re-solved so the ankle stays, the foot keeping its world orientation.

Any limb hanging from a moved joint that holds an exact position effector (a pinned hand while the spine bends)
is re-solved the same way so its end stays. Everything is SMPL space, float64 numpy; one pose at a time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS
from smplik.rotations import axis_angle_to_matrix_np

CONTACT_M = 0.05
"""A foot whose ``*_foot`` joint is within this height (m, +y up) of the lower foot's counts as planted."""
TARGET_WEIGHT = 3.0
"""Weight of the dragged joint's target."""
END_WEIGHT = 0.3
"""Weight of the limb end an elbow or knee drag keeps (yields when the target needs it)."""
STRICT_WEIGHT = 30.0
"""Weight of what must not move (planted feet, held effectors)."""
DRAG_JOINTS: tuple[str, ...] = ("left_elbow", "right_elbow", "left_knee", "right_knee", "head", "neck",
                                "spine1", "spine2", "spine3", "pelvis")
"""Joints whose position drag :func:`drag_joint` solves."""
_ARMS = {"left": ("left_collar", "left_shoulder", "left_elbow", "left_wrist"),
         "right": ("right_collar", "right_shoulder", "right_elbow", "right_wrist")}
_LEGS = {"left": ("left_hip", "left_knee", "left_ankle", "left_foot"),
         "right": ("right_hip", "right_knee", "right_ankle", "right_foot")}
_STIFF = {"collar": 0.05, "shoulder": 5e-4, "elbow": 5e-4, "hip": 5e-4, "knee": 5e-4, "neck": 5e-4,
          "spine3": 1e-3, "spine2": 2e-3, "spine1": 3e-3, "pelvis": 0.01}
"""Regularisation per joint kind (larger: turns less); the root translation's is :data:`_TRANSL_STIFF`."""
_TRANSL_STIFF = 1e-5
RESTART_MISS_M = 0.005
"""A drag missing its target by more than this (m) is retried from slightly bent elbows/knees."""
RESTART_BEND = 0.3
"""The bend (rad) of those retries."""


@dataclass(frozen=True)
class DragPlan:
    """What a drag of ``joint`` may move.

    Attributes:
        joint: the dragged joint.
        free: joints whose local rotations the solve changes.
        translate: the root translation is free too.
        keep: (joint, weight) pairs whose positions are held at their starting place.
        world_locked: joints that keep their world rotation (their local rotation follows their parent's change).
        chain: the moved chain itself (the dragged joint's own limb/spine joints; the figures' "inside").
    """

    joint: int
    free: tuple[int, ...]
    translate: bool = False
    keep: tuple[tuple[int, float], ...] = ()
    world_locked: tuple[int, ...] = ()
    chain: tuple[int, ...] = field(default=())


def _j(*names: str) -> tuple[int, ...]:
    return tuple(JOINT_INDEX[n] for n in names)


def _subtree(roots: Sequence[int]) -> set[int]:
    out = set(roots)
    for j in range(NUM_JOINTS):
        if PARENTS[j] in out:
            out.add(j)
    return out


def planted_feet(p_world: np.ndarray, held: Sequence[int] = ()) -> list[str]:
    """Sides ("left"/"right") whose foot is planted: a held position effector on the leg (``held``: joint
    indices) or the ``*_foot`` joint within :data:`CONTACT_M` of the lower foot's height. p_world (24, 3)."""
    y = {s: p_world[JOINT_INDEX[f"{s}_foot"], 1] for s in ("left", "right")}
    low = min(y.values())
    return [s for s in ("left", "right")
            if y[s] <= low + CONTACT_M or any(JOINT_INDEX[n] in held for n in _LEGS[s][1:])]


def drag_plan(joint: int | str, p_world: np.ndarray, held: Sequence[int] = ()) -> DragPlan:
    """The :class:`DragPlan` of a position drag of ``joint`` on a pose with joints ``p_world`` (24, 3);
    ``held``: the joints of the exact position effectors the drag must keep (they free the limbs they hang from)."""
    j = JOINT_INDEX[joint] if isinstance(joint, str) else int(joint)
    name = JOINT_NAMES[j]
    if name not in DRAG_JOINTS:
        raise ValueError(f"No chain drag for joint {name!r}; expected one of: {', '.join(DRAG_JOINTS)}.")
    held = set(int(h) for h in held) - {j}
    side = name.split("_")[0]
    if name.endswith("elbow"):
        collar, shoulder, elbow, wrist = _j(*_ARMS[side])
        return DragPlan(j, (collar, shoulder, elbow), keep=((wrist, END_WEIGHT),), world_locked=(wrist,),
                        chain=(collar, shoulder, elbow, wrist))
    if name.endswith("knee"):
        hip, knee, ankle, _ = _j(*_LEGS[side])
        return DragPlan(j, (hip, knee), keep=((ankle, END_WEIGHT),), world_locked=(ankle,), chain=(hip, knee, ankle))
    spine = _j("spine1", "spine2", "spine3", "neck")
    translate = False
    if name in ("head", "neck"):
        free = list(spine[: 4 if name == "head" else 3])
        locked = [JOINT_INDEX["neck"]] if name == "neck" else []
    else:  # spine1..3, pelvis: the spine below, then the root
        below = {"pelvis": 0, "spine1": 0, "spine2": 1, "spine3": 2}[name]
        free = [0, *spine[:below]]
        translate = True
        locked = [j] if name != "pelvis" else []
    keep: list[tuple[int, float]] = []
    moved = _subtree(free)
    if translate:  # the legs hang from the root: planted ones are re-solved, the others ride
        for s in planted_feet(p_world, tuple(held)):
            hip, knee, ankle, _ = _j(*_LEGS[s])
            free += [hip, knee]
            keep.append((ankle, STRICT_WEIGHT))
            locked.append(ankle)
    for s, arm in _ARMS.items():  # a pinned hand stays while the torso moves
        collar, shoulder, elbow, wrist = _j(*arm)
        if collar in moved and held & {elbow, wrist, JOINT_INDEX[f"{s}_hand"]}:
            free += [shoulder, elbow]
            keep.append((wrist, STRICT_WEIGHT))
            locked.append(wrist)
    chain = tuple(sorted(set(free) - set(_j(*_LEGS["left"], *_LEGS["right"], *_ARMS["left"], *_ARMS["right"]))
                         | {j}))
    return DragPlan(j, tuple(free), translate, tuple(keep), tuple(locked), chain)


def _fk(R_local: np.ndarray, transl: np.ndarray, J_rest: np.ndarray,
        locks: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (24, 3, 3) and joints (24, 3); joints in ``locks`` take that world rotation."""
    R = np.empty((NUM_JOINTS, 3, 3))
    p = np.empty((NUM_JOINTS, 3))
    for k in range(NUM_JOINTS):
        par = PARENTS[k]
        if par < 0:
            R[k] = R_local[k]
            p[k] = J_rest[k] + transl
        else:
            R[k] = R[par] @ R_local[k]
            p[k] = p[par] + R[par] @ (J_rest[k] - J_rest[par])
        if k in locks:
            R[k] = locks[k]
    return R, p


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@dataclass(frozen=True)
class DragResult:
    """A solved drag: local rotations (24, 3, 3), root translation (3,), joints (24, 3) and the plan used."""

    R_local: np.ndarray
    transl: np.ndarray
    p_world: np.ndarray
    plan: DragPlan


def drag_joint(R_local: np.ndarray, transl: np.ndarray, J_rest: np.ndarray, joint: int | str, target: np.ndarray, *,
               held_positions: Sequence[tuple[int, np.ndarray]] = (), plan: DragPlan | None = None,
               iterations: int = 60) -> DragResult:
    """Move ``joint`` to ``target`` by the local solve of its :func:`drag_plan` (module docstring).

    Args:
        R_local: (24, 3, 3) the pose the drag starts from (local rotations); transl (3,); J_rest (24, 3).
        joint: the dragged joint (name or index, one of :data:`DRAG_JOINTS`); target (3,), SMPL space.
        held_positions: (joint, (3,) position) of the exact position effectors to keep (others than the dragged).
        plan: default :func:`drag_plan` of the starting pose.
    """
    R_local = np.array(R_local, np.float64)
    transl = np.array(transl, np.float64)
    J_rest = np.asarray(J_rest, np.float64)
    target = np.asarray(target, np.float64)
    R0, p0 = _fk(R_local, transl, J_rest, {})
    R_start, t_start = R_local.copy(), transl.copy()
    held_positions = [(int(h), np.asarray(v, np.float64)) for h, v in held_positions if int(h) != _index(joint)]
    if plan is None:
        plan = drag_plan(joint, p0, [h for h, _ in held_positions])
    locks = {k: R0[k].copy() for k in plan.world_locked}
    free = list(plan.free)
    moved = _subtree(free)
    # residual terms: (joint, goal, weight)
    terms: list[tuple[int, np.ndarray, float]] = [(plan.joint, target, TARGET_WEIGHT)]
    terms += [(k, p0[k].copy(), w) for k, w in plan.keep]
    terms += [(h, v, STRICT_WEIGHT) for h, v in held_positions if h in moved and h not in dict(plan.keep)]
    stiff = np.concatenate([np.full(3, _stiffness(k)) for k in free] + ([np.full(3, _TRANSL_STIFF)]
                                                                       if plan.translate else []))
    R_local, transl, best = _lm(R_local, transl, J_rest, free, plan.translate, locks, terms, stiff, iterations)
    miss = float(np.linalg.norm(_fk(R_local, transl, J_rest, locks)[1][plan.joint] - target))
    if miss > RESTART_MISS_M:  # a straight limb is a singular start: retry from the hinges slightly bent
        hinges = [k for k in plan.chain if k in free and JOINT_NAMES[k].endswith(("elbow", "knee"))]
        for k in hinges:
            for axis in range(3):
                for sign in (-1.0, 1.0):
                    R_try = np.array(R_start)
                    R_try[k] = R_try[k] @ axis_angle_to_matrix_np(sign * RESTART_BEND * np.eye(3)[axis])
                    got = _lm(R_try, np.array(t_start), J_rest, free, plan.translate, locks, terms, stiff,
                              iterations)
                    if got[2] < best:
                        R_local, transl, best = got
    # world-locked joints: their local rotation follows (the hand keeps its world orientation)
    R_world, p = _fk(R_local, transl, J_rest, locks)
    for k in locks:
        R_local[k] = R_world[PARENTS[k]].T @ locks[k]
    R_local = _twist_to_parent(R_local, J_rest, [k for k in free if JOINT_NAMES[k].endswith(("elbow", "knee"))])
    _, p = _fk(R_local, transl, J_rest, {})
    return DragResult(R_local, transl, p, plan)


def _lm(R_local: np.ndarray, transl: np.ndarray, J_rest: np.ndarray, free: Sequence[int], translate: bool,
        locks: dict[int, np.ndarray], terms: Sequence[tuple[int, np.ndarray, float]], stiff: np.ndarray,
        iterations: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Levenberg-Marquardt on the free joints' world-frame turns (and the root translation): the weighted
    position terms plus ``stiff`` times the squared turn from the start. Returns (R_local, transl, cost)."""
    n = 3 * len(free) + (3 if translate else 0)
    anc = [_ancestors_inclusive(t[0]) for t in terms]
    x = np.zeros(n)
    mu = 1e-3
    R_world, p = _fk(R_local, transl, J_rest, locks)

    def cost(pw: np.ndarray, xv: np.ndarray) -> float:
        r = np.concatenate([w * (pw[k] - g) for k, g, w in terms])
        return float(r @ r + (stiff * xv) @ xv)

    current = cost(p, x)
    for _ in range(iterations):
        r = np.concatenate([w * (p[k] - g) for k, g, w in terms])
        Jm = np.zeros((len(r), n))
        for t, (k, _g, w) in enumerate(terms):
            chain_up = anc[t]
            for c, f in enumerate(free):
                if f not in chain_up:
                    continue
                # the first world-locked joint below f on the way to k stops the turn: k moves with it
                pivot = k
                for a in reversed(chain_up[1:chain_up.index(f)]):
                    if a in locks:
                        pivot = a
                        break
                Jm[3 * t:3 * t + 3, 3 * c:3 * c + 3] = -w * _skew(p[pivot] - p[f])
            if translate:
                Jm[3 * t:3 * t + 3, n - 3:] = w * np.eye(3)
        A = Jm.T @ Jm + np.diag(stiff)
        g = Jm.T @ r + stiff * x
        if float(np.abs(g).max()) < 1e-12:
            break
        step = np.zeros(n)
        while mu <= 1e6:
            step = -np.linalg.solve(A + mu * np.eye(n), g)
            R_try, t_try = _apply(R_local, transl, R_world, free, step, translate)
            Rw_try, p_try = _fk(R_try, t_try, J_rest, locks)
            new = cost(p_try, x + step)
            if new < current:
                R_local, transl, R_world, p, x, current = R_try, t_try, Rw_try, p_try, x + step, new
                mu = max(mu / 3.0, 1e-9)
                break
            mu *= 4.0
        if mu > 1e6 or float(np.abs(step).max()) < 1e-9:
            break
    return R_local, transl, current


def _index(joint: int | str) -> int:
    return JOINT_INDEX[joint] if isinstance(joint, str) else int(joint)


def _stiffness(k: int) -> float:
    name = JOINT_NAMES[k]
    for kind, value in _STIFF.items():
        if name.endswith(kind):
            return value
    return 0.05


def _ancestors_inclusive(k: int) -> list[int]:
    """[k, parent(k), ..., 0]."""
    out = [k]
    while PARENTS[out[-1]] >= 0:
        out.append(PARENTS[out[-1]])
    return out


def _apply(R_local: np.ndarray, transl: np.ndarray, R_world: np.ndarray, free: Sequence[int], step: np.ndarray,
           translate: bool) -> tuple[np.ndarray, np.ndarray]:
    """Turn each free joint by its world-frame rotation vector of ``step`` (about the joint)."""
    R_new = R_local.copy()
    for c, f in enumerate(free):
        D = axis_angle_to_matrix_np(step[3 * c:3 * c + 3])
        if PARENTS[f] < 0:
            R_new[f] = D @ R_local[f]
        else:
            Rp = R_world[PARENTS[f]]
            R_new[f] = Rp.T @ D @ Rp @ R_local[f]
    t_new = transl + step[-3:] if translate else transl
    return R_new, t_new


def _twist_to_parent(R_local: np.ndarray, J_rest: np.ndarray, hinges: Sequence[int]) -> np.ndarray:
    """:func:`workflows.scene.edits.hinge_twist_to_parent`'s rule in numpy: each hinge's turn about its parent
    bone moves into the parent (positions and world rotations unchanged)."""
    from scipy.spatial.transform import Rotation

    R_local = R_local.copy()
    for j in hinges:
        par = PARENTS[j]
        a = J_rest[j] - J_rest[par]
        a = a / max(np.linalg.norm(a), 1e-12)
        q = Rotation.from_matrix(R_local[j]).as_quat()  # x, y, z, w
        twist = np.concatenate([(q[:3] @ a) * a, q[3:]])
        norm = np.linalg.norm(twist)
        if norm < 1e-9:
            continue
        T = Rotation.from_quat(twist / norm).as_matrix()
        R_local[j] = T.T @ R_local[j]
        R_local[par] = R_local[par] @ T
    return R_local
