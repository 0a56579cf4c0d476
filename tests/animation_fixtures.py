"""Video estimator outputs (many frames, tracks that start late or have gaps) in each producer's exact layout.

No tests here: ``test_animation.py`` uses it. The single-frame writers and the producers' conventions are in
``estimator_fixtures.py``; these write the same layouts with one pose per frame:

* GVHMR ``tools/demo/demo.py``: ``torch.save(pred, 'hmr4d_results.pt')``, ``smpl_params_incam`` /
  ``smpl_params_global`` dicts of (L, ...) tensors and ``K_fullimg (L, 3, 3)``.
* WHAM ``demo.py``: ``joblib.dump(results, 'wham_output.pkl')``, ``results[track_id]`` with ``pose (T, 72)``,
  ``trans``, ``pose_world``, ``trans_world``, ``betas (T, 10)``, ``verts``, ``frame_ids (T,)``.
* PHALP ``PHALP.track``: ``joblib.dump(final_visuals_dic, path, compress=3)``, one dict per frame name with
  per-detection lists ``smpl`` (rotation matrices), ``camera``, ``tid``, ``size``.
"""

from __future__ import annotations

from pathlib import Path

import joblib
import numpy as np
import torch
from estimator_fixtures import _R, FOCAL, IMAGE_H, IMAGE_W, depth_for, people
from scipy.spatial.transform import Rotation

M = np.diag([1.0, -1.0, -1.0])


