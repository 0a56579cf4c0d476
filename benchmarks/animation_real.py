"""The default animation cleaning on real estimator outputs: jitter, skating and steps hidden by foot locks.

Reads every estimator file under a folder (the first argument, else ``$SMPLIK_REAL_ESTIMATORS``, else
``<cache>/real/estimators``; third-party files stay outside the repository: GVHMR ``hmr4d_results.pt``, WHAM
``wham_output.pkl``, 4D-Humans/PHALP ``*.pkl``, AIST++ motions, and any other format ``scene animate`` reads), and
cleans every gap-free track of at least 10 frames as ``smplik scene animate`` does with default settings
(:func:`workflows.animation.read_clip`, :func:`~workflows.animation.realistic_depth` for near-orthographic
cameras, :func:`~workflows.animation.clean_track` with :func:`~workflows.animation.camera_clean`). Metrics, as in
the real-file table of ``docs/animation.md`` (``benchmarks/animation.py``;
:func:`workflows.animation.clean.motion_metrics`):

* jitter: mean joint acceleration (mm/frame^2);
* skating: mean foot speed over the default's contact frames, relative to the ground (mm/frame; in camera frames
  the ground velocity the default pipeline finds);
* for ``raw`` (the estimate), ``default`` (adaptive cleaning, glitch repair, foot locks) and ``sequence`` (the
  previous default, ``--smoothing sequence --pose-budget 5``, the method of the earlier real-file table, run on the
  same file: the "today" figures the default must not be worse than).

Hidden steps: a lock must not hide a real step. For every pair of consecutive frames where a foot is locked in the
same contact run of the default, the estimate's foot (raw per-frame joints, relative to the ground) is checked:

* ``one_frame_moves``: it moves at least :data:`STEP_M` (3 cm) from one frame to the next;
* ``hidden_steps``: such a move that stays in the noise-free estimate of the foot (the default cleaning without
  locks: its mean over up to 3 frames of the run from t on is at least 3 cm from its mean over up to 3 frames of
  the run before t; a step,
  not a frame of noise that comes back), the failure counted;
* ``max_drift_cm``: the farthest the noise-free estimate of the foot (the default cleaning without locks) gets
  from its lock's mean within one run (a slow slide the lock holds still);
* ``release_step_cm``: the most the output's foot moves in one frame beyond what the cleaned foot without locks
  moves (a blend that snaps the foot back after a release; at most 2 cm: no snap).

Known truth at the clean files' noise level (:func:`low_noise_truth`, when ``../shared/data/cmu`` is there): the
default and the previous default on synthetic estimates of CMU test clips with that little noise.

Prints a table and writes ``benchmarks/results/animation_real.json``. Without data it says so and exits 0.
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

STEP_M = 0.03
"""A move of the estimate's foot this large (m) inside a lock counts as a step the lock may hide."""
ASSUMED_FPS = 30.0
"""Frame rate of formats that store none (GVHMR, WHAM, PHALP): their demos' video rate."""
SUFFIXES = (".pt", ".pkl", ".pk", ".npz", ".npy")


def find_files(folder: Path) -> list[Path]:
    """Estimator files under ``folder`` (any depth), sorted."""
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix in SUFFIXES)


