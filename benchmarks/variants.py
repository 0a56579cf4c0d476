"""Variants (``IKSolver.sample``, k = 4, 32 candidates) on CMU poses: time, effector error, diversity, best-of-K.

Poses: 4 frames (evenly spaced) of each of the first ``--files`` clips of a split of ``<shared>/data/cmu/split.json``
(``--split test``, default; ``validation`` for choices), retargeted to SMPL. Effectors: exact position effectors at
the true head, wrists and pelvis (the legs, elbows and knees left free, as for a VR user). Per pose: the time of one
``sample`` call (one CPU thread), the number of variants, the largest user-effector residual over all variants
(mm), the mean and smallest mean-joint distance between two variants (cm), and the mean joint error against the
true pose of variant 0 (the plain solve) and of the best of the K variants (best-of-K: how often one of the offered
alternatives is closer to what the person really did). ``--guide-tolerance`` overrides
:data:`smplik.variants.GUIDE_TOLERANCE` (the validation sweep).

Prints a summary and writes ``benchmarks/results/variants[_SPLIT][_tolT].json`` (test at the default tolerance:
``variants.json``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save, shared_dir  # noqa: E402

import smplik.variants as variants_mod  # noqa: E402
from smplik.conventions import Gender  # noqa: E402
from smplik.effectors import Effector  # noqa: E402
from smplik.pose import Pose  # noqa: E402
from smplik.solver import IKSolver, effector_residuals  # noqa: E402

EFFECTOR_JOINTS = ("head", "left_wrist", "right_wrist", "pelvis")
K = 4
FRAMES_PER_FILE = 4


def split_poses(split: str, files: int) -> list[Pose]:
    """FRAMES_PER_FILE evenly spaced frames of the first ``files`` clips of ``split``, retargeted to SMPL."""
    from smplik.data.retarget import retarget_bvh

    cmu = shared_dir() / "data" / "cmu"
    names = json.loads((cmu / "split.json").read_text())[split]["files"]
    poses = []
    for name in names[:: max(1, len(names) // files)][:files]:
        clip = retarget_bvh(cmu / name, "cmu")
        for f in np.linspace(0, clip.num_frames - 1, FRAMES_PER_FILE + 2).round().astype(int)[1:-1]:
            poses.append(Pose(clip.global_orient[f].astype(float), clip.body_pose[f].astype(float),
                              clip.transl[f].astype(float), clip.betas.astype(float), clip.gender or Gender.NEUTRAL))
    return poses


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("test", "validation"), default="test")
    parser.add_argument("--files", type=int, default=8)
    parser.add_argument("--guide-tolerance", type=float, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if not (shared_dir() / "data" / "cmu" / "split.json").is_file():
        print(f"skipped: no CMU split at {shared_dir() / 'data' / 'cmu'}")
        return
    if args.guide_tolerance is not None:
        variants_mod.GUIDE_TOLERANCE = args.guide_tolerance
    from workflows.scene.recovery import TargetPose

    solver = IKSolver.load()
    poses = split_poses(args.split, args.files)
    solver.sample([Effector.position("head", (0, 1.6, 0))], K)  # warm-up (kernels, sessions)
    rows = []
    for truth in poses:
        joints = TargetPose.from_pose(truth).p_world.double().numpy()
        effectors = [Effector.position(j, joints[Effector.position(j, (0, 0, 0)).joint]) for j in EFFECTOR_JOINTS]
        t0 = time.perf_counter()
        out = solver.sample(effectors, K, betas=truth.betas, gender=truth.gender, seed=0)
        dt = time.perf_counter() - t0
        pair = [float(np.linalg.norm(a.joints - b.joints, axis=1).mean())
                for i, a in enumerate(out) for b in out[i + 1:]]
        err = [float(np.linalg.norm(p.joints - joints, axis=1).mean()) for p in out]
        rows.append({"ms": dt * 1000, "count": len(out),
                     "max_residual_mm": max(r.value for p in out for r in effector_residuals(p, effectors,
                                                                                            solver.bodies)),
                     "mean_pair_cm": 100 * statistics.fmean(pair) if pair else 0.0,
                     "min_pair_cm": 100 * min(pair) if pair else 0.0,
                     "variant0_mm": 1000 * err[0], "best_of_k_mm": 1000 * min(err)})

    def mean(key: str) -> float:
        return round(statistics.fmean(r[key] for r in rows), 2)

    summary = {"split": args.split, "poses": len(rows), "k": K, "candidates": 32,
               "guide_tolerance": variants_mod.GUIDE_TOLERANCE, "effectors": list(EFFECTOR_JOINTS),
               "p50_ms": round(statistics.median(r["ms"] for r in rows), 1),
               "mean_count": mean("count"), "poses_with_k": sum(r["count"] == K for r in rows),
               "worst_residual_mm": round(max(r["max_residual_mm"] for r in rows), 2),
               "mean_max_residual_mm": mean("max_residual_mm"), "mean_pair_distance_cm": mean("mean_pair_cm"),
               "mean_min_pair_distance_cm": mean("min_pair_cm"), "variant0_mean_joint_error_mm": mean("variant0_mm"),
               "best_of_k_mean_joint_error_mm": mean("best_of_k_mm"),
               "best_is_not_variant0": sum(r["best_of_k_mm"] < r["variant0_mm"] for r in rows)}
    for key, value in summary.items():
        print(f"{key:32s} {value}")
    name = "variants" + ("" if args.split == "test" else f"_{args.split}")
    if args.guide_tolerance is not None:
        name += f"_tol{args.guide_tolerance:g}"
    print(f"wrote {save(name, {'summary': summary, 'poses': rows})}")


if __name__ == "__main__":
    main()