def video_motion(T: int, seed: int = 0, fmt: str = "gvhmr", x: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A walking-in-place motion over T frames in a producer's camera convention (OpenCV axes):
    aa (T, 24, 3) with swinging legs and arms plus estimator-like jitter, transl (T, 3)."""
    rng = np.random.default_rng(seed)
    aa0, t0, _ = people(seed=seed, n=1, depth=depth_for(fmt), focal=FOCAL[fmt])
    phase = 2 * np.pi * np.arange(T) / 30.0
    aa = np.repeat(aa0 * 0.3, T, 0)
    aa[:, 0] = aa0[0, 0]
    swing = 0.5 * np.sin(phase)
    aa[:, 1, 0] += swing  # left hip
    aa[:, 2, 0] -= swing
    aa[:, 4, 0] += 0.4 * (1 + np.sin(phase))  # knees
    aa[:, 5, 0] += 0.4 * (1 - np.sin(phase))
    aa[:, 16, 2] -= 1.0 + 0.3 * np.sin(phase)  # shoulders
    aa[:, 17, 2] += 1.0 + 0.3 * np.sin(phase)
    aa[:, 1:] += rng.normal(0, 0.02, (T, 23, 3))
    transl = np.repeat(t0, T, 0) + np.array([x, 0.0, 0.0]) + rng.normal(0, 0.005, (T, 3))
    return aa, transl


def _world(aa: np.ndarray, transl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-convention people -> the same people in a y-up world (roots rotated by M; same rest-pelvis rule
    is ignored: a producer's world transl is just another smplx transl)."""
    go = Rotation.from_matrix(M @ _R(aa[:, 0])).as_rotvec()
    out = aa.copy()
    out[:, 0] = go
    return out, transl @ M.T


def write_gvhmr_video(folder: Path, aa: np.ndarray, transl: np.ndarray) -> Path:
    """GVHMR's ``hmr4d_results.pt`` over L = len(aa) frames (one person)."""
    L = aa.shape[0]
    f, cx, cy = FOCAL["gvhmr"], IMAGE_W / 2, IMAGE_H / 2
    aa_w, t_w = _world(aa, transl)

    def params(a: np.ndarray, t: np.ndarray) -> dict:
        return {"body_pose": torch.tensor(a[:, 1:22].reshape(L, 63), dtype=torch.float32),
                "global_orient": torch.tensor(a[:, 0], dtype=torch.float32),
                "transl": torch.tensor(t, dtype=torch.float32), "betas": torch.zeros(L, 10)}

    pred = {"smpl_params_global": params(aa_w, t_w), "smpl_params_incam": params(aa, transl),
            "K_fullimg": torch.tensor([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]).expand(L, 3, 3).clone(),
            "net_outputs": {"pred_cam": torch.zeros(L, 3)}}
    path = folder / "hmr4d_results.pt"
    torch.save(pred, path)
    return path


def write_wham_video(folder: Path, tracks: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Path:
    """WHAM's ``wham_output.pkl``: ``{track_id: (aa (T, 24, 3), transl (T, 3), frame_ids (T,))}``."""
    out = {}
    for tid, (aa, transl, frame_ids) in tracks.items():
        T = aa.shape[0]
        aa_w, t_w = _world(aa, transl)
        out[tid] = {"pose": aa.reshape(T, 72).astype(np.float32), "trans": transl.astype(np.float32),
                    "pose_world": aa_w.reshape(T, 72).astype(np.float32), "trans_world": t_w.astype(np.float32),
                    "betas": np.zeros((T, 10), np.float32), "verts": np.zeros((T, 4, 3), np.float32),
                    "frame_ids": np.asarray(frame_ids)}
    path = folder / "wham_output.pkl"
    joblib.dump(out, path)
    return path


def write_phalp_video(folder: Path, frames: list[dict[int, tuple[np.ndarray, np.ndarray]]]) -> Path:
    """PHALP's per-frame dict; ``frames[t] = {tid: (aa (24, 3), transl (3,))}`` (an empty dict: nobody)."""
    data = {}
    for t, people_t in enumerate(frames):
        tids = sorted(people_t)
        data[f"img/{t + 1:06d}.jpg"] = {
            "time": t, "shot": 0, "frame_path": f"img/{t + 1:06d}.jpg", "tid": tids, "tracked_ids": tids,
            "bbox": [np.zeros(4)] * len(tids),
            "smpl": [{"global_orient": _R(people_t[i][0][:1]).astype(np.float32),
                      "body_pose": _R(people_t[i][0][1:]).astype(np.float32),
                      "betas": np.zeros(10, np.float32)} for i in tids],
            "camera": [people_t[i][1].astype(np.float32) for i in tids], "size": [[IMAGE_H, IMAGE_W]] * len(tids),
            "conf": [1.0] * len(tids)}
    path = folder / "demo_video.pkl"
    joblib.dump(data, path, compress=3)
    return path


def walking_joints(T: int = 40, seed: int = 0, scale: float = 1.0, betas: np.ndarray | None = None) -> np.ndarray:
    """(T, 24, 3) joints of our body walking forward (y-up metres, facing +z), SMPL order."""
    rng = np.random.default_rng(seed)
    phase = 2 * np.pi * np.arange(T) / 20.0
    aa = np.zeros((T, 24, 3))
    aa[:, 1, 0], aa[:, 2, 0] = 0.5 * np.sin(phase), -0.5 * np.sin(phase)
    aa[:, 4, 0], aa[:, 5, 0] = 0.5 * (1 + np.sin(phase)), 0.5 * (1 - np.sin(phase))
    aa[:, 16, 2], aa[:, 17, 2] = -1.1, 1.1
    aa[:, 18, 1], aa[:, 19, 1] = -0.4 - 0.2 * np.sin(phase), 0.4 - 0.2 * np.sin(phase)
    aa[:, 1:] += rng.normal(0, 0.01, (T, 23, 3))
    betas = np.zeros(10) if betas is None else betas
    from workflows.animation.clips import joints_of, rest_joints

    J_rest = rest_joints(betas, "neutral")
    transl = np.stack([np.zeros(T), np.full(T, -J_rest[:, 1].min() + 0.0), 0.05 * np.arange(T)], 1)
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    return joints_of(R, transl, J_rest) * scale


def humanml3d_features(P: np.ndarray) -> np.ndarray:
    """(T, 263) HumanML3D features of joints P (T, 22, 3) facing +z, in the layout HumanML3D's
    ``process_file`` writes: root angular velocity 0 (none here), root xz velocity 1-2 (per frame), root height 3, ric
    (joints relative to the root's xz) 4:67; no rotation data."""
    T = len(P)
    feats = np.zeros((T, 263))
    feats[:, 3] = P[:, 0, 1]
    rel = P[:, 1:].copy()
    rel[..., 0] -= P[:, :1, 0]
    rel[..., 2] -= P[:, :1, 2]
    feats[:, 4:67] = rel.reshape(T, -1)
    feats[:-1, 1] = P[1:, 0, 0] - P[:-1, 0, 0]
    feats[:-1, 2] = P[1:, 0, 2] - P[:-1, 0, 2]
    return feats
