"""Full body from VR trackers on held-out CMU motion at 60 Hz, clip by clip, against per-frame IK given the same
trackers: accuracy, arm rotations, tracker misses, foot skating, anomalies, per-frame cost.

Clips: every clip of the test split of ``configs/split_cmu_dance.json`` (CMU subjects 02, 09, 10, 26, 32, never
seen in training: walks, runs, a jump, punches and strikes, swordplay, ...) and the held-out dance ``55_01``
("dance, whirl"; subject 55 is in the validation split, never trained on: the only dance of a subject outside
training), read from ``../shared/data/cmu`` into a 60 Hz pose cache (``--cache``; built from these clips when
missing), the first ``--frames`` frames of each (shortened to keep the run under 10 minutes on one thread), each
clip on its own random body (beta ~ N(0, I), random gender; seeded). The kind of each clip (walk, run, martial
arts, dance, other) comes from the trial description in ``../shared/data/cmu/README.md``.

Trackers: head, wrists (and pelvis for the 4-tracker model) world positions and rotations of the truth
(:func:`signals_from_motion`), exact or with noise (position sigma 1 cm, rotation 2 degrees, per frame). Both
shipped models are run: ``smplik_tracking.pt`` (4 trackers) and ``smplik_tracking_3.pt`` (head and hands).

Methods (per tracker set):
* ``ours``: the shipped model with the default runtime (deterministic, offline foot locks, the end-effector fit
  of :mod:`smplik.tracking.fit`): what ``smplik track`` and ``Tracker.step`` give;
* ``ours_nofit``: the same without the end-effector fit (ablation);
* ``ik``: the shipped per-frame IK solver (``IKSolver.load()``) given the same trackers as exact position and
  rotation effectors, each frame alone.

Metrics (world frame, no alignment): MPJPE (24 joints, mm), MPJVE (joint velocity error, cm/s), MPJAE (joint
acceleration error, cm/s^2; the legs' too), rotation error (mean geodesic angle of the 24 local rotations, the
root's in the world, degrees), the arms' local rotation errors (shoulder, elbow, wrist; mean of left and right,
degrees), the head and wrist joints' distance to their trackers (mean and 95th percentile, mm; and the 95th
percentile after each clip's first second, once the fit has measured the trackers' jitter), foot skating
(mean foot speed on the truth's contact frames, :func:`workflows.animation.clean.foot_contacts`, mm/frame) and
the anomaly rate (share of frames whose :func:`smplik.tracking.runtime.anomaly_scores` exceeds
:data:`ANOMALY_THRESHOLD`). ``comparison`` lists, per clip, tracker set and noise, ours against IK and whether ours
is ahead on each figure. Cost: per-frame wall time of ``Tracker.step`` (default runtime) on one thread, p50 and
p90, deterministic and with 16 samples.

Usage: ``python benchmarks/tracking.py [--frames 600]`` -> ``benchmarks/results/tracking.json`` (the 4-tracker
results at the top level, the 3-tracker ones under ``three_trackers``).
"""

from __future__ import annotations

