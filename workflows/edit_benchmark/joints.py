"""The edit benchmark's joint drags: elbows, knees, head, neck, spine and pelvis dragged on real motion.

For each real pose pair (frames ``t0`` and ``t1 = t0 + gap`` of a held-out clip, seeded draw) and each joint of
:data:`JOINTS`, the scene is frame ``t0`` with the hands and feet pinned (exact position effectors, as a user
holds them) and the joint is dragged to a target taken from the real motion that the moved chain can reach
with the rest of the body where it was: frame ``t0`` with frame ``t1``'s local rotations of the chain's
joints (:data:`TARGET_CHAINS`: for an elbow the collar's and shoulder's, for the head the spine's and neck's);
for the pelvis frame ``t1``'s pelvis height and forward/sideways move relative to the feet (pelvis frame of
``t0``), the feet staying planted. The drag is solved as the editor solves it (:func:`workflows.scene.edits.
drag_effector` relaxes the chain's stale effectors, :func:`workflows.scene.edits.solve_edit`) and, for
comparison, by the previous release's solve of such drags (``before``: the network's chain on the scene's pose,
refined, :func:`workflows.scene.edits.solve_limb_edit`).

Figures per joint (every drag is also a row of ``pairs``): CPU time per drag (one at a time, as the editor
solves them), the dragged joint's distance to its target (mm) and the largest displacement of the joints
outside the moved chain (mm: every joint no free rotation of :func:`smplik.chain_drag.drag_plan` carries, and the
pinned effectors' joints); the pelvis rows also say whether the target was reachable with the feet planted.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from smplik.conventions import JOINT_INDEX, NUM_BETAS, Gender

JOINTS: tuple[str, ...] = ("left_elbow", "right_elbow", "left_knee", "right_knee", "head", "neck", "spine1",
                           "spine2", "spine3", "pelvis")
"""The dragged joints."""
TARGET_CHAINS: dict[str, tuple[str, ...]] = {
    "left_elbow": ("left_collar", "left_shoulder"), "right_elbow": ("right_collar", "right_shoulder"),
    "left_knee": ("left_hip",), "right_knee": ("right_hip",),
    "head": ("spine1", "spine2", "spine3", "neck"), "neck": ("spine1", "spine2", "spine3"),
    "spine1": (), "spine2": ("spine1",), "spine3": ("spine1", "spine2"), "pelvis": (),
}
"""The joints whose frame-t1 local rotations place each dragged joint's target (module docstring)."""
PINNED: tuple[str, ...] = ("left_wrist", "right_wrist", "left_ankle", "right_ankle")
"""The scene's exact position effectors (hands and feet pinned)."""
GAP_S = 0.5
"""Time between a pair's frames (s)."""
MAX_MOVE_M = 0.25
"""Targets farther than this from the joint are left out (not a drag, a new pose)."""
MIN_MOVE_M = 0.02
"""Targets nearer than this are left out (nothing to drag)."""


def _fk(aa: np.ndarray, transl: np.ndarray, J_rest: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    from smplik.chain_drag import _fk as fk

    return fk(Rotation.from_rotvec(aa).as_matrix(), transl, J_rest, {})[1]


def drag_targets(aa0: np.ndarray, tr0: np.ndarray, aa1: np.ndarray, tr1: np.ndarray, J_rest: np.ndarray,
                 joint: str) -> np.ndarray:
    """The target (3,) of ``joint`` for the pair of poses (local axis-angle (24, 3), transl (3,)) (module
    docstring)."""
    from scipy.spatial.transform import Rotation

    j = JOINT_INDEX[joint]
    if joint in ("pelvis", "spine1"):
        p0, p1 = _fk(aa0, tr0, J_rest), _fk(aa1, tr1, J_rest)
        feet = [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]]
        R0 = Rotation.from_rotvec(aa0[0]).as_matrix()
        R1 = Rotation.from_rotvec(aa1[0]).as_matrix()
        rel1 = R1.T @ (p1[j] - p1[feet].mean(0))  # pelvis frame of t1, relative to the feet
        rel0 = R0.T @ (p0[j] - p0[feet].mean(0))
        return p0[j] + R0 @ (rel1 - rel0)
    aa = aa0.copy()
    for name in TARGET_CHAINS[joint]:
        aa[JOINT_INDEX[name]] = aa1[JOINT_INDEX[name]]
    return _fk(aa, tr0, J_rest)[j]


