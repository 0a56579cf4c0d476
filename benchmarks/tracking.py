"""Full body from 4 trackers on held-out CMU motion at 60 Hz: accuracy, foot skating, anomalies, per-frame cost.

Data: the test split of ``configs/split_cmu_dance.json`` (CMU subjects never seen in training), read from
``../shared/data/cmu`` into a 60 Hz pose cache (``--cache``; built once when missing), up to ``--frames`` frames
per clip, each clip on its own random body (beta ~ N(0, I), random gender; seeded). Trackers: head,
left_wrist, right_wrist, pelvis world positions and rotations of the truth (:func:`signals_from_motion`),
exact or with noise (position sigma 1 cm, rotation 2 degrees, per frame).

Methods:
* ``ours``: the shipped tracking model, deterministic (``samples=1``), with foot locks (default runtime: the
  offline locks of :func:`smplik.tracking.runtime.track_sequence`);
* ``ours_causal``: the same with the streaming (causal) foot locks of :meth:`Tracker.step` (``offline_lock=False``);
* ``ours_16``: 16 samples with sample selection (look-ahead 10 frames);
* ``ours_fit``: deterministic with the tracker fit (root, wrists and head set from the trackers; ablation);
* ``ik``: the shipped per-frame IK solver (``IKSolver.load()``) given the 4 trackers as exact position and
  rotation effectors (8 effectors), frame by frame, and ``ik_clean``: that motion after the animation
  pipeline's cleaning (:func:`workflows.animation.clean.sequence_clean`, foot locks included);
* ``mlp``: an AvatarPoser-style MLP over the last 20 frames, trained on the same data for the same wall-clock
  budget, concurrently, on one thread (``--mlp``; skipped when the file is absent).

Metrics (world frame, no alignment, 24 joints): MPJPE (mm), MPJVE (mean joint velocity error, cm/s), MPJAE
(mean joint acceleration error, cm/s^2), MPJAE of the legs (hips, knees, ankles, feet), foot skating (mean foot
speed on the truth's contact frames, :func:`workflows.animation.clean.foot_contacts` on the truth; mm/frame) and
the anomaly rate (share of frames whose :func:`smplik.tracking.runtime.anomaly_scores` exceeds
:data:`ANOMALY_THRESHOLD`). Cost: per-frame wall time of ``Tracker.step`` on one thread, p50 and p90.

Usage: ``python benchmarks/tracking.py [--frames 600] [--mlp PATH] [--split test]`` ->
``benchmarks/results/tracking.json`` (``tracking_validation.json`` for ``--split validation``, the split on which
the runtime's parameters are chosen).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save, shared_dir  # noqa: E402

from smplik.body_model import BodyModelSet  # noqa: E402
from smplik.conventions import JOINT_INDEX, Gender  # noqa: E402
from smplik.kinematics import forward_kinematics  # noqa: E402
from smplik.rotations import axis_angle_to_matrix  # noqa: E402
from smplik.tracking.config import TrackerRuntimeConfig  # noqa: E402
from smplik.tracking.data import body_vector  # noqa: E402
from smplik.tracking.features import decode_pose, tracker_features  # noqa: E402
from smplik.tracking.io import signals_from_motion  # noqa: E402
from smplik.tracking.model_io import load_model  # noqa: E402
from smplik.tracking.runtime import ANOMALY_THRESHOLD, Tracker, anomaly_scores, track_sequence  # noqa: E402
from workflows.animation.clean import CleanConfig, foot_contacts, foot_skating, sequence_clean  # noqa: E402

LEGS = [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("hip", "knee", "ankle", "foot")]
NOISES = {"exact": (0.0, 0.0), "noisy": (0.01, 2.0)}


def joints(R: np.ndarray, transl: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Rw, p = forward_kinematics(torch.as_tensor(R, dtype=torch.float64), torch.as_tensor(J, dtype=torch.float64),
                               torch.as_tensor(transl, dtype=torch.float64))
    return Rw.numpy(), p.numpy()


def metrics(R: np.ndarray, p: np.ndarray, truth: np.ndarray, contact: np.ndarray, fps: float, lo: np.ndarray,
            hi: np.ndarray) -> dict[str, float]:
    v, vt = np.diff(p, axis=0) * fps, np.diff(truth, axis=0) * fps
    a, at = np.diff(p, 2, axis=0) * fps ** 2, np.diff(truth, 2, axis=0) * fps ** 2
    acc = np.linalg.norm(a - at, axis=-1)
    score = anomaly_scores(R.astype(np.float32), p.astype(np.float32), lo, hi)
    return {"mpjpe_mm": 1000 * float(np.linalg.norm(p - truth, axis=-1).mean()),
            "mpjve_cm_s": 100 * float(np.linalg.norm(v - vt, axis=-1).mean()),
            "mpjae_cm_s2": 100 * float(acc.mean()), "legs_mpjae_cm_s2": 100 * float(acc[:, LEGS].mean()),
            "skating_mm_per_frame": 1000 * foot_skating(p, contact), "contact_frames": int(contact.sum()),
            "anomaly_rate": float((score > ANOMALY_THRESHOLD).mean()), "frames": int(p.shape[0])}


def ik_motion(solver, sig, betas: np.ndarray, gender: Gender) -> tuple[np.ndarray, np.ndarray]:
    from smplik.effectors import Effector
    from smplik.tracking.fast import quaternion_to_matrix_np

    R_trk = quaternion_to_matrix_np(sig.rotations)
    lists = [[e for k, name in enumerate(sig.names) for e in (Effector.position(name, sig.positions[t, k]),
                                                               Effector.rotation(name, R_trk[t, k]))]
             for t in range(sig.num_frames)]
    poses = []
    for s in range(0, len(lists), 256):
        poses += solver.solve_batch(lists[s:s + 256], betas=betas, gender=gender)
    aa = np.stack([np.concatenate([p.global_orient[None], p.body_pose]) for p in poses])
    return axis_angle_to_matrix(torch.as_tensor(aa)).numpy(), np.stack([p.transl for p in poses])


def mlp_motion(model, sig, betas: np.ndarray, gender: Gender, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from smplik.tracking.fast import quaternion_to_matrix_np

    p = torch.as_tensor(sig.positions, dtype=torch.float32)
    R = torch.as_tensor(quaternion_to_matrix_np(sig.rotations), dtype=torch.float32)
    x, yaw, origin = tracker_features(p, R, torch.as_tensor(sig.has_rotation), sig.fps)
    body = body_vector(torch.as_tensor(betas, dtype=torch.float32), torch.tensor(gender.index))
    with torch.inference_mode():
        out = model.net(x[None], body[None])[0]
        Rl, transl, _ = decode_pose(out, yaw, origin, torch.as_tensor(J, dtype=torch.float32))
    return Rl.double().numpy(), transl.double().numpy()


def per_frame_cost(samples: int, sig, frames: int = 300, model: str | None = None) -> dict[str, float]:
    torch.set_num_threads(1)
    tracker = Tracker.load(model, config=TrackerRuntimeConfig(samples=samples))  # the default runtime
    tracker.reset(sig.has_rotation)
    times = []
    for t in range(min(frames, sig.num_frames)):
        t0 = time.perf_counter()
        tracker.step(sig.positions[t], sig.rotations[t])
        times.append(time.perf_counter() - t0)
    ms = 1000 * np.asarray(times[20:])
    return {"p50_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)), "frames": int(ms.size)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="/tmp/smplik_tracking_cmu60.npz", help="60 Hz pose cache (built if missing).")
    ap.add_argument("--frames", type=int, default=600, help="Most frames per test clip.")
    ap.add_argument("--mlp", default=None, help="The AvatarPoser-style baseline's model file.")
    ap.add_argument("--model", default=None, help="Tracking model file (default: the shipped 4-tracker model); "
                    "its trackers are the ones synthesised, e.g. smplik/checkpoints/smplik_tracking_3.pt -> "
                    "results tracking_3trackers*.json.")
    ap.add_argument("--split", default="test", choices=("train", "validation", "test"),
                    help="Clips of configs/split_cmu_dance.json to run (choose parameters on validation).")
    ap.add_argument("--no-clean", action="store_true", help="Skip the IK + cleaning baseline.")
    ap.add_argument("--reuse", default=None, help="A previous results file: its ik, ik_clean, mlp and truth rows are "
                    "kept and those methods not rerun (same --frames and cache).")
    args = ap.parse_args()
    torch.set_num_threads(1)
    threadpool_limits(1)  # numpy's BLAS on one thread too (the per-frame path is numpy)
    import shape_inversion.auto_preset  # noqa: F401 - installs preset "auto" (the rig mapper)
    from smplik.data.dataset import build_cache, find_sources, load_cache

    cache = Path(args.cache)
    if not cache.exists():
        root = shared_dir() / "data"
        sources = find_sources(root / "cmu", "bvh") + find_sources(root / "cmu-dance", "bvh")
        build_cache(sources, fps=60, split=Path(__file__).resolve().parents[1] / "configs" / "split_cmu_dance.json",
                    out=cache, skip_unassigned=True)
    data = load_cache(cache).subset(args.split)
    fps = data.fps
    model = load_model(args.model)
    lo, hi = model.pose_lo.numpy(), model.pose_hi.numpy()
    mlp = load_model(args.mlp) if args.mlp and Path(args.mlp).exists() else None
    from smplik.solver import IKSolver

    solver = IKSolver.load()
    bodies = BodyModelSet.load()
    rng = np.random.default_rng(0)
    rows: dict[str, dict[str, list[dict[str, float]]]] = {n: {} for n in NOISES}
    seconds: dict[str, float] = {}
    reused = ("ik", "ik_clean", "mlp", "truth")
    if args.reuse:
        import json

        old = json.loads(Path(args.reuse).read_text())
        if old.get("frames_per_clip") != args.frames:
            raise SystemExit(f"{args.reuse} was run with --frames {old.get('frames_per_clip')}, not {args.frames}.")
        if old.get("split", "test") != args.split:
            raise SystemExit(f"{args.reuse} was run on the {old.get('split', 'test')} split, not {args.split}.")
        for noise in NOISES:
            rows[noise].update({k: v for k, v in old["per_clip"][noise].items() if k in reused})
        seconds.update({k: v for k, v in old["seconds"].items() if k in reused})
        mlp_info = old.get("mlp")
    for c in np.unique(data.clip_id.numpy()):
        clip = data.select(data.clip_id == int(c))
        T = min(args.frames, len(clip))
        betas = rng.standard_normal(10)
        gender = list(Gender)[int(rng.integers(3))]
        J = bodies.rest_joints(torch.as_tensor(betas, dtype=torch.float32), torch.tensor(gender.index)).double().numpy()
        R_true = axis_angle_to_matrix(clip.pose[:T].double()).numpy()
        transl_true = clip.transl[:T].double().numpy()
        _, p_true = joints(R_true, transl_true, J)
        contact = foot_contacts(p_true, fps, CleanConfig())
        name = data.clip_names[int(c)]
        for noise, (sigma_m, sigma_deg) in NOISES.items():
            sig = signals_from_motion(R_true, transl_true, J, model.cfg.trackers, fps, noise_m=sigma_m,
                                      noise_deg=sigma_deg, rng=np.random.default_rng(int(c)))
            methods = {}
            for label, samples, fit, offline in (("ours", 1, False, True), ("ours_causal", 1, False, False),
                                                 ("ours_16", 16, False, True), ("ours_fit", 1, True, True)):
                t0 = time.perf_counter()
                tr = Tracker.load(args.model, betas=betas, gender=gender,
                                  config=TrackerRuntimeConfig(samples=samples, tracker_fit=fit, offline_lock=offline))
                res = track_sequence(tr, sig)
                seconds[label] = seconds.get(label, 0.0) + time.perf_counter() - t0
                methods[label] = (res.R_local, res.transl)
            if args.reuse:
                pass
            else:
                t0 = time.perf_counter()
                methods["ik"] = ik_motion(solver, sig, betas, gender)
                seconds["ik"] = seconds.get("ik", 0.0) + time.perf_counter() - t0
            if not args.no_clean and not args.reuse:
                t0 = time.perf_counter()
                Rc, tc, _ = sequence_clean(*methods["ik"], J, fps, CleanConfig())
                methods["ik_clean"] = (Rc, tc)
                seconds["ik_clean"] = seconds.get("ik_clean", 0.0) + time.perf_counter() - t0
            if mlp is not None and not args.reuse:
                methods["mlp"] = mlp_motion(mlp, sig, betas, gender, J)
            for label, (R, transl) in methods.items():
                m = metrics(R, joints(R, transl, J)[1], p_true, contact, fps, lo, hi)
                rows[noise].setdefault(label, []).append({"clip": name, **m})
                print(f"{noise:6s} {name:16s} {label:12s} MPJPE {m['mpjpe_mm']:6.1f} mm  MPJVE "
                      f"{m['mpjve_cm_s']:6.1f} cm/s  MPJAE {m['mpjae_cm_s2']:7.1f} cm/s2  skating "
                      f"{m['skating_mm_per_frame']:5.2f} mm/f  anomalies {m['anomaly_rate']:.3f}", flush=True)
        if not args.reuse:
            truth_m = metrics(R_true, p_true, p_true, contact, fps, lo, hi)
            rows["exact"].setdefault("truth", []).append({"clip": name, **truth_m})
    summary = {}
    for noise, by_method in rows.items():
        summary[noise] = {}
        for label, rs in by_method.items():
            w = np.array([r["frames"] for r in rs], dtype=float)
            keys = [k for k in rs[0] if k not in ("clip", "frames", "contact_frames")]
            summary[noise][label] = {k: round(float(np.average([r[k] for r in rs], weights=w)), 3) for k in keys}
            summary[noise][label]["frames"] = int(w.sum())
    sig = signals_from_motion(R_true, transl_true, J, model.cfg.trackers, fps)
    cost = {"deterministic": per_frame_cost(1, sig, model=args.model),
            "samples_16": per_frame_cost(16, sig, model=args.model)}
    for noise, table in summary.items():
        print(f"\n{noise}: " + ", ".join(f"{k}" for k in table))
        for label, m in table.items():
            print(f"  {label:12s} " + "  ".join(f"{k} {v}" for k, v in m.items()))
    print("per-frame cost (1 thread):", cost)
    if not args.reuse:
        mlp_info = None if mlp is None else {k: mlp.info.get(k) for k in ("net", "val_mpjpe_mm", "steps", "seconds",
                                                                          "continued_from")}
    stem = "tracking" if len(model.cfg.trackers) == 4 else f"tracking_{len(model.cfg.trackers)}trackers"
    path = save(stem if args.split == "test" else f"{stem}_{args.split}", {
                "trackers": list(model.cfg.trackers), "summary": summary,
                             "split": args.split, "per_clip": rows, "per_frame_cost_ms": cost,
                             "seconds": {k: round(v, 1) for k, v in seconds.items()}, "frames_per_clip": args.frames,
                             "model": {k: model.info.get(k) for k in ("net", "val_mpjpe_mm", "steps", "seconds")},
                             "mlp": mlp_info})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
