"""Overlay placement per estimator format: pixel error of the pelvis and head against the producer's own drawing.

For every camera-frame format, fixtures are written in the producer's exact layout
(``tests/estimator_fixtures.py``), read by smplik, and the built-in body's pelvis and head are projected
through the scene's overlay camera (:func:`workflows.scene.previews.image_camera`). The reference is where
the producer draws them: the published SMPL rest joints posed by FK plus its translation, through its
camera (for SMPL-X producers only the pelvis is known). Three framings: people 200, 240 and 400 px tall
in a 640 x 480 image; 10 seeds x 2 people (1 for HybrIK and GVHMR) each. The head error is the
built-in body's proportions differing from SMPL's (about 1 cm between pelvis and head); with real
SMPL files configured both are exact. "before" is the pelvis error of the previous rule
(``J0`` of the built-in body instead of the producer's).

SAM-3D-Body (``sam3d``, MHR joints, the SMPL pose fitted by the SMPL-IK solver): the fixtures hold the
MHR joints at the joints of a known pose of our body, the reference is the producer's projection of
``pred_joint_coords + pred_cam_t``; also reported: the fitted body's joint error (mm, all 24 joints).

Against the producer's own render (real files): for every ``hmr4d_results.pt`` under ``--real`` (else
``$SMPLIK_REAL_ESTIMATORS``, else ``<cache>/real/estimators``) that has GVHMR's ``0_input_video.mp4`` and
``1_incam.mp4`` (its in-camera render over the video) beside it, 10 frames per track: the producer's body
is where the two videos differ; its top row (head) and bottom row (feet) are compared with those of our
built-in body's mesh projected through the scene's overlay camera, in % of the producer's body height in
the image (positive: ours lower). ``upper`` / ``lower``: the producer's pelvis-to-head-top and
pelvis-to-feet image lengths over ours (our pelvis pixel for both): which part of the body differs
(SMPL-X betas are another body than the built-in body's, :mod:`workflows.estimators.smplx_shape`; with
``$SMPLIK_SMPLX_MODEL`` set the readers fit our betas to SMPL-X's skeleton and this measures that fit).
Needs imageio with its ffmpeg plugin (``imageio-ffmpeg``); skipped without it or without the files.

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
from smplik.paths import real_estimators_dir  # noqa: E402
from workflows.estimators import read_estimate  # noqa: E402
from workflows.estimators.base import estimator_rest_pelvis, rest_pelvis  # noqa: E402
from workflows.estimators.smplx_shape import smplx_model_path  # noqa: E402

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
    real = real_estimators_dir()
    renders = producer_render_rows(real)
    path = save("estimator_placement", {"image_size": [640, 480], "seeds": SEEDS, "formats": results,
                                        "producer_renders": renders,
                                        "smplx_model": bool(smplx_model_path()),
                                        "note": "head error = built-in body proportions vs SMPL's; SMPL-X "
                                                "producers (gvhmr): pelvis only; sam3d: fitted SMPL pose; "
                                                "producer_renders: % of the body's image height, + = ours lower; "
                                                "upper/lower: producer's pelvis-to-head / pelvis-to-feet over ours "
                                                "(SMPL-X betas read as built-in betas unless smplx_model)"})
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


def _body_rows(video_in: np.ndarray, video_out: np.ndarray, threshold: int = 60, min_pixels: int = 4
               ) -> tuple[int, int] | None:
    """Top and bottom image rows where the producer's render differs from the input frame (its body)."""
    diff = np.abs(video_in.astype(np.int16) - video_out.astype(np.int16)).max(-1) > threshold
    rows = np.nonzero(diff.sum(1) >= min_pixels)[0]
    return (int(rows.min()), int(rows.max())) if rows.size else None