def lock_check(raw: np.ndarray, free: np.ndarray, out: np.ndarray, contacts: np.ndarray, ground: np.ndarray,
               step_m: float = STEP_M) -> dict:
    """Steps hidden by locks (module docstring). raw, free, out (T, 24, 3) joints in metres: the estimate, the
    default cleaning without locks, the default; contacts (T, 2) the default's locks; ground (3,) or (T, 3)
    m/frame."""
    from smplik.contacts import FOOT_JOINTS, _runs, ground_drift

    T = raw.shape[0]
    drift = ground_drift(ground, T)
    moves, steps, worst_drift, worst_release, where = 0, 0, 0.0, 0.0, []
    for side, foot in enumerate(FOOT_JOINTS):
        r = raw[:, foot] - drift
        f = free[:, foot] - drift
        o = out[:, foot] - drift
        for s, e in _runs(contacts[:, side]):
            worst_drift = max(worst_drift, float(np.linalg.norm(f[s:e] - f[s:e].mean(0), axis=-1).max()))
            for t in range(s + 1, e):
                if np.linalg.norm(r[t] - r[t - 1]) < step_m:
                    continue
                moves += 1
                before, after = f[max(s, t - 3):t].mean(0), f[t:min(e, t + 3)].mean(0)  # inside the run
                if np.linalg.norm(after - before) >= step_m:
                    steps += 1
                    where.append({"foot": "left" if side == 0 else "right", "frame": int(t),
                                  "move_cm": round(100 * float(np.linalg.norm(r[t] - r[t - 1])), 1),
                                  "kept_cm": round(100 * float(np.linalg.norm(after - before)), 1)})
        # how much faster the output's foot moves than the cleaned foot without locks (a lock holding the foot
        # still is slower; a blend that snaps it back after a release is faster), from frame t to t+1
        extra = np.linalg.norm(np.diff(o, axis=0), axis=-1) - np.linalg.norm(np.diff(f, axis=0), axis=-1)
        worst_release = max(worst_release, float(extra.max(initial=0.0)))
    return {"one_frame_moves": moves, "hidden_steps": steps, "hidden_step_frames": where[:20],
            "max_drift_cm": round(100 * worst_drift, 2), "release_step_cm": round(100 * worst_release, 2)}


def bench_file(path: Path, folder: Path, solver, max_frames: int, with_sequence: bool) -> list[dict]:
    """Every gap-free track of ``path``: raw / default / sequence metrics and the lock check."""
    from smplik.contacts import foot_noise, ground_of
    from workflows.animation.clean import CleanConfig, motion_metrics
    from workflows.animation.clips import AnimateConfig, camera_clean, clean_track, read_clip, realistic_depth
    from workflows.scene.pipeline import retarget_to_body

    clip = read_clip(path, solver=solver)
    camera = next(iter(clip.tracks.values()))[0][1].camera if clip.space == "camera" else None
    clip, _, _ = realistic_depth(clip, camera, AnimateConfig().camera_fov_deg)
    fps = clip.fps or ASSUMED_FPS
    rows = []
    for tid, entries in clip.tracks.items():
        frames = [f for f, _ in entries]
        if len(frames) != frames[-1] - frames[0] + 1 or len(frames) < 10:
            continue  # gaps or too short: scene animate refuses those too
        people = [p for _, p in entries[:max_frames]]
        body = (np.mean([p.betas for p in people], axis=0), people[0].gender, 1.0)
        poses = [retarget_to_body(p, *body) for p in people]
        cfg = camera_clean(CleanConfig(), clip.space)
        start = time.process_time()
        _, _, contacts, raw, clean, glitches = clean_track(poses, fps, cfg, 1.0)
        clean_cpu_s = time.process_time() - start
        free = clean_track(poses, fps, dataclasses.replace(cfg, foot_lock=False), 1.0)[4]
        ground = ground_of(free, fps, cfg, noise=foot_noise(raw, free, fps))  # as clean_track finds it
        row = {"file": str(path.relative_to(folder)), "format": clip.format, "space": clip.space, "track": tid,
               "frames": len(poses), "fps": fps, "repaired_glitches": int(glitches.sum()),
               "clean_frames_per_cpu_s": round(len(poses) / max(clean_cpu_s, 1e-9), 1),
               "raw": motion_metrics(raw, raw, contacts, ground).to_dict(),
               "default": motion_metrics(clean, raw, contacts, ground).to_dict(),
               "locks": lock_check(raw, free, clean, contacts, ground)}
        if with_sequence:
            seq = camera_clean(CleanConfig(smoothing="sequence", pose_budget_mm=5.0), clip.space)
            _, _, seq_contacts, _, seq_joints, _ = clean_track(poses, fps, seq, 1.0)
            row["sequence"] = motion_metrics(seq_joints, raw, contacts, ground).to_dict()
            # the previous default's own contacts (its table's skating): a stance it locked and the default
            # does not is skating the default adds
            row["on_sequence_contacts"] = {name: motion_metrics(j, raw, seq_contacts, ground).to_dict()
                                           for name, j in (("raw", raw), ("default", clean), ("sequence", seq_joints))}
        rows.append(row)
    return rows