import argparse
import json
import re
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
from smplik.tracking.io import signals_from_motion  # noqa: E402
from smplik.tracking.model_io import load_model  # noqa: E402
from smplik.tracking.runtime import ANOMALY_THRESHOLD, Tracker, anomaly_scores, track_sequence  # noqa: E402
from workflows.animation.clean import CleanConfig, foot_contacts, foot_skating  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LEGS = [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("hip", "knee", "ankle", "foot")]
ARM_JOINTS = {j: [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right")] for j in ("shoulder", "elbow", "wrist")}
NOISES = {"exact": (0.0, 0.0), "noisy": (0.01, 2.0)}
EXTRA_CLIPS = ("55_01.bvh",)
"""Held-out clips outside the test split (subject 55, validation split: never trained on)."""
MODELS = {"4": "smplik/checkpoints/smplik_tracking.pt", "3": "smplik/checkpoints/smplik_tracking_3.pt"}
COMPARED = ("mpjpe_mm", "mpjae_cm_s2", "rotation_deg", "shoulder_deg", "elbow_deg", "wrist_deg",
            "skating_mm_per_frame")
"""Figures on which ours is compared with IK per clip (lower is better)."""


def clip_kinds(readme: Path) -> dict[str, str]:
    """Clip file name -> kind (walk, run, martial arts, dance, other) from the README's trial descriptions."""
    kinds = {}
    for line in readme.read_text().splitlines():
        m = re.match(r"\|\s*(\d\d_\d\d\.bvh)\s*\|[^|]*\|[^|]*\|[^|]*\|[^|]*\|\s*([^|]+?)\s*\|", line)
        if not m:
            continue
        d = m.group(2).lower()
        kinds[m.group(1)] = ("dance" if "dance" in d else "martial arts" if ("punch" in d or "sword" in d)
                             else "run" if "run" in d else "walk" if "walk" in d else "other")
    return kinds


def joints(R: np.ndarray, transl: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Rw, p = forward_kinematics(torch.as_tensor(R, dtype=torch.float64), torch.as_tensor(J, dtype=torch.float64),
                               torch.as_tensor(transl, dtype=torch.float64))
    return Rw.numpy(), p.numpy()


def angle_deg(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Geodesic angles (degrees) between rotations A and B (..., 3, 3)."""
    tr = np.einsum("...ij,...ij->...", A, B)
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def metrics(R: np.ndarray, p: np.ndarray, R_true: np.ndarray, truth: np.ndarray, contact: np.ndarray, fps: float,
            lo: np.ndarray, hi: np.ndarray, sig) -> dict[str, float]:
    v, vt = np.diff(p, axis=0) * fps, np.diff(truth, axis=0) * fps
    a, at = np.diff(p, 2, axis=0) * fps ** 2, np.diff(truth, 2, axis=0) * fps ** 2
    acc = np.linalg.norm(a - at, axis=-1)
    score = anomaly_scores(R.astype(np.float32), p.astype(np.float32), lo, hi)
    rot = angle_deg(R, R_true)
    out = {"mpjpe_mm": 1000 * float(np.linalg.norm(p - truth, axis=-1).mean()),
           "mpjve_cm_s": 100 * float(np.linalg.norm(v - vt, axis=-1).mean()),
           "mpjae_cm_s2": 100 * float(acc.mean()), "legs_mpjae_cm_s2": 100 * float(acc[:, LEGS].mean()),
           "rotation_deg": float(rot.mean())}
    out.update({f"{j}_deg": float(rot[:, idx].mean()) for j, idx in ARM_JOINTS.items()})
    for name, label in (("head", "head"), ("left_wrist", "wrist"), ("right_wrist", "wrist")):
        if name in sig.names:
            miss = 1000 * np.linalg.norm(p[:, JOINT_INDEX[name]] - sig.positions[:, sig.names.index(name)], axis=-1)
            out.setdefault(f"{label}_miss_mm", []).append(miss)
    settled = int(fps)  # the fit starts by assuming jittery trackers; it follows exact ones fully within a second
    for label in ("head", "wrist"):
        parts = out.pop(f"{label}_miss_mm")
        miss = np.concatenate(parts)
        out[f"{label}_miss_mm"], out[f"{label}_miss_p95_mm"] = float(miss.mean()), float(np.percentile(miss, 95))
        late = np.concatenate([m[settled:] for m in parts])
        out[f"{label}_miss_after_1s_p95_mm"] = float(np.percentile(late, 95)) if late.size else float("nan")
    out.update({"skating_mm_per_frame": 1000 * foot_skating(p, contact), "contact_frames": int(contact.sum()),
                "anomaly_rate": float((score > ANOMALY_THRESHOLD).mean()), "frames": int(p.shape[0])})
    return out


def ik_motion(solver, sig, betas: np.ndarray, gender: Gender) -> tuple[np.ndarray, np.ndarray]:
    from smplik.effectors import Effector
    from smplik.rotations import quaternion_to_matrix_np

    R_trk = quaternion_to_matrix_np(sig.rotations)
    lists = [[e for k, name in enumerate(sig.names) for e in (Effector.position(name, sig.positions[t, k]),
                                                               Effector.rotation(name, R_trk[t, k]))]
             for t in range(sig.num_frames)]
    poses = []
    for s in range(0, len(lists), 256):
        poses += solver.solve_batch(lists[s:s + 256], betas=betas, gender=gender)
    aa = np.stack([np.concatenate([p.global_orient[None], p.body_pose]) for p in poses])
    return axis_angle_to_matrix(torch.as_tensor(aa)).numpy(), np.stack([p.transl for p in poses])


def per_frame_cost(model: str, samples: int, sig, frames: int = 300, **config) -> dict[str, float]:
    torch.set_num_threads(1)
    tracker = Tracker.load(model, config=TrackerRuntimeConfig(samples=samples, **config))  # the default runtime
    tracker.reset(sig.has_rotation)
    times = []
    for t in range(min(frames, sig.num_frames)):
        t0 = time.perf_counter()
        tracker.step(sig.positions[t], sig.rotations[t])
        times.append(time.perf_counter() - t0)
    ms = 1000 * np.asarray(times[20:])
    return {"p50_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)), "frames": int(ms.size)}


def summarise(rows: dict[str, dict[str, list[dict]]], kinds: dict[str, str]) -> tuple[dict, dict]:
    """Frame-weighted means over all clips and per kind: ``(summary, by_kind)``."""
    def mean(rs: list[dict]) -> dict[str, float]:
        w = np.array([r["frames"] for r in rs], dtype=float)
        keys = [k for k in rs[0] if k not in ("clip", "kind", "frames", "contact_frames")]
        out = {k: round(float(np.average([r[k] for r in rs], weights=w)), 3) for k in keys}
        out["frames"] = int(w.sum())
        return out

    summary = {n: {m: mean(rs) for m, rs in by.items()} for n, by in rows.items()}
    by_kind = {n: {kind: {m: mean([r for r in rs if r["kind"] == kind]) for m, rs in by.items()}
                   for kind in sorted({kinds.get(r["clip"], "other") for rs in by.values() for r in rs})}
               for n, by in rows.items()}
    return summary, by_kind


def run_model(label: str, args, data, kinds, solver, bodies, fps, seconds) -> dict:
    model_path = str(ROOT / MODELS[label])
    model = load_model(model_path)
    lo, hi = model.pose_lo.numpy(), model.pose_hi.numpy()
    rng = np.random.default_rng(0)
    rows: dict[str, dict[str, list[dict]]] = {n: {} for n in NOISES}
    names = data.clip_names
    for c in np.unique(data.clip_id.numpy()):
        name = names[int(c)]
        clip = data.select(data.clip_id == int(c))
        T = min(args.frames, len(clip))
        betas = rng.standard_normal(10)
        gender = list(Gender)[int(rng.integers(3))]
        J = bodies.rest_joints(torch.as_tensor(betas, dtype=torch.float32), torch.tensor(gender.index)).double().numpy()
        R_true = axis_angle_to_matrix(clip.pose[:T].double()).numpy()
        transl_true = clip.transl[:T].double().numpy()
        _, p_true = joints(R_true, transl_true, J)
        contact = foot_contacts(p_true, fps, CleanConfig())
        for noise, (sigma_m, sigma_deg) in NOISES.items():
            sig = signals_from_motion(R_true, transl_true, J, model.cfg.trackers, fps, noise_m=sigma_m,
                                      noise_deg=sigma_deg, rng=np.random.default_rng(int(c)))
            methods = {}
            for method, fit in (("ours", True), ("ours_nofit", False)):
                t0 = time.perf_counter()
                tr = Tracker.load(model_path, betas=betas, gender=gender,
                                  config=TrackerRuntimeConfig(effector_fit=fit))
                res = track_sequence(tr, sig)
                seconds[f"{label}_{method}"] = seconds.get(f"{label}_{method}", 0.0) + time.perf_counter() - t0
                methods[method] = (res.R_local, res.transl)
            t0 = time.perf_counter()
            methods["ik"] = ik_motion(solver, sig, betas, gender)
            seconds[f"{label}_ik"] = seconds.get(f"{label}_ik", 0.0) + time.perf_counter() - t0
            for method, (R, transl) in methods.items():
                m = metrics(R, joints(R, transl, J)[1], R_true, p_true, contact, fps, lo, hi, sig)
                rows[noise].setdefault(method, []).append({"clip": name, "kind": kinds.get(name, "other"), **m})
                print(f"{label} {noise:6s} {name:10s} {method:10s} MPJPE {m['mpjpe_mm']:6.1f} mm  MPJAE "
                      f"{m['mpjae_cm_s2']:7.1f} cm/s2  rot {m['rotation_deg']:5.1f}  sh/el/wr {m['shoulder_deg']:5.1f} "
                      f"{m['elbow_deg']:5.1f} {m['wrist_deg']:5.1f} deg  miss head {m['head_miss_mm']:5.1f} wrist "
                      f"{m['wrist_miss_mm']:5.1f} mm  skating {m['skating_mm_per_frame']:5.2f} mm/f", flush=True)
    summary, by_kind = summarise(rows, kinds)
    table = []
    for noise, by in rows.items():
        for i, ours in enumerate(by["ours"]):
            row = {"clip": ours["clip"], "kind": ours["kind"], "noise": noise, "frames": ours["frames"]}
            for k in COMPARED + ("head_miss_mm", "wrist_miss_mm"):
                row[k] = {m: round(by[m][i][k], 2) for m in ("ours", "ours_nofit", "ik")}
            row["ours_ahead_of_ik"] = {k: bool(by["ours"][i][k] < by["ik"][i][k]) for k in COMPARED}
            table.append(row)
    sig = signals_from_motion(R_true, transl_true, J, model.cfg.trackers, fps)
    cost = {"deterministic": per_frame_cost(model_path, 1, sig), "samples_16": per_frame_cost(model_path, 16, sig),
            "deterministic_nofit": per_frame_cost(model_path, 1, sig, effector_fit=False)}
    print(f"{label} trackers, per-frame cost (1 thread):", cost, flush=True)
    return {"trackers": list(model.cfg.trackers), "summary": summary, "by_kind": by_kind, "per_clip": rows,
            "comparison": table, "per_frame_cost_ms": cost,
            "model": {k: model.info.get(k) for k in ("net", "val_mpjpe_mm", "steps", "seconds")}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="/tmp/smplik_tracking_heldout60.npz",
                    help="60 Hz pose cache of the held-out clips (built if missing).")
    ap.add_argument("--frames", type=int, default=600, help="Most frames per clip (60 Hz).")
    ap.add_argument("--trackers", default="4,3", help="Tracker sets to run (comma-separated: 4, 3).")
    args = ap.parse_args()
    torch.set_num_threads(1)
    threadpool_limits(1)  # numpy's BLAS on one thread too (the per-frame path is numpy)
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.dataset import build_cache, find_sources, load_cache

    split_file = ROOT / "configs" / "split_cmu_dance.json"
    wanted = set(json.loads(split_file.read_text())["test"]["files"]) | set(EXTRA_CLIPS)
    cmu = shared_dir() / "data" / "cmu"
    cache = Path(args.cache)
    if not cache.exists():
        sources = [s for s in find_sources(cmu, "bvh") if s.path.name in wanted]
        build_cache(sources, fps=60, split=split_file, out=cache, rig_mapper=auto_preset)
    data = load_cache(cache)
    missing = wanted - set(data.clip_names)
    if missing:
        raise SystemExit(f"{cache}: clips {', '.join(sorted(missing))} missing; delete it to rebuild.")
    kinds = clip_kinds(cmu / "README.md")
    from smplik.solver import IKSolver

    solver = IKSolver.load()
    bodies = BodyModelSet.load()
    seconds: dict[str, float] = {}
    t_start = time.perf_counter()
    results = {label: run_model(label, args, data, kinds, solver, bodies, data.fps, seconds)
               for label in args.trackers.split(",")}
    for label, res in results.items():
        print(f"\n{label} trackers:")
        for row in res["comparison"]:
            behind = [k for k, ahead in row["ours_ahead_of_ik"].items() if not ahead]
            print(f"  {row['noise']:6s} {row['clip']:10s} {row['kind']:12s} MPJPE ours {row['mpjpe_mm']['ours']:6.1f}"
                  f" IK {row['mpjpe_mm']['ik']:6.1f}  behind IK on: {', '.join(behind) or '-'}")
    main_res = results.get("4") or next(iter(results.values()))
    out = {**main_res, "split": "test + 55_01", "clips": sorted(wanted),
           "kinds": {n: kinds.get(n, "other") for n in sorted(wanted)}, "frames_per_clip": args.frames,
           "note": f"each clip cut to its first {args.frames} frames at 60 Hz (the whole run stays under 10 minutes "
                   "on one thread)",
           "seconds": {k: round(v, 1) for k, v in seconds.items()},
           "total_seconds": round(time.perf_counter() - t_start, 1)}
    if "3" in results and main_res is not results["3"]:
        out["three_trackers"] = results["3"]
    path = save("tracking", out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
