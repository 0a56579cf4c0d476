"""VR recordings through `smplik track` with no options: floor, stature, wrists, frames.

Recordings: held-out CMU clips (test split of ../shared/data/cmu/split.json) on bodies other than the default one,
made into a headset + two controllers CSV (`workflows.tracking.from_motion.write_device_csv`) in each published
layout in turn (Who Is Alyx, Unity HMD Recorder, HP Omnicept, Magic XRoom, and the issue's OpenVR-axes cm/ms
variant), irregular 90 Hz sampling; plus one with its origin at eye level. Each is tracked as `smplik track REC
--out DIR` would (calibration on), and once without calibration (`--no-calibrate`: the default body, the file's
floor) for comparison. Per recording: rows in, frames in (resampled trackers) and out, stature estimated and
true, feet on the floor (share of frames whose mesh's lowest point is within 3 cm of y = 0, on the truth's
standing frames: its lowest point within 3 cm too), median lowest point, wrist to the controller's wrist point
and to the controller's origin (mean, mm), the calibration line.

    python benchmarks/tracking_recordings.py [--clips 4] -> benchmarks/results/tracking_recordings.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import save, shared_dir  # noqa: E402


def lowest_and_joints(anim_file: Path) -> tuple[np.ndarray, np.ndarray]:
    """(T,) the mesh's lowest point per frame and (T, 24, 3) the joints of an animation.json's first track."""
    import torch

    from smplik.body_model import BodyModelSet
    from workflows.animation.files import load_animation

    track = load_animation(anim_file).tracks[0]
    with torch.no_grad():
        v, j = BodyModelSet.load()[track.gender].vertices(
            torch.as_tensor(track.global_orient).float(), torch.as_tensor(track.body_pose).float(),
            torch.as_tensor(track.transl).float(), torch.as_tensor(track.betas).float().expand(track.num_frames, 10))
    return v[..., 1].min(-1).values.numpy(), j.numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", type=int, default=4)
    args = ap.parse_args()
    from smplik.conventions import JOINT_INDEX
    from smplik.tracking.calibrate import body_heights
    from smplik.tracking.csv_io import read_csv_devices, read_csv_trackers
    from workflows.tracking.from_motion import _sole_height, motion_signals, write_device_csv
    from workflows.tracking.run import track_file

    cmu = shared_dir() / "data" / "cmu"
    files = json.loads((cmu / "split.json").read_text())["test"]["files"]
    clips = files[:: max(1, len(files) // args.clips)][: args.clips]
    layouts = [("who-is-alyx", {}), ("unity-hmd-recorder", {}), ("omnicept", {}), ("magic-xroom", {}),
               ("who-is-alyx", {"units": "cm", "axes": "openvr"})]
    bodies = [(1.5, "male"), (-1.5, "female"), (0.8, "neutral"), (-0.8, "neutral")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = [(clip, layouts[i % len(layouts)], bodies[i % len(bodies)], False) for i, clip in enumerate(clips)]
        cases.append((clips[0], layouts[4], bodies[0], True))  # the origin at eye level; OpenVR axes, cm, ms
        for n, (clip, (producer, opts), (beta0, gender), eye_level) in enumerate(cases):
            betas = np.zeros(10)
            betas[0] = beta0
            sig, truth = motion_signals(cmu / clip, betas=betas, gender=gender)
            if eye_level:
                from dataclasses import replace

                sig = replace(sig, positions=sig.positions - [0.0, 1.6, 0.0])
            path = write_device_csv(sig, tmp / f"rec{n}.csv", producer, **opts)
            rec = read_csv_devices(path)
            raw = read_csv_trackers(path, controller="none")  # the controllers' origins
            wrist_points = read_csv_trackers(path)
            truth_low = _sole_height(truth.R_local, truth.transl, truth.betas, truth.gender)  # ~0 by construction
            row = {"clip": clip, "layout": producer, "layout_options": opts, "body": {"beta0": beta0, "gender": gender},
                   "origin_at_eye_level": eye_level, "rows_in": int(len(rec.times)), "reader_notes": list(rec.notes),
                   "frames_in": int(wrist_points.num_frames),
                   "true_stature_m": round(body_heights(betas, gender)[1], 4),
                   "truth_lowest_point_median_mm": round(1000 * truth_low, 1)}
            for mode, calibrate in (("calibrated", True), ("uncalibrated", False)):
                t0 = time.perf_counter()
                out = track_file(path, tmp / f"out{n}_{mode}", formats=[], gender=gender if calibrate else "neutral",
                                 calibrate=calibrate)
                low, joints = lowest_and_joints(out.animation_file)
                T = min(len(low), wrist_points.num_frames)
                lift = np.array([0.0, out.calibration.floor_y if out.calibration is not None else 0.0, 0.0])
                wr = [JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]]
                to_point = np.linalg.norm(joints[:T, wr] - (wrist_points.positions[:T, 1:3] - lift), axis=-1)
                to_origin = np.linalg.norm(joints[:T, wr] - (raw.positions[:T, 1:3] - lift), axis=-1)
                on = np.abs(low) < 0.03
                row[mode] = {
                    "frames_out": int(out.animation.tracks[0].num_frames),
                    "feet_on_floor_pct": round(100 * float(on.mean()), 1),
                    "lowest_point_median_mm": round(1000 * float(np.median(low)), 1),
                    "wrist_to_wrist_point_mm": round(1000 * float(to_point.mean()), 1),
                    "wrist_to_controller_mm": round(1000 * float(to_origin.mean()), 1),
                    "anomaly_rate": round(out.anomaly_rate, 4), "seconds": round(time.perf_counter() - t0, 2)}
                if out.calibration is not None:
                    row[mode].update(stature_m=round(out.calibration.stature_m, 4),
                                     calibration=out.calibration.summary(), message=out.calibration.message)
            row["frames_in_equals_out"] = row["frames_in"] == row["calibrated"]["frames_out"]
            print(json.dumps({k: row[k] for k in ("clip", "layout", "frames_in")}), row["calibrated"], flush=True)
            rows.append(row)
    cal = [r["calibrated"] for r in rows]
    unc = [r["uncalibrated"] for r in rows]
    summary = {
        "recordings": len(rows),
        "frames_in_equals_out": all(r["frames_in_equals_out"] for r in rows),
        "stature_abs_error_max_cm": round(100 * max(abs(r["calibrated"]["stature_m"] - r["true_stature_m"])
                                                    for r in rows if not r["origin_at_eye_level"]), 2),
        "feet_on_floor_pct_median": {"calibrated": float(np.median([c["feet_on_floor_pct"] for c in cal])),
                                     "uncalibrated": float(np.median([c["feet_on_floor_pct"] for c in unc]))},
        "wrist_to_wrist_point_mm_mean": {"calibrated": float(np.mean([c["wrist_to_wrist_point_mm"] for c in cal]))},
    }
    save("tracking_recordings", {"summary": summary, "recordings": rows})
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