def producer_render_rows(folder: Path, frames_per_track: int = 10) -> dict:
    """Head (top) and feet (bottom) of our overlay vs GVHMR's own in-camera render, per real track."""
    tracks = sorted(folder.rglob("hmr4d_results.pt")) if folder.is_dir() else []
    tracks = [t for t in tracks if (t.parent / "0_input_video.mp4").is_file() and (t.parent / "1_incam.mp4").is_file()]
    if not tracks:
        print(f"producer renders: skipped (no GVHMR track with its videos under {folder})")
        return {}
    try:
        import imageio

        imageio.get_reader(tracks[0].parent / "1_incam.mp4").close()
    except (ImportError, ValueError, RuntimeError, OSError) as exc:
        print(f"producer renders: skipped (cannot decode mp4 with imageio: {exc})")
        return {}
    import torch

    from smplik.body_model import load_body_model
    from workflows.estimators import _load_raw as load_estimator_file
    from workflows.estimators import people_from_data
    from workflows.scene import Scene, SceneCharacter
    from workflows.scene.previews import image_camera

    rows = {}
    print(f"{'GVHMR track':36s} {'frames':>6s} {'head % mean':>11s} {'head % max':>10s} {'feet % mean':>11s} "
          f"{'feet % max':>10s} {'upper':>6s} {'lower':>6s}")
    for path in tracks:
        data = load_estimator_file(path, False, 1 << 30)
        length = len(data["smpl_params_incam"]["body_pose"])
        video_in = imageio.get_reader(path.parent / "0_input_video.mp4")
        video_out = imageio.get_reader(path.parent / "1_incam.mp4")
        head, feet, upper, lower = [], [], [], []
        for f in np.linspace(0, length - 1, frames_per_track).round().astype(int):
            a, b = video_in.get_data(int(f)), video_out.get_data(int(f))
            body = _body_rows(a, b)
            if body is None:
                continue
            p = people_from_data(data, source=str(path), frame=int(f))[0]
            cam = image_camera(Scene((SceneCharacter("p", p.gender, p.betas, pose=p.to_pose()),), camera=p.camera),
                               a.shape[1], a.shape[0])

            def t(x: np.ndarray) -> torch.Tensor:
                return torch.as_tensor(np.asarray(x), dtype=torch.float32)[None]

            with torch.no_grad():
                verts, joints = load_body_model(p.gender).vertices(t(p.global_orient), t(p.body_pose), t(p.transl),
                                                                   t(p.betas))
            points = np.concatenate([verts[0].double().numpy(), joints[0, :1].double().numpy()])
            V = np.linalg.solve(cam.T_world_camera, np.c_[points, np.ones(len(points))].T).T
            v = cam.cy - cam.fy * V[:, 1] / -V[:, 2]
            pelvis, v = v[-1], v[:-1]
            height = body[1] - body[0]
            head.append(100 * (v.min() - body[0]) / height)
            feet.append(100 * (v.max() - body[1]) / height)
            upper.append((pelvis - body[0]) / (pelvis - v.min()))  # the producer's pelvis-to-head / ours
            lower.append((body[1] - pelvis) / (v.max() - pelvis))
        name = str(path.parent.relative_to(folder))
        rows[name] = {"frames": len(head), "head_pct_mean": round(float(np.mean(head)), 2),
                      "head_pct_max_abs": round(float(np.max(np.abs(head))), 2),
                      "feet_pct_mean": round(float(np.mean(feet)), 2),
                      "feet_pct_max_abs": round(float(np.max(np.abs(feet))), 2),
                      "upper_body_ratio_mean": round(float(np.mean(upper)), 3),
                      "lower_body_ratio_mean": round(float(np.mean(lower)), 3),
                      "betas": [round(float(b), 2) for b in np.asarray(data["smpl_params_incam"]["betas"])[0]]}
        r = rows[name]
        print(f"{name:36s} {r['frames']:6d} {r['head_pct_mean']:11.2f} {r['head_pct_max_abs']:10.2f} "
              f"{r['feet_pct_mean']:11.2f} {r['feet_pct_max_abs']:10.2f} {r['upper_body_ratio_mean']:6.3f} "
              f"{r['lower_body_ratio_mean']:6.3f}")
    return rows


def producer_pixels_3d(w, aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """The producer's camera-frame pelvis (N, 3)."""
    from estimator_fixtures import producer_joints

    return producer_joints(aa, transl, w.family)[:, 0]


if __name__ == "__main__":
    main()