def reachable(aa0: np.ndarray, tr0: np.ndarray, aa1: np.ndarray, J_rest: np.ndarray, joint: str,
              target: np.ndarray) -> bool:
    """Whether the pinned hands and feet can stay while ``joint`` reaches ``target``: in the pose that meets it
    (frame t0 with the chain's frame-t1 rotations, or translated for the pelvis and spine1) every pinned end
    whose limb is not the dragged one is within its limb's length (less 1 mm) of the limb's root."""
    j = JOINT_INDEX[joint]
    p0 = _fk(aa0, tr0, J_rest)
    if joint in ("pelvis", "spine1"):
        p = p0 + (target - p0[j])
    else:
        aa = aa0.copy()
        for name in TARGET_CHAINS[joint]:
            aa[JOINT_INDEX[name]] = aa1[JOINT_INDEX[name]]
        p = _fk(aa, tr0, J_rest)
    limbs = {"left_wrist": ("left_shoulder", "left_elbow"), "right_wrist": ("right_shoulder", "right_elbow"),
             "left_ankle": ("left_hip", "left_knee"), "right_ankle": ("right_hip", "right_knee")}
    for end, (root, mid) in limbs.items():
        if mid == joint:
            continue
        r, m, e = JOINT_INDEX[root], JOINT_INDEX[mid], JOINT_INDEX[end]
        length = np.linalg.norm(J_rest[m] - J_rest[r]) + np.linalg.norm(J_rest[e] - J_rest[m])
        if np.linalg.norm(p0[e] - p[r]) > length - 1e-3:
            return False
    return True


