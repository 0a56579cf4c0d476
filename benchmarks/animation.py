"""Animations from real video estimator outputs: jitter, foot skating and fidelity before and after cleaning.

For every estimator file under the data folder (``--data``, else ``$SMPLIK_REAL_ESTIMATORS``, else
``<cache>/real/estimators``; the files are third-party and stay outside the repository: GVHMR demo
``hmr4d_results.pt``, WHAM ``wham_output.pkl``, AIST++ ``motions/*.pkl``, PHALP ``*.pkl``), every track is
read frame by frame and retargeted onto its body exactly as ``smplik scene animate`` does, in the
estimator's world frame when it has one (WHAM, GVHMR ``smpl_params_global``, AIST++). Variants:

* ``raw``: the estimator's per-frame poses (the reference of the fidelity metric);
* ``adaptive``: smplik's default cleaning (noise measured per channel, :func:`workflows.animation.clean.denoise_motion`,
  glitch repair, foot locks);
* ``adaptive_no_lock``: the same without foot locking;
* ``sequence``: the previous default, the sequence solve with foot locks and a 5 mm pose budget
  (:func:`workflows.animation.clean.sequence_clean`);
* ``savgol``: Savitzky-Golay smoothing (window 9, order 2) + foot locking (a plain baseline);
* ``one_euro``: zero-phase One-Euro smoothing + foot locking (a plain baseline).

Fidelity budget (the previous default's goal, still printed; the known-truth benchmark,
``benchmarks/animation_truth.py``, measures what now counts: the error to the true motion): cleaning may move
the pose at most :data:`FIDELITY_TOLERANCE_MM` from the estimate
(pelvis-aligned MPJPE to the raw per-frame joints). Per joint and frame, pelvis-aligned,
``|clean - truth| <= |raw - truth| + |clean - raw|``, so the cleaned motion's error to the unknown true
motion exceeds the estimate's by at most that MPJPE; 5 mm is 10 % of 50 mm, below the MPJPE of every video
estimator we read on 3DPW (WHAM, GVHMR, 4D-Humans: about 55-80 mm), so within it cleaning cannot raise the
fidelity error by more than 10 %.

Metrics (:mod:`workflows.animation.clean`): jitter = mean joint acceleration (mm/frame^2), skating = mean
speed of the foot joints during contact, relative to the ground (mm/frame; the contacts and, in camera
frames, the ground velocity found by the default pipeline, the same for every variant), pose fidelity =
pelvis-aligned MPJPE (mm, 24 joints) to the raw per-frame joints (the MPJPE of HMR papers), and the
trajectory change (mean pelvis distance, mm, the table's ``traj``) separately.

Camera-space tracks of near-orthographic estimators (4D-Humans/PHALP) are placed at a realistic depth first,
as ``scene animate`` does (:func:`workflows.animation.realistic_depth`); ``raw_source_depth`` is the estimate
at the estimator's own depth, for the record, and ``raw`` the reference after that placement. The default
pipeline is also run end to end (read, retarget, clean, keyframes, effector recovery on keyframes with
the shipped model): keyframe count and frames per second (the table's ``fps``: end to end, reading
included; the JSON also has the reading and the rest separately; the shipped model is loaded
once), both per wall-clock second and per CPU second of the process (``cpu fps``: independent of other
load on a shared machine; on two idle cores the wall-clock rate is at least this). Frame rates: AIST++ 60;
GVHMR and WHAM store none, 30 is assumed (GVHMR's demo works on 30 frames/s video).

CMU (``../shared/data/cmu``, clips :data:`CMU_CLIPS` when present): real mocap retargeted to SMPL, 30
frames/s; each frame's effectors recovered (6, the shipped model) and solved frame by frame, against the
sequence solve from the same effectors (:func:`smplik.sequence.solve_sequence`, warm-started from the
frame-wise solves), and, as baselines, the frame-wise solves smoothed afterwards (Savitzky-Golay, One-Euro):
MPJPE and acceleration error (mm/frame^2) to the real motion. Also a synthetic estimate of each clip
(Gaussian noise of :data:`NOISE_RAD` on every rotation component and :data:`NOISE_M` on the root, per frame)
cleaned by each variant: its MPJPE to the true motion before and after cleaning (the fidelity error measured
against a known truth).

Prints tables and writes ``benchmarks/results/animation.json``; without data it says so and exits 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _common import save  # noqa: E402

from smplik.paths import real_estimators_dir  # noqa: E402
from workflows.animation.clean import CleanConfig, foot_noise, ground_of, motion_metrics  # noqa: E402
from workflows.animation.clips import (  # noqa: E402
    AnimateConfig,
    animation_from_clip,
    camera_clean,
    clean_track,
    read_clip,
    realistic_depth,
)
from workflows.scene.pipeline import retarget_to_body  # noqa: E402

ASSUMED_FPS = {"gvhmr": 30.0, "wham": 30.0, "phalp": 30.0}
VARIANTS = {"adaptive": CleanConfig(), "adaptive_no_lock": CleanConfig(foot_lock=False),
            "sequence": CleanConfig(smoothing="sequence", pose_budget_mm=5.0),
            "savgol": CleanConfig(smoothing="savgol"), "one_euro": CleanConfig(smoothing="one_euro")}
DEFAULT = "adaptive"
FIDELITY_TOLERANCE_MM = 5.0
"""Most MPJPE (mm) cleaning may add to the estimate (10 % of a 50 mm estimator error; module docstring)."""


def find_files(folder: Path) -> list[Path]:
    """Estimator files (``.pt``, ``.pkl``) under ``folder``, sorted."""
    return sorted(p for p in folder.rglob("*") if p.suffix in (".pt", ".pkl") and p.is_file())


def bench_file(path: Path, solver, max_frames: int) -> list[dict]:
    start, cpu_start = time.perf_counter(), time.process_time()
    clip = read_clip(path, space="world", solver=solver)
    source_clip = clip
    camera = next(iter(clip.tracks.values()))[0][1].camera if clip.space == "camera" else None
    clip, _, depth = realistic_depth(clip, camera, AnimateConfig().camera_fov_deg)
    read_s, read_cpu = time.perf_counter() - start, time.process_time() - cpu_start
    frames_read = sum(len(v) for v in clip.tracks.values())
    fps = clip.fps or ASSUMED_FPS.get(clip.format, 30.0)
    rows = []
    for tid, entries in clip.tracks.items():
        frames = [f for f, _ in entries]
        if len(frames) != frames[-1] - frames[0] + 1 or len(frames) < 10:
            continue  # gaps or too short: the animate command refuses those too
        entries = entries[:max_frames]
        people = [p for _, p in entries]
        body = (np.mean([p.betas for p in people], axis=0), people[0].gender, 1.0)
        poses = [retarget_to_body(p, *body) for p in people]
        default = clean_track(poses, fps, camera_clean(CleanConfig(), clip.space), 1.0)
        raw_joints, contacts = default[3], default[2]
        default_cfg = camera_clean(CleanConfig(), clip.space)
        # skating relative to the ground (camera frames), found as the pipeline does (the cleaned path as smooth)
        noise = foot_noise(raw_joints, default[4], fps)
        ground = ground_of(default[4], fps, default_cfg, noise=noise)
        repaired = int(default[5].sum())
        result = {"file": str(path.relative_to(path.parents[1])), "format": clip.format, "space": clip.space,
                  "track": tid, "frames": len(poses), "fps": fps, "repaired_glitches": repaired}
        if depth is not None:  # the estimate at the estimator's own (near-orthographic) depth, for the record
            result["depth_change"] = dataclasses.asdict(depth)
            source = [retarget_to_body(p, *body) for _, p in source_clip.tracks[tid][:max_frames]]
            source_raw = clean_track(source, fps, CleanConfig(), 1.0)[3]
            result["raw_source_depth"] = motion_metrics(source_raw, source_raw, contacts,
                                                        ground_of(source_raw, fps, default_cfg, noise=noise)).to_dict()
        result["raw"] = motion_metrics(raw_joints, raw_joints, contacts, ground).to_dict()
        for name, cfg in VARIANTS.items():
            joints = default[4] if name == DEFAULT else clean_track(poses, fps, camera_clean(cfg, clip.space), 1.0)[4]
            result[name] = motion_metrics(joints, raw_joints, contacts, ground).to_dict()
        # the whole pipeline on this track: keyframes and throughput
        sub = dataclass_clip(clip, tid, entries)
        start, cpu_start = time.perf_counter(), time.process_time()
        anim, _ = animation_from_clip(sub, solver, fps=fps, config=AnimateConfig())
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
        share = len(poses) / frames_read
        result["keyframes"] = len(anim.tracks[0].keyframes)
        result["pipeline_frames_per_s"] = round(len(poses) / elapsed, 1)
        result["reading_frames_per_s"] = round(frames_read / read_s, 1)
        result["end_to_end_frames_per_s"] = round(len(poses) / (elapsed + read_s * share), 1)
        # CPU seconds of this process (all its threads, at most 2): load-independent; on 2 idle cores the wall
        # time is at most this, so frames per CPU second is a lower bound of the idle machine's frames/s.
        result["end_to_end_frames_per_cpu_s"] = round(len(poses) / (cpu + read_cpu * share), 1)
        rows.append(result)
    return rows


def dataclass_clip(clip, tid, entries):
    return dataclasses.replace(clip, tracks={tid: entries})


NOISE_RAD, NOISE_M, NOISE_SEED = 0.02, 0.005, 0
"""Per-frame Gaussian noise (radians per rotation component, metres on the root) of the synthetic estimates."""
CMU_CLIPS = ("02_01", "05_01", "07_05", "16_15")
"""CMU clips (walks, runs, a dance) resampled to 30 frames/s; only those present are used."""


def _errors(p: np.ndarray, p_true: np.ndarray) -> dict[str, float]:
    """MPJPE (mm) and acceleration error (mm/frame^2) of joints p (T, 24, 3) against p_true."""
    acc = p[2:] - 2 * p[1:-1] + p[:-2]
    acc_true = p_true[2:] - 2 * p_true[1:-1] + p_true[:-2]
    return {"mpjpe_mm": round(float(np.linalg.norm(p - p_true, axis=-1).mean() * 1000), 2),
            "accel_error_mm": round(float(np.linalg.norm(acc - acc_true, axis=-1).mean() * 1000), 3)}


def bench_cmu(folder: Path, solver, frames: int) -> list[dict]:
    """Real mocap (CMU BVH on SMPL) -> each frame's recovered effectors -> poses: frame-wise solves against the
    same solves cleaned as a sequence (One-Euro, foot locking), MPJPE and acceleration error to the real motion."""
    from smplik.data.retarget import retarget_bvh
    from smplik.effectors import pack_effectors
    from smplik.sequence import solve_sequence
    from workflows.animation.clips import axis_angle_to_local, joints_of, rest_joints
    from workflows.scene.recovery import RecoveryConfig, TargetPose, recover_many

    rows = []
    for name in CMU_CLIPS:
        path = folder / f"{name}.bvh"
        if not path.is_file():
            continue
        clip = retarget_bvh(path, "cmu")
        step = max(1, round(clip.fps / 30.0))
        idx = np.arange(0, clip.global_orient.shape[0], step)[:frames]
        from smplik.conventions import Gender
        from smplik.pose import Pose

        gender = clip.gender or Gender.NEUTRAL
        betas = np.zeros(10) if clip.betas is None else np.asarray(clip.betas, dtype=np.float64)
        truth = [Pose(clip.global_orient[i].astype(float), clip.body_pose[i].astype(float),
                      clip.transl[i].astype(float), betas, gender) for i in idx]
        J = rest_joints(betas, gender)
        p_true = np.stack([TargetPose.from_pose(p).p_world.double().numpy() for p in truth])
        start = time.perf_counter()
        recs = recover_many(solver, [TargetPose.from_pose(p) for p in truth], RecoveryConfig(max_effectors=6,
                                                                                            threshold=0.0))
        elapsed = time.perf_counter() - start
        solved = [r.pose for r in recs]
        p_frame = np.stack([np.asarray(r.pose.joints, dtype=np.float64) for r in recs])
        row = {"clip": name, "frames": len(idx), "frame_wise": _errors(p_frame, p_true)}
        R0 = axis_angle_to_local(np.stack([p.global_orient for p in solved]), np.stack([p.body_pose for p in solved]))
        start = time.perf_counter()
        R_seq, t_seq = solve_sequence(torch.as_tensor(R0), torch.as_tensor(np.stack([p.transl for p in solved])),
                                      torch.as_tensor(J), pack_effectors([list(r.effectors) for r in recs],
                                                                         torch.float64))
        sequence_s = time.perf_counter() - start
        row["sequence"] = _errors(joints_of(R_seq.numpy(), t_seq.numpy(), J), p_true)
        for label, cfg in (("frame_wise_savgol", CleanConfig(smoothing="savgol", foot_lock=False)),
                           ("frame_wise_one_euro", CleanConfig(smoothing="one_euro", foot_lock=False))):
            R_s, t_s = clean_track(solved, 30.0, cfg, 1.0)[:2]
            row[label] = _errors(joints_of(R_s, t_s, J), p_true)
        # a synthetic estimate of the real motion (per-frame noise on every rotation and the root) cleaned by each
        # variant: the fidelity error to the true motion, measured, where the real files have no truth
        rng = np.random.default_rng(NOISE_SEED)
        noisy = [Pose(p.global_orient + rng.normal(0, NOISE_RAD, 3), p.body_pose + rng.normal(0, NOISE_RAD, (23, 3)),
                      p.transl + rng.normal(0, NOISE_M, 3), betas, gender) for p in truth]
        estimate = {"raw": _errors(clean_track(noisy, 30.0, CleanConfig(smoothing="none", foot_lock=False,
                                                                        repair_glitches=False), 1.0)[3], p_true)}
        for label, cfg in VARIANTS.items():
            estimate[label] = _errors(clean_track(noisy, 30.0, cfg, 1.0)[4], p_true)
        row["noisy_estimate"] = estimate
        rows.append({**row, "recovery_frames_per_s": round(len(idx) / elapsed, 1),
                     "sequence_solve_frames_per_s": round(len(idx) / sequence_s, 1)})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=real_estimators_dir())
    parser.add_argument("--max-frames", type=int, default=800, help="Frames per track at most.")
    parser.add_argument("--cmu-frames", type=int, default=150, help="Frames (30 frames/s) per CMU clip.")
    args = parser.parse_args()
    if not args.data.is_dir():
        print(f"no estimator data at {args.data} (pass --data or set SMPLIK_REAL_ESTIMATORS); nothing to do")
        return
    from smplik.solver import IKSolver

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    solver = IKSolver.load(None)
    rows: list[dict] = []
    for path in find_files(args.data):
        rows += bench_file(path, solver, args.max_frames)
    head = (f"{'file':52s} {'T':>4s} {'variant':17s} {'jitter':>7s} {'skating':>8s} {'MPJPE':>6s} {'traj':>6s}")
    print(head + f" {'keys':>5s} {'fps':>6s} {'cpu fps':>7s} {'glitches':>8s}")
    for r in rows:
        if "depth_change" in r:
            d = r["depth_change"]
            print(f"{r['file'][:52]:52s} depth x{d['factor']:.4f} ({d['fov_from_deg']:.1f} -> {d['fov_to_deg']:g} deg "
                  f"camera): median {d['depth_from_m']:.1f} m -> {d['depth_to_m']:.2f} m")
        for v in ("raw_source_depth", "raw", *VARIANTS):
            if v not in r:
                continue
            m = r[v]
            extra = (f" {r['keyframes']:5d} {r['end_to_end_frames_per_s']:6.1f} {r['end_to_end_frames_per_cpu_s']:7.1f}"
                     f" {r['repaired_glitches']:8d}"
                     if v == DEFAULT else "")
            print(f"{r['file'][:52]:52s} {r['frames']:4d} {v:17s} {m['jitter_mm_per_frame2']:7.2f} "
                  f"{m['skating_mm_per_frame']:8.2f} {m['mpjpe_mm']:6.1f} {m['trajectory_mm']:6.1f}{extra}")
    checks = {v: all(r[v]["jitter_mm_per_frame2"] < r["raw"]["jitter_mm_per_frame2"]
                     and (r[v]["skating_mm_per_frame"] < r["raw"]["skating_mm_per_frame"]
                          or r["raw"]["contact_frames"] == 0) for r in rows)
              for v in VARIANTS}
    no_contacts = [r["file"] for r in rows if r["raw"]["contact_frames"] == 0]
    print("lower jitter on every file and lower skating on every file with contacts:", checks)
    print("files where no foot contact was detected (skating not measured):", no_contacts or "none")
    within = {v: all(r[v]["mpjpe_mm"] <= FIDELITY_TOLERANCE_MM for r in rows) for v in VARIANTS}
    print(f"fidelity within {FIDELITY_TOLERANCE_MM} mm of the estimate on every file:", within)
    slowest = min((r["end_to_end_frames_per_s"] for r in rows), default=None)
    slowest_cpu = min((r["end_to_end_frames_per_cpu_s"] for r in rows), default=None)
    print(f"slowest end-to-end frames/s (default pipeline): {slowest} per wall-clock second, {slowest_cpu} per CPU "
          "second")
    from _common import shared_dir

    cmu = bench_cmu(shared_dir() / "data" / "cmu", solver, args.cmu_frames)
    print(f"{'CMU clip':10s} {'T':>4s} {'solving':16s} {'MPJPE':>6s} {'accel err':>9s}")
    labels = ("frame_wise", "sequence", "frame_wise_savgol", "frame_wise_one_euro")
    for r in cmu:
        for label in labels:
            print(f"{r['clip']:10s} {r['frames']:4d} {label:16s} {r[label]['mpjpe_mm']:6.1f} "
                  f"{r[label]['accel_error_mm']:9.2f}")
    print(f"{'CMU noisy estimate':18s} " + " ".join(f"{v:>16s}" for v in ("raw", *VARIANTS)) + "   (MPJPE to truth)")
    for r in cmu:
        print(f"{r['clip']:18s} " + " ".join(f"{r['noisy_estimate'][v]['mpjpe_mm']:16.2f}" for v in ("raw", *VARIANTS)))
    noisy_check = {v: all(r["noisy_estimate"][v]["mpjpe_mm"] <= 1.1 * r["noisy_estimate"]["raw"]["mpjpe_mm"]
                          for r in cmu) for v in VARIANTS}
    print("cleaning a noisy estimate keeps its MPJPE to the true motion within 10 % on every clip:", noisy_check)
    cmu_check = all(r["sequence"]["accel_error_mm"] < r["frame_wise"]["accel_error_mm"]
                    and r["sequence"]["mpjpe_mm"] <= r["frame_wise"]["mpjpe_mm"] for r in cmu)
    print("sequence solving beats frame-wise on acceleration error and is no worse on MPJPE on every clip:",
          cmu_check)
    path = save("animation", {"data": str(args.data), "variants": {k: vars(v) for k, v in VARIANTS.items()},
                              "default": DEFAULT, "fidelity_tolerance_mm": FIDELITY_TOLERANCE_MM,
                              "tracks": rows, "lower_jitter_and_skating_everywhere": checks,
                              "files_without_contacts": no_contacts,
                              "fidelity_within_tolerance_everywhere": within,
                              "slowest_end_to_end_frames_per_s": slowest,
                              "slowest_end_to_end_frames_per_cpu_s": slowest_cpu, "cmu": cmu,
                              "cmu_sequence_beats_frame_wise": cmu_check,
                              "cmu_noisy_estimate_within_10_percent": noisy_check})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
