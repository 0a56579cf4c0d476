"""Retargeting quality on the CMU clips: angle between retargeted SMPL bones and source bones.

For every ``*.bvh`` in the CMU folder (``--cmu-dir``, else :func:`smplik.paths.cmu_dir`:
``$SMPLIK_CMU_DIR``, else ``<repo>/../shared/data/cmu``) the clip is retargeted with the ``cmu`` preset onto the neutral
built-in body (or ``$SMPLIK_MODEL_DIR``), and for each scored bone (thighs, shins, feet, spine,
neck, upper arms, forearms) the angle between the SMPL bone (our FK on ``J(beta)``) and the
source bone is taken, skipping the rest frame 0 and using every ``--stride``-th frame.
Diagnostic bones (hip and shoulder lines, clavicles, hands) are reported but not scored.

Writes ``benchmarks/results/retarget_quality.json``::

    {"per_clip": {clip: mean_deg}, "overall": {"mean_deg", "max_deg", "per_bone_group", ...}, ...}

Usage: ``python benchmarks/retarget_quality.py [--cmu-dir DIR] [--stride 4] [--out PATH]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from smplik.atomic import write_json_atomic  # noqa: E402
from smplik.data.bvh import read_bvh  # noqa: E402
from smplik.data.retarget import DIAGNOSTIC_BONES, bone_direction_errors, retarget_bvh  # noqa: E402
from smplik.paths import cmu_dir as default_cmu_dir  # noqa: E402
from smplik.paths import missing_cmu_reason  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cmu-dir", type=Path, default=None, help="Folder of CMU BVH files.")
    parser.add_argument("--stride", type=int, default=4, help="Score every N-th motion frame (default 4).")
    parser.add_argument("--gender", default="neutral")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "retarget_quality.json")
    args = parser.parse_args(argv)
    cmu_dir = args.cmu_dir or default_cmu_dir()
    if cmu_dir is None:
        parser.error(missing_cmu_reason())
    files = sorted(cmu_dir.glob("*.bvh"))
    if not files:
        parser.error(f"no .bvh files in {cmu_dir} (use --cmu-dir or $SMPLIK_CMU_DIR)")

    t0 = time.perf_counter()
    per_clip: dict[str, float] = {}
    per_clip_max: dict[str, float] = {}
    rest_modes: dict[str, str] = {}
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    diag_sums: dict[str, float] = {}
    abl_sums: dict[str, float] = {}
    all_max = 0.0
    frames_scored = 0
    for path in files:
        motion = read_bvh(path)
        clip = retarget_bvh(motion, "cmu", gender=args.gender)
        frames = slice(clip.motion_start, None, args.stride)
        err = bone_direction_errors(clip, frames=frames)
        diag = bone_direction_errors(clip, frames=frames, bones=DIAGNOSTIC_BONES)
        ablation = bone_direction_errors(retarget_bvh(motion, "cmu", gender=args.gender, fit_directions=False),
                                         frames=frames)
        for i, g in enumerate(ablation.groups):
            abl_sums[g] = abl_sums.get(g, 0.0) + float(ablation.degrees[:, i].sum())
        per_clip[path.stem] = round(err.mean(), 6)
        per_clip_max[path.stem] = round(float(err.degrees.max()), 6)
        rest_modes[path.stem] = clip.rest_mode
        all_max = max(all_max, float(err.degrees.max()))
        n = err.degrees.shape[0]
        frames_scored += n
        for i, g in enumerate(err.groups):
            sums[g] = sums.get(g, 0.0) + float(err.degrees[:, i].sum())
            counts[g] = counts.get(g, 0) + n
        for i, b in enumerate(diag.bones):
            diag_sums[b] = diag_sums.get(b, 0.0) + float(diag.degrees[:, i].sum())
        print(f"{path.stem}: {err.mean():.5f} deg (max {err.degrees.max():.4f}, {n} frames, rest {clip.rest_mode})")
    seconds = time.perf_counter() - t0
    group_means = {g: round(sums[g] / counts[g], 6) for g in sums}
    overall = float(sum(sums.values()) / sum(counts.values()))
    result = {
        "metric": "angle in degrees between each retargeted SMPL bone direction (FK on the body model's rest "
                  "joints) and the source BVH bone direction; mean over bones and scored frames",
        "method": "rest-pose alignment (source rest = frame 0 or the OFFSET pose, whichever is closer to a T-pose) "
                  "plus a per-frame minimal-rotation fit of each joint's aim bone; see smplik/data/retarget.py",
        "cmu_dir": str(cmu_dir),
        "clips": len(files),
        "frames_scored": frames_scored,
        "frame_stride": args.stride,
        "skipped": "frame 0 of every clip (rest pose)",
        "gender": args.gender,
        "per_clip": per_clip,
        "per_clip_max_deg": per_clip_max,
        "rest_mode": rest_modes,
        "overall": {
            "mean_deg": round(overall, 6),
            "max_deg": round(all_max, 6),
            "per_bone_group": group_means,
        },
        "ablation_rest_alignment_only": {
            "note": "fit_directions=False: rest-pose alignment alone, without the per-frame direction fit",
            "mean_deg": round(sum(abl_sums.values()) / sum(counts.values()), 4),
            "per_bone_group": {g: round(abl_sums[g] / counts[g], 4) for g in abl_sums},
        },
        "diagnostic_bones_mean_deg": {b: round(v / frames_scored, 3) for b, v in diag_sums.items()},
        "runtime_s": round(seconds, 1),
    }
    write_json_atomic(args.out, result)
    print(f"overall: {overall:.5f} deg over {len(files)} clips, {frames_scored} frames "
          f"(per group: {', '.join(f'{g} {v:.5f}' for g, v in group_means.items())}); {seconds:.1f} s -> {args.out}")
    print(f"ablation (rest alignment only): {result['ablation_rest_alignment_only']}")
    return result


if __name__ == "__main__":
    main()