def joint_drag_benchmark(clips: Sequence[Any], solver: Any, *, pairs_per_joint: int = 40, seed: int = 0,
                         joints: Sequence[str] = JOINTS, before: bool = True,
                         progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Drag every joint of ``joints`` on ``pairs_per_joint`` real pose pairs of ``clips``
    (:class:`workflows.edit_benchmark.run.EditClip`); the results document part (JSON-ready): per joint the
    figures of the editor's drag (``smplik``) and of ``before``, and per pair its clip, frames and numbers."""
    from smplik.chain_drag import _subtree, drag_plan
    from smplik.effectors import Effector
    from smplik.pose import Pose
    from workflows.scene.edits import drag_effector, solve_edit, solve_limb_edit

    say = progress or (lambda _msg: None)
    J_rest = solver.bodies[Gender.NEUTRAL].rest_joints(torch.zeros(NUM_BETAS, dtype=torch.float64)).numpy()
    rng = np.random.default_rng(seed)
    frames = [(c, t) for c, clip in enumerate(clips) for t in range(0, len(clip.pose) - int(GAP_S * clip.fps))]
    order = rng.permutation(len(frames))
    out: dict[str, Any] = {"joints": {}, "pairs": [], "settings": {
        "pairs_per_joint": pairs_per_joint, "seed": seed, "gap_s": GAP_S, "pinned": list(PINNED),
        "max_move_m": MAX_MOVE_M, "min_move_m": MIN_MOVE_M, "clips": len(clips)}}
    for joint in joints:
        j = JOINT_INDEX[joint]
        rows: list[dict[str, Any]] = []
        problems = []
        for idx in order:
            if len(problems) >= pairs_per_joint:
                break
            c, t0 = frames[int(idx)]
            clip = clips[c]
            t1 = t0 + int(round(GAP_S * clip.fps))
            aa0, tr0 = clip.pose[t0].double().numpy(), clip.transl[t0].double().numpy()
            aa1, tr1 = clip.pose[t1].double().numpy(), clip.transl[t1].double().numpy()
            p0 = _fk(aa0, tr0, J_rest)
            target = drag_targets(aa0, tr0, aa1, tr1, J_rest, joint)
            move = float(np.linalg.norm(target - p0[j]))
            if not MIN_MOVE_M <= move <= MAX_MOVE_M:
                continue
            pinned = tuple(Effector.position(n, p0[JOINT_INDEX[n]]) for n in PINNED)
            effs, _, _ = drag_effector(pinned, Effector.position(joint, target))
            previous = Pose(aa0[0], aa0[1:], tr0, np.zeros(NUM_BETAS), Gender.NEUTRAL)
            problems.append((c, t0, t1, p0, target, move, list(effs), previous,
                             reachable(aa0, tr0, aa1, J_rest, joint, target)))
        if not problems:
            continue
        import time

        ms: list[float] = []
        solved = []
        for p in problems:  # one drag at a time, as the editor solves them: CPU time per drag
            t = time.process_time()
            solved += solve_edit(solver, [p[6]], [p[7]], [j])
            ms.append(1000.0 * (time.process_time() - t))
        methods = {"smplik": solved}
        if before:
            methods["before"] = solve_limb_edit(solver, [p[6] for p in problems], [p[7] for p in problems],
                                                [j] * len(problems))
        figures: dict[str, dict[str, list[float]]] = {m: {"target": [], "outside": []} for m in methods}
        reach = np.array([p[8] for p in problems])
        for i, (c, t0, t1, p0, target, move, effs, _prev, ok) in enumerate(problems):
            held = [e.joint for e in effs if e.tolerance < 1.0 and e.joint != j]
            plan = drag_plan(j, p0, held)
            outside = sorted(set(range(len(p0))) - _subtree(list(plan.free)) | set(held))
            row: dict[str, Any] = {"joint": joint, "clip": clips[c].name, "t0": t0, "t1": t1,
                                   "move_mm": round(1000 * move, 1), "reachable": bool(ok)}
            for m, poses in methods.items():
                p = _fk(np.concatenate([poses[i].global_orient[None], poses[i].body_pose]), poses[i].transl,
                        J_rest)
                err = 1000 * float(np.linalg.norm(p[j] - target))
                disp = 1000 * float(np.linalg.norm(p[outside] - p0[outside], axis=1).max())
                figures[m]["target"].append(err)
                figures[m]["outside"].append(disp)
                row[m] = {"target_mm": round(err, 2), "outside_mm": round(disp, 2)}
            rows.append(row)
        out["joints"][joint] = {m: _summary(f["target"], f["outside"], reach) | {
            "move_mm_median": round(float(np.median([1000 * p[5] for p in problems])), 1)}
            for m, f in figures.items()}
        out["joints"][joint]["smplik"] |= {"cpu_ms_median": round(float(np.median(ms)), 1),
                                           "cpu_ms_max": round(float(np.max(ms)), 1)}
        out["pairs"] += rows
        s = out["joints"][joint]["smplik"]
        say(f"{joint:12s} {s['pairs']:3d} drags ({s['reachable']} reachable)  target {s['target_mm_median']:5.1f} mm "
            f"median, {s['target_mm_max']:6.1f} max, {100 * s['target_within_10mm']:.0f}% <= 10 mm (reachable: "
            f"{s['reachable_target_mm_max']:.1f} max); outside the chain {s['outside_mm_max']:5.2f} mm max; "
            f"{s['cpu_ms_median']:.0f} ms CPU per drag (median, max {s['cpu_ms_max']:.0f})")
    return out


def _summary(target: Sequence[float], outside: Sequence[float], reach: np.ndarray) -> dict[str, float | int]:
    t, o = np.asarray(target), np.asarray(outside)
    tr = t[reach] if reach.any() else np.zeros(1)
    return {"pairs": len(t), "reachable": int(reach.sum()),
            "reachable_target_mm_median": round(float(np.median(tr)), 2),
            "reachable_target_mm_max": round(float(tr.max()), 2),
            "reachable_target_within_10mm": round(float((tr <= 10.0).mean()), 3),
            "target_mm_median": round(float(np.median(t)), 2),
            "target_mm_p95": round(float(np.percentile(t, 95)), 2), "target_mm_max": round(float(t.max()), 2),
            "target_within_10mm": round(float((t <= 10.0).mean()), 3),
            "outside_mm_median": round(float(np.median(o)), 2), "outside_mm_max": round(float(o.max()), 2),
            "outside_within_5mm": round(float((o <= 5.0).mean()), 3)}