LOW_NOISE_DEG, LOW_NOISE_M = 0.5, (0.002, 0.002, 0.005)
"""Noise of the known-truth check at the clean world-frame files' level: rotations (deg rms), root (m, x/y/depth)."""
LOW_NOISE_CLIPS = ("02_01", "02_05")
"""CMU test clips (``benchmarks/animation_truth.py``'s test split: a walk, punches) of that check."""


def low_noise_truth(frames: int = 150) -> list[dict]:
    """The default and the previous default against a known truth at the noise level of the clean estimates
    (``benchmarks/animation_truth.py``'s synthetic estimates, independent and AR(1) noise, at
    :data:`LOW_NOISE_DEG` / :data:`LOW_NOISE_M`): does the previous default's lower jitter on them come closer to
    the true motion? Empty without ``../shared/data/cmu``."""
    import animation_truth as truth

    from workflows.animation.clean import CleanConfig

    methods = {"raw": truth.METHODS["raw"], "default": CleanConfig(),
               "sequence": CleanConfig(smoothing="sequence", pose_budget_mm=5.0)}
    saved = truth.ROT_NOISE_DEG, truth.ROOT_NOISE_M, truth.NOISE_MODELS
    truth.ROT_NOISE_DEG, truth.ROOT_NOISE_M, truth.NOISE_MODELS = LOW_NOISE_DEG, LOW_NOISE_M, ("independent", "ar1")
    try:
        rows = []
        for name in LOW_NOISE_CLIPS:
            poses = truth.load_truth(name, frames)
            if poses is None:
                continue
            for r in truth.bench_clip(name, name, poses, methods, 0):
                rows.append({"clip": name, "noise": r["noise"], **{m: {k: r[m][k] for k in (
                    "pa_mpjpe_mm", "accel_error_mm", "skating_mm_per_frame")} for m in methods}})
        return rows
    finally:
        truth.ROT_NOISE_DEG, truth.ROOT_NOISE_M, truth.NOISE_MODELS = saved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, nargs="?", default=real_estimators_dir())
    parser.add_argument("--max-frames", type=int, default=800, help="Frames per track at most.")
    parser.add_argument("--only", default="", help="Only files whose path contains this.")
    parser.add_argument("--no-truth", action="store_true", help="Skip the known-truth check at low noise.")
    parser.add_argument("--no-sequence", action="store_true", help="Skip the previous default (slow on long clips).")
    args = parser.parse_args()
    if not args.folder.is_dir():
        print(f"no estimator data at {args.folder} (pass a folder or set SMPLIK_REAL_ESTIMATORS); nothing to do")
        return
    from smplik.solver import IKSolver
    from workflows.estimators.errors import EstimateFormatError

    torch.set_num_threads(1)
    solver = IKSolver.load(None)
    rows, errors = [], []
    for path in (p for p in find_files(args.folder) if args.only in str(p)):
        try:
            rows += bench_file(path, args.folder, solver, args.max_frames, not args.no_sequence)
        except (EstimateFormatError, ValueError) as exc:  # a file the animate command refuses: say so, go on
            errors.append({"file": str(path.relative_to(args.folder)), "error": str(exc).splitlines()[0]})
    print(f"{'file':58s} {'track':>6s} {'T':>4s} {'jitter raw/default/seq':>24s} {'skating raw/default/seq':>24s}"
          f" {'contacts':>8s} {'MPJPE':>6s} {'glitch':>6s} {'moves':>5s} {'steps':>5s} {'drift':>6s} {'release':>7s}")
    for r in rows:
        seq = r.get("sequence")
        j = f"{r['raw']['jitter_mm_per_frame2']:.2f}/{r['default']['jitter_mm_per_frame2']:.2f}/" + (
            f"{seq['jitter_mm_per_frame2']:.2f}" if seq else "-")
        s = f"{r['raw']['skating_mm_per_frame']:.2f}/{r['default']['skating_mm_per_frame']:.2f}/" + (
            f"{seq['skating_mm_per_frame']:.2f}" if seq else "-")
        lk = r["locks"]
        print(f"{r['file'][-58:]:58s} {str(r['track'])[:6]:>6s} {r['frames']:4d} {j:>24s} {s:>24s} "
              f"{r['default']['contact_frames']:8d} {r['default']['mpjpe_mm']:6.1f} {r['repaired_glitches']:6d} "
              f"{lk['one_frame_moves']:5d} {lk['hidden_steps']:5d} {lk['max_drift_cm']:6.2f} "
              f"{lk['release_step_cm']:7.2f}")
    with_seq = [r for r in rows if "sequence" in r]
    print("skating on the previous default's contacts (raw / default / sequence, mm/frame; its contact foot-frames):")
    for r in with_seq:
        c = r["on_sequence_contacts"]
        print(f"{r['file'][-58:]:58s} {str(r['track'])[:6]:>6s} " + " / ".join(
            f"{c[v]['skating_mm_per_frame']:.2f}" for v in ("raw", "default", "sequence"))
            + f"  ({c['raw']['contact_frames']})")
    for e in errors:
        print(f"{e['file']}: refused: {e['error']}")
    checks = {
        "jitter_below_raw": all(r["default"]["jitter_mm_per_frame2"] < r["raw"]["jitter_mm_per_frame2"] for r in rows),
        "jitter_at_most_sequence": all(r["default"]["jitter_mm_per_frame2"] <= r["sequence"]["jitter_mm_per_frame2"]
                                       for r in with_seq),
        "skating_at_most_sequence": all(r["default"]["skating_mm_per_frame"] <= r["sequence"]["skating_mm_per_frame"]
                                        for r in with_seq),
        "skating_at_most_sequence_on_its_contacts": all(
            r["on_sequence_contacts"]["default"]["skating_mm_per_frame"]
            <= r["on_sequence_contacts"]["sequence"]["skating_mm_per_frame"] for r in with_seq),
        "no_hidden_step": all(r["locks"]["hidden_steps"] == 0 for r in rows),
        "no_release_snap_over_2cm": all(r["locks"]["release_step_cm"] <= 2.0 for r in rows),
    }
    for name, ok in checks.items():
        print(f"{name}: {ok}")
    low = [] if args.no_truth else low_noise_truth()
    if low:
        print(f"known truth at {LOW_NOISE_DEG} deg / {'/'.join(f'{1000 * m:g}' for m in LOW_NOISE_M)} mm noise "
              "(PA-MPJPE mm, acceleration error mm/frame^2; raw / default / previous default):")
    for r in low:
        print(f"  {r['clip']} {r['noise']:12s} PA " + " / ".join(f"{r[m]['pa_mpjpe_mm']:.2f}" for m in
                                                                ("raw", "default", "sequence"))
              + "   accel " + " / ".join(f"{r[m]['accel_error_mm']:.2f}" for m in ("raw", "default", "sequence")))
    path = save("animation_real", {"folder": str(args.folder), "step_m": STEP_M, "tracks": rows, "refused": errors,
                                   "checks": checks, "low_noise_truth": low,
                                   "low_noise": {"rotation_deg": LOW_NOISE_DEG, "root_m": LOW_NOISE_M}})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
