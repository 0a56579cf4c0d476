"""Camera-space cleaning against a known truth: the ground's velocity (constant, or varying over time) in a camera
that pans with the person and in a still one.

CMU clips (``benchmarks/animation_truth.py``'s splits; ``--split validation`` for choices) are seen from a camera
that translates with the person (``pan``: the camera follows the pelvis's horizontal path smoothed over
:data:`PAN_SIGMA_FRAMES`, so the ground moves through its frame at a speed that changes with every stride) or
stands still (``still``), as a camera-space estimator gives them; synthetic estimates add
``animation_truth``'s independent and frame-correlated (AR(1)) noise. Each is cleaned as ``scene animate`` cleans
a camera-space track (``ground_moves``) with:

* ``constant``: the ground's velocity constant over the clip (``ground_smoothness=None``, the earlier default);
* ``default``: a varying ground where it explains at least :data:`smplik.contacts.GROUND_VARYING_GAIN` times the
  low feet of the constant one (:func:`smplik.contacts.ground_track`);
* ``ungated``: a varying ground wherever it explains 3 more low feet than the constant one.

Per variant: PA-MPJPE and acceleration error against the truth (mm, mm/frame^2), skating over the truth's contacts
relative to the *true* ground (the camera's motion; mm/frame), contact foot-frames, and whether the ground varied.
Prints a table and writes ``benchmarks/results/animation_ground.json`` (``animation_ground_validation.json``);
without the CMU data it says so and exits 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
import animation_truth as truth  # noqa: E402
from _common import save, shared_dir  # noqa: E402

PAN_SIGMA_FRAMES = 4.0
"""Gaussian smoothing (frames) of the pelvis path the panning camera follows: it keeps up with each stride."""
NOISE = ("independent", "ar1")
VARIANTS = ("constant", "default", "ungated")


def camera_view(poses: list, follow: bool) -> tuple[list, np.ndarray]:
    """The poses seen from a camera that translates along the pelvis's smoothed horizontal path (``follow``) or
    stands still, and the ground's true velocity in its frame (T, 3) m/frame."""
    from scipy.ndimage import gaussian_filter1d

    from smplik.pose import Pose

    T = len(poses)
    path = np.zeros((T, 3))
    if follow:
        path = gaussian_filter1d(truth._joints(poses)[:, 0], PAN_SIGMA_FRAMES, axis=0, mode="nearest")
        path[:, 1] = 0.0
    seen = [Pose(p.global_orient, p.body_pose, p.transl - path[t], p.betas, p.gender) for t, p in enumerate(poses)]
    return seen, np.gradient(-path, axis=0)


def clean_variant(poses: list, variant: str):
    """``clean_track`` of a camera-space track with the ground of ``variant``; also whether the ground varied."""
    import smplik.contacts as contacts
    from workflows.animation.clean import CleanConfig, foot_noise, ground_of
    from workflows.animation.clips import clean_track

    smoothness = None if variant == "constant" else CleanConfig().ground_smoothness
    cfg = CleanConfig(ground_moves=True, ground_smoothness=smoothness)
    saved = contacts.GROUND_VARYING_GAIN
    contacts.GROUND_VARYING_GAIN = 1.0 if variant == "ungated" else saved
    try:
        out = clean_track(poses, truth.FPS, cfg, 1.0)
        free = clean_track(poses, truth.FPS, dataclasses.replace(cfg, foot_lock=False), 1.0)[4]
        ground = ground_of(free, truth.FPS, cfg, noise=foot_noise(out[3], free, truth.FPS))  # as clean_track finds it
    finally:
        contacts.GROUND_VARYING_GAIN = saved
    return out, bool(np.ptp(ground, axis=0).max() > 0.0)


def bench_clip(name: str, label: str, poses: list, seed: int) -> list[dict]:
    from workflows.animation.clean import CleanConfig, foot_contacts, foot_skating

    contacts_true = foot_contacts(truth._joints(poses), truth.FPS, CleanConfig())  # world frame: a still ground
    rows = []
    for camera in ("pan", "still"):
        seen, ground_true = camera_view(poses, camera == "pan")
        p_true = truth._joints(seen)
        for m, model in enumerate(NOISE):
            est = truth.make_estimate(seen, model, seed + 1000 * m)
            row: dict = {"clip": name, "motion": label, "camera": camera, "noise": model, "frames": len(poses),
                         "truth_contact_frames": int(contacts_true.sum())}
            for variant in VARIANTS:
                out, varied = clean_variant(est.poses, variant)
                r = truth.metrics(out[4], p_true, contacts_true)
                row[variant] = {"pa_mpjpe_mm": r["pa_mpjpe_mm"], "accel_error_mm": r["accel_error_mm"],
                                "skating_true_ground_mm_per_frame": round(
                                    1000 * foot_skating(out[4], contacts_true, ground_true), 3),
                                "contact_frames": int(out[2].sum()), "ground_varies": varied}
            rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--split", choices=("test", "validation"), default="validation")
    parser.add_argument("--frames", type=int, default=240, help="Frames (30 frames/s) per clip at most.")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    clips = truth.TEST_CLIPS if args.split == "test" else truth.VALIDATION_CLIPS
    rows: list[dict] = []
    for i, (name, label) in enumerate(clips.items()):
        poses = truth.load_truth(name, args.frames)
        if poses is None:
            continue
        rows += bench_clip(name, label, poses, args.seed + 10 * i)
    if not rows:
        print(f"no CMU clips under {shared_dir() / 'data' / 'cmu'}; nothing to do")
        return
    print(f"{'clip':7s} {'camera':6s} {'noise':12s} " + " | ".join(
        f"{v}: PA / accel / skating (true ground) / contacts / varies" for v in VARIANTS))
    for r in rows:
        print(f"{r['clip']:7s} {r['camera']:6s} {r['noise']:12s} " + " | ".join(
            f"{r[v]['pa_mpjpe_mm']:.2f} / {r[v]['accel_error_mm']:.2f} / {r[v]['skating_true_ground_mm_per_frame']:.2f}"
            f" / {r[v]['contact_frames']} / {'yes' if r[v]['ground_varies'] else 'no'}" for v in VARIANTS))
    means = {v: {k: round(float(np.mean([r[v][k] for r in rows])), 3)
                 for k in ("pa_mpjpe_mm", "accel_error_mm", "skating_true_ground_mm_per_frame")} for v in VARIANTS}
    for v, mean in means.items():
        print(f"mean {v:9s} PA {mean['pa_mpjpe_mm']:.2f}  accel {mean['accel_error_mm']:.2f}  "
              f"skating {mean['skating_true_ground_mm_per_frame']:.2f}")
    name = "animation_ground" if args.split == "test" else "animation_ground_validation"
    path = save(name, {"split": args.split, "frames_max": args.frames, "seed": args.seed,
                       "pan_sigma_frames": PAN_SIGMA_FRAMES, "noise": NOISE, "rows": rows, "means": means})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
