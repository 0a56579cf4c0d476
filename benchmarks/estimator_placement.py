"""Overlay placement per estimator format: pixel error of the pelvis and head against the producer's own drawing.

For every camera-frame format, fixtures are written in the producer's exact layout
(``tests/estimator_fixtures.py``), read by smplik, and the built-in body's pelvis and head are projected
through the scene's overlay camera (:func:`workflows.previews.image_camera`). The reference is where
the producer draws them: the published SMPL rest joints posed by FK plus its translation, through its
camera (for SMPL-X producers only the pelvis is known). Three framings: people 200, 240 and 400 px tall
in a 640 x 480 image; 10 seeds x 2 people (1 for HybrIK and GVHMR) each. The head error is the
built-in body's proportions differing from SMPL's (about 1 cm between pelvis and head); with real
SMPL files configured both are exact. "before" is the pelvis error of the previous rule
(``J0`` of the built-in body instead of the producer's).

SAM-3D-Body (``sam3d``, MHR joints, the SMPL pose fitted by the SMPL-IK solver): the fixtures hold the
MHR joints at the joints of a known pose of our body, the reference is the producer's projection of
``pred_joint_coords + pred_cam_t``; also reported: the fitted body's joint error (mm, all 24 joints).

Prints a table and writes ``benchmarks/results/estimator_placement.json``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the packages first: benchmarks/shape_inversion.py must not shadow shape_inversion/
sys.path.append(str(ROOT / "tests"))
from _common import save  # noqa: E402
from estimator_fixtures import (  # noqa: E402
    CAMERA_WRITERS,
    SINGLE_PERSON,
    framing,
    overlay_pixels,
    people,
    producer_pixels,
    project,
    write_sam3d,
)

from smplik.conventions import Gender  # noqa: E402
from workflows.estimators import read_estimate  # noqa: E402
from workflows.estimators.base import estimator_rest_pelvis, rest_pelvis  # noqa: E402

SEEDS = 10
HEIGHTS_PX = (200.0, 240.0, 400.0)


def main() -> None:
    results: dict[str, dict] = {}
    print(f"{'format':8s} {'person px':>9s} {'pelvis mean':>11s} {'pelvis max':>10s} {'head mean':>9s} "
          f"{'head max':>8s} {'before (pelvis)':>15s}")
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, writer in sorted(CAMERA_WRITERS.items()):
            results[fmt] = {}
            for height in HEIGHTS_PX:
                pelvis, head, before = [], [], []
                for seed in range(SEEDS):
                    n = 1 if fmt in SINGLE_PERSON else 2
                    aa, transl, betas = people(seed=seed, n=n, **framing(fmt, height))
                    folder = Path(tmp) / f"{fmt}_{height:.0f}_{seed}"
                    folder.mkdir()
                    w = writer(folder, aa, transl, betas)
                    found = read_estimate(w.path, space="camera")
                    err = np.linalg.norm(overlay_pixels(found) - producer_pixels(w, aa, transl), axis=-1)
                    pelvis += err[:, 0].tolist()
                    if w.family == "smpl":
                        head += err[:, 1].tolist()
                    J_est = estimator_rest_pelvis(betas, Gender.NEUTRAL, w.family)  # type: ignore[arg-type]
                    shift = rest_pelvis(betas, Gender.NEUTRAL) - J_est  # the old rule's offset (camera: y flipped)
                    shift[:, 1:] *= -1
                    old = project(producer_pixels_3d(w, aa, transl) + shift, w.f, w.cx, w.cy)
                    if fmt == "hybrik":  # HybrIK stores the pelvis itself: the old rule was right there
                        old = producer_pixels(w, aa, transl)[:, 0]
                    before += np.linalg.norm(old - producer_pixels(w, aa, transl)[:, 0], axis=-1).tolist()
                row = {"pelvis_px_mean": round(float(np.mean(pelvis)), 3),
                       "pelvis_px_max": round(float(np.max(pelvis)), 3),
                       "head_px_mean": round(float(np.mean(head)), 3) if head else None,
                       "head_px_max": round(float(np.max(head)), 3) if head else None,
                       "before_fix_pelvis_px_mean": round(float(np.mean(before)), 1), "people": len(pelvis)}
                results[fmt][f"{height:.0f}px_tall"] = row
                hm = "-" if not head else f"{row['head_px_mean']:.2f}"
                hx = "-" if not head else f"{row['head_px_max']:.2f}"
                print(f"{fmt:8s} {height:9.0f} {row['pelvis_px_mean']:11.3f} {row['pelvis_px_max']:10.3f} {hm:>9s} "
                      f"{hx:>8s} {row['before_fix_pelvis_px_mean']:15.1f}")
        results["sam3d"] = sam3d_rows(Path(tmp))
    path = save("estimator_placement", {"image_size": [640, 480], "seeds": SEEDS, "formats": results,
                                        "note": "head error = built-in body proportions vs SMPL's; SMPL-X "
                                                "producers (gvhmr): pelvis only; sam3d: fitted SMPL pose"})
    print(f"wrote {path}")


def sam3d_rows(tmp: Path) -> dict:
    """SAM-3D-Body fixtures: pelvis / head pixels against the producer's projection, and the fit's joint error."""
    from estimator_fixtures import SAM3D_F, our_joints

    from workflows.estimators.base import M_WORLD_CAMERA

    rows = {}
    for height in HEIGHTS_PX:
        px, mm = [], []
        for seed in range(SEEDS):
            aa, transl, _ = people(seed=seed, n=2, depth=SAM3D_F * 1.7 / height, focal=SAM3D_F)
            folder = tmp / f"sam3d_{height:.0f}_{seed}"
            folder.mkdir()
            w, J_cam = write_sam3d(folder, aa, transl)
            found = read_estimate(w.path)
            px.append(np.linalg.norm(overlay_pixels(found) - project(J_cam[:, [0, 15]], w.f, w.cx, w.cy), axis=-1))
            mm += [1000 * np.linalg.norm(our_joints(p) - J_cam[i] @ M_WORLD_CAMERA.T, axis=-1)
                   for i, p in enumerate(found)]
        e, j = np.concatenate(px), np.stack(mm)
        row = {"pelvis_px_mean": round(float(e[:, 0].mean()), 3), "pelvis_px_max": round(float(e[:, 0].max()), 3),
               "head_px_mean": round(float(e[:, 1].mean()), 3), "head_px_max": round(float(e[:, 1].max()), 3),
               "joint_mm_mean": round(float(j.mean()), 2), "joint_mm_max": round(float(j.max()), 2),
               "people": int(e.shape[0])}
        rows[f"{height:.0f}px_tall"] = row
        print(f"{'sam3d':8s} {height:9.0f} {row['pelvis_px_mean']:11.3f} {row['pelvis_px_max']:10.3f} "
              f"{row['head_px_mean']:9.2f} {row['head_px_max']:8.2f} {'-':>15s}  joints {row['joint_mm_mean']:.1f} "
              f"mm mean, {row['joint_mm_max']:.1f} max")
    return rows


def producer_pixels_3d(w, aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """The producer's camera-frame pelvis (N, 3)."""
    from estimator_fixtures import producer_joints

    return producer_joints(aa, transl, w.family)[:, 0]


if __name__ == "__main__":
    main()
