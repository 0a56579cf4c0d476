"""Joint positions -> SMPL animation against a known truth, and an SMPLify-style optimisation baseline.

Each held-out CMU clip (test subjects of ``../shared/data/cmu/split.json``; :data:`CLIPS`) is retargeted onto
SMPL (:func:`smplik.data.retarget.retarget_bvh`, 20 frames/s: HumanML3D's rate, at most ``--frames`` frames): the
truth. Its first 22 joints (HumanML3D's layout, y-up metres) are the input, as a text-to-motion model writes them.

Methods, on the same joints:

* ``smplik``: what ``smplik scene animate joints.npy`` does (:mod:`workflows.animation.joint_motion`): SMPL-SI's
  body for the bone lengths, the SMPL-IK solver per frame (all frames in one batch), then the animation's glitch
  repair and foot locks, no smoothing (joints a model made are smooth already: ``AnimateConfig.
  model_motion_smoothing``) (:func:`workflows.animation.clips.animation_from_clip`); keyframe effector recovery
  is switched off here (an editing aid, not part of the fit).
* ``smplik_adaptive``: the same with the video default's ``adaptive`` smoothing (``--smoothing adaptive``).
* ``smplik_solve_only``: the same without the cleaning (no glitch repair, smoothing or foot locks): the solver's
  own accuracy.
* ``smplify``: an SMPLify-style fit as text-to-motion projects do (MDM's ``joints2smpl``): Adam on every frame's
  axis-angle pose and translation (torch, CPU, all frames at once), minimising the squared joint distances plus
  a pose prior (``|theta|^2`` weight :data:`PRIOR`) and a temporal smoothness term (weight :data:`SMOOTH`), on
  the same SMPL-SI body, from the zero pose at the joints' pelvis; :data:`ITERATIONS` steps.

Metrics per clip against the truth: MPJPE (mm, the 22 input joints, world frame, no alignment) and over all 24
joints (the hands are not in the input), joint-angle error (degrees, the geodesic angle between the true and
fitted local rotations of the 21 body joints below the pelvis plus the pelvis' global rotation; the twist of a
limb about its own bone is not in joint positions, so part of this error is not recoverable by any method),
frames per CPU second (process CPU time of the method's fit; model loading and compilation excluded by an
untimed warm-up run) and CPU seconds.

Prints a table and writes ``benchmarks/results/joints_to_smpl.json``; without the CMU data it says so and exits 0.
Run: ``nice -n 10 python benchmarks/joints_to_smpl.py`` (a few CPU minutes).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _common import save, shared_dir  # noqa: E402

from smplik.conventions import Gender  # noqa: E402
from smplik.pose import Pose  # noqa: E402

FPS = 20.0
CLIPS = {"02_01": "walk", "26_01": "walk", "02_05": "punch", "02_04": "jump", "09_06": "run", "10_04": "kick"}
"""Test-split clips (subjects 02, 09, 10, 26)."""
ITERATIONS = 300
PRIOR = 1e-3
SMOOTH = 1e-1
LEARNING_RATE = 0.05


def load_truth(name: str, frames: int) -> list[Pose] | None:
    from smplik.data.retarget import retarget_bvh

    path = shared_dir() / "data" / "cmu" / f"{name}.bvh"
    if not path.is_file():
        return None
    clip = retarget_bvh(path, "cmu", fps=FPS)
    betas = np.zeros(10) if clip.betas is None else np.asarray(clip.betas, dtype=np.float64)
    rows = range(clip.motion_start, min(clip.global_orient.shape[0], clip.motion_start + frames))
    return [Pose(clip.global_orient[i].astype(float), clip.body_pose[i].astype(float), clip.transl[i].astype(float),
                 betas, clip.gender or Gender.NEUTRAL) for i in rows]


def local_rotations(go: np.ndarray, bp: np.ndarray) -> np.ndarray:
    from workflows.animation.clips import axis_angle_to_local

    return axis_angle_to_local(go, bp.reshape(len(go), 23, 3))


def joints(go: np.ndarray, bp: np.ndarray, transl: np.ndarray, betas: np.ndarray, scale: float = 1.0) -> np.ndarray:
    from workflows.animation.clips import joints_of, rest_joints

    return joints_of(local_rotations(go, bp), transl, rest_joints(betas, Gender.NEUTRAL)) * scale


def angle_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Mean geodesic angle (degrees) over frames and the 22 joints (pelvis global, 21 local) of (T, 24, 3, 3)."""
    rel = np.einsum("...ji,...jk->...ik", R_a[:, :22], R_b[:, :22])
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    return float(np.degrees(np.arccos(cos)).mean())


def metrics(go, bp, transl, betas, scale, truth: list[Pose], P_true: np.ndarray) -> dict[str, float]:
    P = joints(go, bp, transl, betas, scale)
    R = local_rotations(go, bp)
    R_true = local_rotations(np.stack([p.global_orient for p in truth]), np.stack([p.body_pose for p in truth]))
    err = np.linalg.norm(P - P_true, axis=-1)
    return {"mpjpe_22_mm": float(err[:, :22].mean() * 1000), "mpjpe_24_mm": float(err.mean() * 1000),
            "joint_angle_error_deg": angle_error_deg(R, R_true)}


