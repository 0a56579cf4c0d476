"""Offline foot-lock parameters on the validation split: MPJPE, MPJAE (all joints and legs) and foot skating of
the deterministic tracker for lock settings of :class:`TrackerRuntimeConfig`, each varied alone around the defaults
(:data:`SWEEP`).

Same data, bodies and trackers (exact) as ``benchmarks/tracking.py``; the network runs once per clip without locks
and :func:`smplik.tracking.runtime.offline_foot_lock` is applied per setting. Also reports the share of the
truth's contact frames inside a locked segment, and the offline pass's cost per frame (default settings).

Usage: ``python benchmarks/tracking_locks.py --cache PATH [--split validation] [--frames 100]`` ->
``benchmarks/results/tracking_locks.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402
from tracking import joints, metrics  # noqa: E402

from smplik.body_model import BodyModelSet  # noqa: E402
from smplik.conventions import Gender  # noqa: E402
from smplik.rotations import axis_angle_to_matrix  # noqa: E402
from smplik.tracking.config import TrackerRuntimeConfig  # noqa: E402
from smplik.tracking.io import signals_from_motion  # noqa: E402
from smplik.tracking.model_io import load_model  # noqa: E402
from smplik.tracking.runtime import Tracker, offline_foot_lock, track_sequence  # noqa: E402
from workflows.animation.clean import CleanConfig, foot_contacts  # noqa: E402

SWEEP = {"contact_on": (0.5, 0.4, 0.35, 0.3), "contact_off": (0.2, 0.3), "min_contact_frames": (4, 8),
         "lock_spread_m": (0.2, 0.3, 0.4, 0.5, 100.0), "lock_blend_frames": (6, 10, 15, 20),
         "lock_reach": (1.0, 0.99, 0.98, 0.97, 0.95), "lock_smooth_frames": (0.0, 1.0, 1.5, 2.0, 3.0),
         "lock_repin": (True, False), "lock_centre": ("median", "min")}
"""Each parameter varied alone around the runtime's defaults."""


def load_clips(cache: Path, split: str, frames: int) -> list[tuple]:
    """Per clip of ``split``: ``(J, p_true, contact, raw, causal, fps, (lo, hi))``, raw = the unlocked network
    output ``(R_local, transl, contact_prob)``, causal = the streaming locks' :class:`TrackResult`."""
    from smplik.data.dataset import load_cache

    data = load_cache(cache).subset(split)
    fps, model, bodies = data.fps, load_model(), BodyModelSet.load()
    lo, hi = model.pose_lo.numpy(), model.pose_hi.numpy()
    rng = np.random.default_rng(0)
    clips = []
    for c in np.unique(data.clip_id.numpy()):  # the same bodies and trackers as benchmarks/tracking.py
        clip = data.select(data.clip_id == int(c))
        T = min(frames, len(clip))
        betas = rng.standard_normal(10)
        gender = list(Gender)[int(rng.integers(3))]
        J = bodies.rest_joints(torch.as_tensor(betas, dtype=torch.float32), torch.tensor(gender.index)).double().numpy()
        R_true = axis_angle_to_matrix(clip.pose[:T].double()).numpy()
        transl_true = clip.transl[:T].double().numpy()
        _, p_true = joints(R_true, transl_true, J)
        contact = foot_contacts(p_true, fps, CleanConfig())
        sig = signals_from_motion(R_true, transl_true, J, model.cfg.trackers, fps, rng=np.random.default_rng(int(c)))
        tr = Tracker.load(betas=betas, gender=gender, config=TrackerRuntimeConfig(foot_lock=False))
        tr.reset(sig.has_rotation)
        poses = [tr.step(sig.positions[t], sig.rotations[t]) for t in range(sig.num_frames)]
        raw = (np.stack([p.R_local for p in poses]), np.stack([p.transl for p in poses]),
               np.stack([p.contact_prob for p in poses]))
        causal = track_sequence(Tracker.load(betas=betas, gender=gender,
                                             config=TrackerRuntimeConfig(offline_lock=False)), sig)
        clips.append((J, p_true, contact, raw, causal, fps, (lo, hi)))

    return clips


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", required=True, help="60 Hz pose cache (benchmarks/tracking.py builds it).")
    ap.add_argument("--split", default="validation", choices=("train", "validation", "test"))
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    torch.set_num_threads(1)
    threadpool_limits(1)
    clips = load_clips(Path(args.cache), args.split, args.frames)
    fps, lo, hi = clips[0][5], *clips[0][6]

    def score(fn) -> dict[str, float]:  # noqa: ANN001
        rows, cover = [], []
        for J, p_true, contact, raw, causal, *_ in clips:
            R, locked = fn(J, raw, causal)
            rows.append(metrics(R, joints(R, raw[1], J)[1], p_true, contact, fps, lo, hi))
            cover.append((locked & contact).sum() / max(contact.sum(), 1))
        w = np.array([r["frames"] for r in rows], float)
        keys = ("mpjpe_mm", "mpjae_cm_s2", "legs_mpjae_cm_s2", "skating_mm_per_frame")
        out = {k: round(float(np.average([r[k] for r in rows], weights=w)), 3) for k in keys}
        out["contact_cover"] = round(float(np.average(cover, weights=[c[2].sum() for c in clips])), 3)
        return out

    results = {"none": score(lambda J, raw, causal: (raw[0], np.zeros((len(raw[0]), 2), bool))),
               "causal": score(lambda J, raw, causal: (causal.R_local, causal.contacts))}
    for k, v in results.items():
        print(f"{k:60s} {v}", flush=True)
    base = TrackerRuntimeConfig()
    results["default"] = score(lambda J, raw, causal: offline_foot_lock(raw[0], raw[1], raw[2], J, base))
    print(f"{'default':60s} {results['default']}", flush=True)
    t0 = time.perf_counter()
    for J, _, _, raw, *_ in clips:
        offline_foot_lock(raw[0], raw[1], raw[2], J, base)
    cost = 1000 * (time.perf_counter() - t0) / sum(len(c[3][0]) for c in clips)
    print(f"offline pass, default settings: {cost:.3f} ms per frame (one thread)")
    for key, values in SWEEP.items():
        for value in values:
            if value == getattr(base, key):
                continue
            cfg = replace(base, **{key: value})
            label = f"{key}={value}"
            results[label] = score(lambda J, raw, causal, cfg=cfg: offline_foot_lock(raw[0], raw[1], raw[2], J, cfg))
            print(f"{label:60s} {results[label]}", flush=True)
    path = save("tracking_locks", {"split": args.split, "frames_per_clip": args.frames, "results": results,
                                   "offline_ms_per_frame": round(cost, 4)})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
