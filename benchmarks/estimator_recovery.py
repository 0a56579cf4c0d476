"""Effector recovery on every frame of real estimator tracks: worst-frame and mean error, effectors used.

Real third-party files are not shipped (their licences do not allow it); the script reads a folder
(``--data``, else ``$SMPLIK_REAL_ESTIMATORS``, else ``<cache>/real/estimators``) and skips cleanly when
it is absent. Tracks found there (any depth):

* ``hmr4d_results.pt``: GVHMR ``tools/demo/demo.py`` outputs (read in its camera frame, as
  ``smplik from-estimate`` does by default);
* ``*.pkl`` with the AIST++ motion layout (``smpl_poses``, ``smpl_trans``).

Every frame of every track is read with :func:`workflows.estimators.people_from_data`, put on its own
body exactly as the pipeline does (:func:`workflows.scene.pipeline.retarget_to_body`) and recovered with
``RecoveryConfig(max_effectors=8, threshold=0)`` (the search runs to 8 effectors on every frame) by
the shipped model on one CPU thread. The error of a frame is the mean per-joint error (mm) of the
final pose, the full-refinement solve of the recovered effectors (what the scene re-solves to).

Prints a table and writes ``benchmarks/results/estimator_recovery.json``.
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
sys.path.insert(1, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402

from smplik.paths import real_estimators_dir  # noqa: E402
from workflows.estimators import EstimateFormatError, detect_format, people_from_data  # noqa: E402
from workflows.estimators import _load_raw as load_estimator_file  # noqa: E402
from workflows.scene.pipeline import retarget_to_body  # noqa: E402
from workflows.scene.recovery import RecoveryConfig, TargetPose, recover_many  # noqa: E402

LIMIT_MM = 40.0
CHUNK = 128


def track_length(data: dict, fmt: str) -> int:
    """Frames in a track of a format this benchmark reads."""
    if fmt == "gvhmr":
        return len(data["smpl_params_incam"]["body_pose"])
    return len(data["smpl_poses"])


def find_tracks(folder: Path) -> list[tuple[str, Path, dict]]:
    """``(format, path, loaded data)`` of every GVHMR / AIST++ file under ``folder`` (sorted paths)."""
    tracks = []
    for path in sorted(list(folder.rglob("hmr4d_results.pt")) + list(folder.rglob("*.pkl"))):
        try:
            data = load_estimator_file(path, False, 1 << 30)
            fmt = detect_format(data)
        except (EstimateFormatError, ValueError) as exc:
            print(f"skipped {path}: {exc}")
            continue
        if fmt in ("gvhmr", "aist"):
            tracks.append((fmt, path, data))
    return tracks


def targets_of(fmt: str, path: Path, data: dict) -> list[TargetPose]:
    """Every frame's person (one per frame in these formats) on its own body, as the pipeline does."""
    out = []
    for f in range(track_length(data, fmt)):
        person = people_from_data(data, source=str(path), format=fmt, frame=f)[0]  # type: ignore[arg-type]
        out.append(TargetPose.from_pose(retarget_to_body(person, person.betas, person.gender, 1.0)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=real_estimators_dir())
    parser.add_argument("--checkpoint", type=Path, default=None)
    parser.add_argument("--max-effectors", type=int, default=8)
    args = parser.parse_args()
    if not args.data.is_dir():
        print(f"skipped: no real estimator files at {args.data} (--data or $SMPLIK_REAL_ESTIMATORS)")
        return
    tracks = find_tracks(args.data)
    if not tracks:
        print(f"skipped: no GVHMR or AIST++ tracks under {args.data}")
        return
    torch.set_num_threads(1)
    from smplik.solver import IKSolver

    solver = IKSolver.load(args.checkpoint)
    cfg = RecoveryConfig(max_effectors=args.max_effectors, threshold=0.0)
    rows, all_err = {}, []
    print(f"{'track':34s} {'format':6s} {'frames':>6s} {'mean mm':>8s} {'median':>7s} {'p95':>6s} {'worst':>6s} "
          f"{'@frame':>6s} {f'>{LIMIT_MM:.0f}mm':>6s} {'effectors':>9s} {'s':>6s}")
    for fmt, path, data in tracks:
        name = str(path.relative_to(args.data))
        targets = targets_of(fmt, path, data)
        t0 = time.perf_counter()
        results = []
        for start in range(0, len(targets), CHUNK):
            results += recover_many(solver, targets[start:start + CHUNK], cfg)
        seconds = time.perf_counter() - t0
        err = np.array([r.final_error for r in results]) * 1000
        used = np.array([len(r.effectors) for r in results])
        all_err.append(err)
        worst = int(np.argmax(err))
        rows[name] = {"format": fmt, "frames": len(err), "mean_mm": round(float(err.mean()), 2),
                      "median_mm": round(float(np.median(err)), 2),
                      "p95_mm": round(float(np.percentile(err, 95)), 2), "worst_mm": round(float(err.max()), 2),
                      "worst_frame": worst, f"frames_over_{LIMIT_MM:.0f}mm": int((err > LIMIT_MM).sum()),
                      "effectors_used": {"mean": round(float(used.mean()), 2), "min": int(used.min()),
                                         "max": int(used.max())},
                      "worst_frame_effectors": [f"{e.joint_name}:{e.type.name.lower()}"
                                                for e in results[worst].effectors],
                      "seconds": round(seconds, 1)}
        r = rows[name]
        print(f"{name:34s} {fmt:6s} {r['frames']:6d} {r['mean_mm']:8.1f} {r['median_mm']:7.1f} {r['p95_mm']:6.1f} "
              f"{r['worst_mm']:6.1f} {worst:6d} {r[f'frames_over_{LIMIT_MM:.0f}mm']:6d} "
              f"{used.mean():9.2f} {seconds:6.1f}")
    err = np.concatenate(all_err)
    total = {"frames": int(err.size), "mean_mm": round(float(err.mean()), 2),
             "worst_mm": round(float(err.max()), 2), f"frames_over_{LIMIT_MM:.0f}mm": int((err > LIMIT_MM).sum())}
    print(f"all {total['frames']} frames: mean {total['mean_mm']:.1f} mm, worst {total['worst_mm']:.1f} mm, "
          f"{total[f'frames_over_{LIMIT_MM:.0f}mm']} frames over {LIMIT_MM:.0f} mm")
    path = save("estimator_recovery", {
        "model": solver.source, "max_effectors": cfg.max_effectors, "threshold_m": cfg.threshold,
        "search_refine_steps": cfg.search_refine_steps, "torch_threads": 1,
        "error": "mean per-joint L2 error of the final pose (full refinement of the recovered effectors), mm",
        "tracks": rows, "all": total})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