def run_smplik(J: np.ndarray, solver, truth: list[Pose], P_true: np.ndarray, clean: bool = True,
               model_smoothing: str | None = "none") -> dict:
    from workflows.animation.clean import CleanConfig
    from workflows.animation.clips import AnimateConfig
    from workflows.animation.joint_motion import JointMotion
    from workflows.animation.run import joint_animation
    from workflows.scene.recovery import RecoveryConfig

    motion = JointMotion({"0": J}, np.arange(22), FPS, "joints")
    config = AnimateConfig(CleanConfig() if clean else CleanConfig(smoothing="none", foot_lock=False,
                                                                   repair_glitches=False),
                           model_motion_smoothing=model_smoothing, keyframe_threshold_m=10.0, max_keyframe_share=1e-9,
                           recovery=RecoveryConfig(max_effectors=1, threshold=0.03))
    t0 = time.process_time()
    anim, _ = joint_animation(motion, "truth", solver, config=config)
    cpu = time.process_time() - t0
    t = anim.tracks[0]
    row = metrics(t.global_orient, t.body_pose, t.transl, t.betas, t.scale, truth, P_true)
    return {**row, "cpu_s": cpu, "frames_per_cpu_s": len(J) / cpu, "scale": float(t.scale)}


def run_smplify(J: np.ndarray, truth: list[Pose], P_true: np.ndarray, betas: np.ndarray, scale: float) -> dict:
    from smplik.kinematics import forward_kinematics
    from smplik.rotations import axis_angle_to_matrix
    from workflows.animation.clips import rest_joints

    t0 = time.process_time()
    target = torch.as_tensor(J / scale, dtype=torch.float32)
    J_rest = torch.as_tensor(rest_joints(betas, Gender.NEUTRAL), dtype=torch.float32)
    T = len(J)
    pose = torch.zeros(T, 24, 3, requires_grad=True)
    transl = (target[:, 0] - J_rest[0]).clone().requires_grad_(True)
    opt = torch.optim.Adam([pose, transl], lr=LEARNING_RATE)
    for _ in range(ITERATIONS):
        opt.zero_grad()
        _, p = forward_kinematics(axis_angle_to_matrix(pose), J_rest, transl)
        loss = ((p[:, :22] - target) ** 2).sum(-1).mean() + PRIOR * (pose[:, 1:] ** 2).sum(-1).mean()
        if T > 2:
            loss = loss + SMOOTH * ((p[2:] - 2 * p[1:-1] + p[:-2]) ** 2).sum(-1).mean()
        loss.backward()
        opt.step()
    cpu = time.process_time() - t0
    aa = pose.detach().double().numpy()
    row = metrics(aa[:, 0], aa[:, 1:], transl.detach().double().numpy(), betas, scale, truth, P_true)
    return {**row, "cpu_s": cpu, "frames_per_cpu_s": T / cpu, "iterations": ITERATIONS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=120, help="at most this many frames per clip (20 frames/s)")
    parser.add_argument("--clips", default=",".join(CLIPS))
    args = parser.parse_args()
    torch.set_num_threads(1)
    from workflows.animation.joint_motion import fit_body
    from workflows.cli_shared import _solver

    solver = _solver(None)
    warm = load_truth(args.clips.split(",")[0], 12)  # compile and load everything once, untimed
    if warm is not None:
        P_warm = joints(np.stack([p.global_orient for p in warm]), np.stack([p.body_pose for p in warm]),
                        np.stack([p.transl for p in warm]), warm[0].betas)
        run_smplik(P_warm[:, :22], solver, warm, P_warm)
        run_smplik(P_warm[:, :22], solver, warm, P_warm, clean=False)
    rows = []
    for name in args.clips.split(","):
        truth = load_truth(name, args.frames)
        if truth is None:
            print(f"no CMU data ({shared_dir() / 'data' / 'cmu'}); nothing measured.")
            return
        go = np.stack([p.global_orient for p in truth])
        bp = np.stack([p.body_pose for p in truth])
        P_true = joints(go, bp, np.stack([p.transl for p in truth]), truth[0].betas)
        J = P_true[:, :22]
        ours = run_smplik(J, solver, truth, P_true)
        solve_only = run_smplik(J, solver, truth, P_true, clean=False)
        adaptive = run_smplik(J, solver, truth, P_true, model_smoothing=None)
        body = fit_body(J, np.arange(22))
        base = run_smplify(J, truth, P_true, body.betas, body.scale)
        rows.append({"clip": name, "label": CLIPS.get(name, ""), "frames": len(truth), "smplik": ours,
                     "smplik_solve_only": solve_only, "smplik_adaptive": adaptive, "smplify": base})
        print(f"{name} {CLIPS.get(name, ''):6s} {len(truth):4d} frames | smplik MPJPE {ours['mpjpe_22_mm']:6.1f} mm "
              f"(24 joints {ours['mpjpe_24_mm']:5.1f}), angle {ours['joint_angle_error_deg']:5.1f} deg, "
              f"{ours['frames_per_cpu_s']:6.1f} frames/CPU s | smplify MPJPE {base['mpjpe_22_mm']:6.1f} mm "
              f"(24 {base['mpjpe_24_mm']:5.1f}), angle {base['joint_angle_error_deg']:5.1f} deg, "
              f"{base['frames_per_cpu_s']:6.1f} frames/CPU s | solve only MPJPE {solve_only['mpjpe_22_mm']:6.1f} mm, "
              f"angle {solve_only['joint_angle_error_deg']:5.1f} deg | adaptive smoothing MPJPE "
              f"{adaptive['mpjpe_22_mm']:6.1f} mm", flush=True)
    summary = {m: {k: float(np.mean([r[m][k] for r in rows])) for k in
                   ("mpjpe_22_mm", "mpjpe_24_mm", "joint_angle_error_deg", "frames_per_cpu_s")}
               for m in ("smplik", "smplik_solve_only", "smplik_adaptive", "smplify")}
    print("mean:", summary)
    save("joints_to_smpl", {"fps": FPS, "max_frames": args.frames, "smplify": {"iterations": ITERATIONS,
                            "prior": PRIOR, "smooth": SMOOTH, "lr": LEARNING_RATE}, "clips": rows,
                            "mean": summary})


if __name__ == "__main__":
    main()
