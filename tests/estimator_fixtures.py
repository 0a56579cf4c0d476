"""Estimator output files in each producer's exact layout, and the producers' own projection formulas.

No tests here: ``test_workflows_estimators.py``, ``test_workflows_estimator_fuzz.py`` and
``benchmarks/estimator_placement.py`` use it. Every writer takes people in the producer's camera
convention (OpenCV axes; SMPL axis-angle ``aa (N, 24, 3)``; smplx ``transl (N, 3)`` relative to the
producer's SMPL rest pelvis; ``betas (N, 10)``) and writes the file the way the producer does (the
producer's code is named in each reader's docstring). :func:`producer_pixels` computes where the
producer itself draws the pelvis and head, from the published SMPL rest joints and the producer's
camera, without smplik's conversion code.
"""

from __future__ import annotations

import json
import pickle
from dataclasses import dataclass
from pathlib import Path

import joblib
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from workflows.estimators.base import SMPL_NEUTRAL_REST_JOINTS, SMPLX_NEUTRAL_REST_PELVIS
from workflows.scene import Scene, SceneCharacter

PARENTS_22 = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
PELVIS, HEAD = 0, 15
IMAGE_W, IMAGE_H = 640, 480


@dataclass(frozen=True)
class Written:
    """A written fixture: the file, the producer's camera (OpenCV pinhole) and the family of its body."""

    path: Path
    f: float
    cx: float
    cy: float
    family: str = "smpl"
    fmt: str = ""


FOCAL = {"romp": max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(30.0)), "bev": max(IMAGE_W, IMAGE_H) / 2 / np.tan(
    np.radians(30.0)), "hybrik": 1000.0 / 256.0 * 250.0, "phalp": 5000.0 / 256.0 * max(IMAGE_W, IMAGE_H),
    "wham": float(np.hypot(IMAGE_W, IMAGE_H)), "pymafx": max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(30.0)),
    "gvhmr": float(np.hypot(IMAGE_W, IMAGE_H)), "gvhmr_flat": float(np.hypot(IMAGE_W, IMAGE_H)), "plain": 800.0,
    "vibe": max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(30.0))}
"""Each fixture's focal length (pixels), to frame the people the same way in every format."""


def framing(fmt: str, height_px: float = 240.0) -> dict[str, float]:
    """``people`` keyword arguments that frame 1.7 m people ``height_px`` tall in ``fmt``'s fixture camera."""
    return {"depth": depth_for(fmt, height_px), "focal": FOCAL[fmt]}


def depth_for(fmt: str, height_px: float = 240.0) -> float:
    """The depth at which a 1.7 m person is ``height_px`` pixels tall in ``fmt``'s fixture camera."""
    return FOCAL[fmt] * 1.7 / height_px


def people(seed: int = 0, n: int = 2, depth: float = 4.0, focal: float | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n people in a producer's camera frame: aa (n, 24, 3) (upright, facing the camera), transl, betas 0.

    ``depth`` (metres) sets the framing; with the camera's ``focal`` (pixels) the people stand up to
    150 px left and right of the image centre and within 10% of that depth.
    """
    focal = FOCAL["romp"] if focal is None else focal
    rng = np.random.default_rng(seed)
    aa = rng.normal(0, 0.2, (n, 24, 3))
    upright = Rotation.from_euler("x", np.pi)  # SMPL's y-up body in OpenCV's y-down camera frame
    for i in range(n):
        aa[i, 0] = (upright * Rotation.from_rotvec(rng.normal(0, 0.25, 3))).as_rotvec()
    x = (np.linspace(-150.0, 150.0, n) if n > 1 else np.zeros(1)) * depth / focal
    y = rng.uniform(-20.0, 40.0, n) * depth / focal
    transl = np.stack([x, y, depth * (1 + rng.uniform(0, 0.1, n))], 1)
    return aa, transl, np.zeros((n, 10))


def producer_joints(aa: np.ndarray, transl: np.ndarray, family: str = "smpl") -> np.ndarray:
    """The producer's posed joints (N, 22, 3) camera frame: FK on SMPL's published rest joints + transl.

    For SMPL-X producers only the pelvis is known (``SMPLX_NEUTRAL_REST_PELVIS``); the other rows are
    SMPL's skeleton hung from that pelvis (use the pelvis row only).
    """
    J = SMPL_NEUTRAL_REST_JOINTS.copy()
    if family == "smplx":
        J = J - J[0] + SMPLX_NEUTRAL_REST_PELVIS
    out = np.zeros((aa.shape[0], 22, 3))
    for n in range(aa.shape[0]):
        R = [None] * 22
        for j in range(22):
            local = Rotation.from_rotvec(aa[n, j]).as_matrix()
            p = PARENTS_22[j]
            if p < 0:
                R[j], out[n, j] = local, J[j]
            else:
                R[j] = R[p] @ local
                out[n, j] = out[n, p] + R[p] @ (J[j] - J[p])
        out[n] += transl[n]
    return out


def project(points: np.ndarray, f: float, cx: float, cy: float) -> np.ndarray:
    """OpenCV pinhole: (..., 3) camera points -> (..., 2) pixels."""
    return np.stack([f * points[..., 0] / points[..., 2] + cx, f * points[..., 1] / points[..., 2] + cy], -1)


def producer_pixels(w: Written, aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """(N, 2, 2) pixels of the pelvis and head as the producer draws them."""
    J = producer_joints(aa, transl, w.family)
    return project(J[:, [PELVIS, HEAD]], w.f, w.cx, w.cy)


def _R(aa: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(aa.shape[:-1] + (3, 3))


def _pelvis(aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    return producer_joints(aa, transl)[:, 0]


def write_romp(folder: Path, aa, transl, betas, *, bev: bool = False, video: bool = False) -> Written:
    """simple_romp ``save_results``: ``np.savez(path, results=outputs)``, float32 arrays (N, ...)."""
    n = aa.shape[0]
    b = np.concatenate([betas, np.full((n, 1), 0.3)], 1) if bev else betas
    res = {"smpl_thetas": aa.reshape(n, 72).astype(np.float32), "smpl_betas": b.astype(np.float32),
           "cam_trans": transl.astype(np.float32), "cam": np.zeros((n, 3), np.float32),
           "center_confs": np.ones(n, np.float32)}
    if video:  # save_video_results: {frame_name: outputs}, one track id per person
        res = {"00000000.jpg": {**res, "track_ids": np.arange(n) + 5},
               "00000001.jpg": {**res, "track_ids": np.arange(n) + 5}}
    path = folder / ("video_results.npz" if video else "romp.npz")
    np.savez(path, results=res)
    f = max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(30.0))
    return Written(path, f, IMAGE_W / 2, IMAGE_H / 2, fmt="bev" if bev else "romp")


def write_hybrik(folder: Path, aa, transl, betas, *, quaternions: bool = False) -> Written:
    """HybrIK ``demo_video.py``: ``res_db`` lists ``np.stack``-ed and ``pk.dump``-ed; one person per frame."""
    T = aa.shape[0]
    R = _R(aa)
    if quaternions:
        q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]  # scalar first
        thetas = q.reshape(T, 96)
    else:
        thetas = R.reshape(T, 216)
    bbox_w = 250.0
    bbox = np.tile(np.array([100.0, 50.0, 100.0 + bbox_w, 50.0 + 1.2 * bbox_w]), (T, 1))
    res_db = {"pred_thetas": thetas.astype(np.float32), "pred_betas": betas.astype(np.float32),
              "transl": _pelvis(aa, transl).astype(np.float32),  # the camera-frame pelvis
              "transl_camsys": _pelvis(aa, transl).astype(np.float32) * 256 / bbox_w,
              "pred_phi": np.zeros((T, 23, 2), np.float32), "bbox": bbox.astype(np.float32),
              "height": np.full(T, IMAGE_H), "width": np.full(T, IMAGE_W),
              "img_path": np.array([f"raw_images/v-{i:06d}.png" for i in range(T)])}
    path = folder / "res.pk"
    with open(path, "wb") as fid:
        pickle.dump(res_db, fid)
    return Written(path, 1000.0 / 256.0 * bbox_w, IMAGE_W / 2, IMAGE_H / 2, fmt="hybrik")


def write_phalp(folder: Path, aa, transl, betas) -> Written:
    """PHALP ``joblib.dump(final_visuals_dic, path, compress=3)``: per-frame lists of detections."""
    n = aa.shape[0]
    R = _R(aa).astype(np.float32)
    frame = {"time": 0, "shot": 0, "frame_path": "img/000001.jpg", "tid": list(range(3, 3 + n)),
             "tracked_ids": list(range(3, 3 + n)), "bbox": [np.zeros(4)] * n,
             "smpl": [{"global_orient": R[i, :1], "body_pose": R[i, 1:], "betas": betas[i].astype(np.float32)}
                      for i in range(n)],
             "camera": [transl[i].astype(np.float32) for i in range(n)], "size": [[IMAGE_H, IMAGE_W]] * n,
             "conf": [1.0] * n}
    empty = {**frame, "time": 1, "tid": [], "tracked_ids": [], "bbox": [], "smpl": [], "camera": [], "size": [],
             "conf": []}
    path = folder / "demo_video.pkl"
    joblib.dump({"img/000001.jpg": frame, "img/000002.jpg": empty}, path, compress=3)
    return Written(path, 5000.0 / 256.0 * max(IMAGE_W, IMAGE_H), IMAGE_W / 2, IMAGE_H / 2, fmt="phalp")


def write_wham(folder: Path, aa, transl, betas, *, frames: int = 3) -> Written:
    """WHAM ``demo.py``: ``joblib.dump(results, 'wham_output.pkl')``, ``results[track_id] = {...}`` (T, ...)."""
    out = {}
    for i in range(aa.shape[0]):
        T = frames
        out[i] = {"pose": np.repeat(aa[i].reshape(1, 72), T, 0).astype(np.float32),
                  "trans": np.repeat(transl[i][None], T, 0).astype(np.float32),
                  "pose_world": np.repeat(aa[i].reshape(1, 72), T, 0).astype(np.float32),
                  "trans_world": np.repeat(transl[i][None], T, 0).astype(np.float32),
                  "betas": np.repeat(betas[i][None], T, 0).astype(np.float32),
                  "verts": np.zeros((T, 4, 3), np.float32), "frame_ids": np.arange(T)}
    path = folder / "wham_output.pkl"
    joblib.dump(out, path)
    return Written(path, float(np.hypot(IMAGE_W, IMAGE_H)), IMAGE_W / 2, IMAGE_H / 2, fmt="wham")


def write_pymafx(folder: Path, aa, transl, betas) -> Written:
    """PyMAF-X demo: flat ``pose (N, 72)``, ``betas``, ``orig_cam_t`` with ``frame_ids``/``person_ids``."""
    n = aa.shape[0]
    data = {"pose": aa.reshape(n, 72).astype(np.float32), "betas": betas.astype(np.float32),
            "orig_cam_t": transl.astype(np.float32), "frame_ids": np.zeros(n, np.int64),
            "person_ids": np.arange(n) + 1, "orig_cam": np.zeros((n, 4), np.float32)}
    path = folder / "output.pkl"
    joblib.dump(data, path)
    f = max(IMAGE_W, IMAGE_H) / 2 / np.tan(np.radians(30.0))  # not stored: smplik's 60-degree assumption
    return Written(path, f, IMAGE_W / 2, IMAGE_H / 2, fmt="pymafx")


def write_gvhmr(folder: Path, aa, transl, betas, *, frames: int = 2) -> Written:
    """GVHMR ``tools/demo/demo.py``: ``torch.save(pred, 'hmr4d_results.pt')`` of tensors (one person, L frames);
    ``K_fullimg = estimate_K(width, height)`` (``hmr4d/utils/geo/hmr_cam.py``: diagonal focal, centred)."""
    f, cx, cy = FOCAL["gvhmr"], IMAGE_W / 2, IMAGE_H / 2
    K = torch.tensor([[f, 0, cx], [0, f, cy], [0, 0, 1.0]]).expand(frames, 3, 3).clone()

    def params(a: np.ndarray, t: np.ndarray) -> dict:
        return {"body_pose": torch.tensor(a[1:22].reshape(1, 63), dtype=torch.float32).expand(frames, 63).clone(),
                "global_orient": torch.tensor(a[0][None], dtype=torch.float32).expand(frames, 3).clone(),
                "transl": torch.tensor(t[None], dtype=torch.float32).expand(frames, 3).clone(),
                "betas": torch.tensor(betas[0][None], dtype=torch.float32).expand(frames, 10).clone()}

    pred = {"smpl_params_global": params(aa[0], transl[0]), "smpl_params_incam": params(aa[0], transl[0]),
            "K_fullimg": K, "net_outputs": {"pred_cam": torch.zeros(frames, 3)}}
    path = folder / "hmr4d_results.pt"
    torch.save(pred, path)
    return Written(path, f, cx, cy, family="smplx", fmt="gvhmr")


def write_gvhmr_flat_npz(folder: Path, aa, transl, betas, *, frames: int = 2) -> Written:
    """A user's AMASS-style conversion of GVHMR's ``hmr4d_results.pt``: github.com/wenconggan/video2smpl
    ``pt2npz/Converter.py`` ``convert_pt_to_npz``: ``poses (L, 72)`` / ``trans`` from ``smpl_params_global``
    (turned by its ``R_fix``), ``betas (10,)``, ``gender``, ``mocap_framerate``, ``K_fullimg`` and every other
    entry flattened with ``_`` (``smpl_params_incam_body_pose`` ...), ``np.savez_compressed``."""
    w = write_gvhmr(folder, aa, transl, betas, frames=frames)
    pred = torch.load(w.path, weights_only=True)
    w.path.unlink()

    def flat(obj, prefix: str) -> dict:  # the converter's extract_tensors
        if isinstance(obj, dict):
            return {k: v for key, val in obj.items() for k, v in flat(val, f"{prefix}{key}_").items()}
        return {prefix[:-1]: obj.numpy()}

    g = pred["smpl_params_global"]
    poses = np.concatenate([g["global_orient"].numpy(), g["body_pose"].numpy(), np.zeros((frames, 6))], 1)
    extra = {k: v for key in pred if key != "smpl_params_global" for k, v in flat(pred[key], f"{key}_").items()}
    path = folder / "hmr4d_results.npz"
    np.savez_compressed(path, poses=poses.astype(np.float32), trans=g["transl"].numpy(),
                        betas=g["betas"].numpy()[0], gender="neutral", mocap_framerate=np.array(30),
                        **{"K_fullimg": pred["K_fullimg"].numpy(), **extra})
    return Written(path, w.f, w.cx, w.cy, family="smplx", fmt="gvhmr")


def write_plain(folder: Path, aa, transl, betas) -> Written:
    """A plain ``.npz`` of smplx keys in the camera frame with intrinsics ``K``."""
    f, cx, cy = FOCAL["plain"], IMAGE_W / 2 - 10.0, IMAGE_H / 2 + 4.0
    path = folder / "smpl.npz"
    np.savez(path, global_orient=aa[:, 0], body_pose=aa[:, 1:], transl=transl, betas=betas, frame="camera",
             K=np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]]), image_size=np.array([IMAGE_W, IMAGE_H]))
    return Written(path, f, cx, cy, fmt="plain")


CAMERA_WRITERS = {"romp": write_romp, "bev": lambda *a: write_romp(*a, bev=True), "hybrik": write_hybrik,
                  "phalp": write_phalp, "wham": write_wham, "pymafx": write_pymafx, "gvhmr": write_gvhmr,
                  "gvhmr_flat": write_gvhmr_flat_npz, "plain": write_plain}
"""Every camera-frame format's writer (HybrIK and GVHMR hold one person: pass n=1 people)."""
SINGLE_PERSON = {"hybrik", "gvhmr", "gvhmr_flat"}


# SAM-3D-Body: MHR-rig slots of the SMPL joints (the reader's table is not used to write them)
_MHR_SLOT = {"pelvis": 1, "left_hip": 2, "left_knee": 3, "left_ankle": 4, "left_foot": 8, "right_hip": 18,
             "right_knee": 19, "right_ankle": 20, "right_foot": 24, "spine1": 35, "spine2": 36, "spine3": 37,
             "right_collar": 38, "right_shoulder": 39, "right_elbow": 40, "right_wrist": 42, "right_hand": 52,
             "left_collar": 74, "left_shoulder": 75, "left_elbow": 76, "left_wrist": 78, "left_hand": 88,
             "neck": 110, "head": 113}
_MHR70_SLOT = {"head": 0, "left_shoulder": 5, "right_shoulder": 6, "left_elbow": 7, "right_elbow": 8, "left_hip": 9,
               "right_hip": 10, "left_knee": 11, "right_knee": 12, "left_ankle": 13, "right_ankle": 14,
               "right_wrist": 41, "left_wrist": 62, "neck": 69}
SAM3D_F = 700.0


def sam3d_joints_cam(aa, transl) -> np.ndarray:
    """Our body's posed joints (N, 24, 3) in the OpenCV camera frame for people in the producers' convention
    (root rotation in camera axes, pelvis at SMPL's rest pelvis + ``transl``): the known answer."""
    from smplik.body_model import load_body_model
    from smplik.conventions import Gender
    from workflows.estimators.base import rest_pelvis

    M = np.diag([1.0, -1.0, -1.0])
    n = aa.shape[0]
    go = np.stack([Rotation.from_matrix(M @ _R(aa[i, 0])).as_rotvec() for i in range(n)])
    pelvis_world = (SMPL_NEUTRAL_REST_JOINTS[0] + transl) @ M.T
    ours = pelvis_world - rest_pelvis(np.zeros((n, 10)), Gender.NEUTRAL)
    m = load_body_model(Gender.NEUTRAL)
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float32)  # noqa: E731
    J = m.joints(t(go), t(aa[:, 1:]), t(ours), t(np.zeros((n, 10)))).double().numpy()
    return J @ M.T


def sam3d_person(J_cam: np.ndarray, f: float = SAM3D_F, cx: float = IMAGE_W / 2, cy: float = IMAGE_H / 2,
                 rots_world: np.ndarray | None = None) -> dict:
    """One person's dict as ``SAM3DBodyEstimator.process_one_image`` returns it (float32 numpy arrays).

    MHR's y-up rig flipped to camera axes, relative to ``pred_cam_t``; ``body_world`` at the origin and
    the root 0.924 m above it (as in the MHR sample outputs); unmapped rig joints at the root.
    """
    from smplik.conventions import JOINT_NAMES

    root_rel = np.array([0.0, -0.924, 0.0])
    cam_t = J_cam[0] - root_rel
    coords = np.tile(root_rel, (127, 1))
    coords[0] = 0.0
    rots = np.tile(np.eye(3), (127, 1, 1))
    for name, slot in _MHR_SLOT.items():
        coords[slot] = J_cam[JOINT_NAMES.index(name)] - cam_t
        if rots_world is not None:
            rots[slot] = rots_world[JOINT_NAMES.index(name)]
    kp = np.tile(J_cam[0], (70, 1)) + np.linspace(-0.05, 0.05, 70)[:, None]
    for name, slot in _MHR70_SLOT.items():
        kp[slot] = J_cam[JOINT_NAMES.index(name)]
    f32 = np.float32
    return {"bbox": np.array([cx - 100, cy - 150, cx + 100, cy + 150], f32), "focal_length": f32(f),
            "pred_keypoints_3d": (kp - cam_t).astype(f32), "pred_keypoints_2d": project(kp, f, cx, cy).astype(f32),
            "pred_vertices": np.zeros((18439, 3), f32), "pred_cam_t": cam_t.astype(f32),
            "pred_pose_raw": np.zeros(266, f32), "global_rot": np.zeros(3, f32),
            "body_pose_params": np.zeros(133, f32), "hand_pose_params": np.zeros(108, f32),
            "scale_params": np.zeros(28, f32), "shape_params": np.zeros(45, f32), "expr_params": np.zeros(72, f32),
            "mask": None, "pred_joint_coords": coords.astype(f32), "pred_global_rots": rots.astype(f32),
            "mhr_model_params": np.zeros(204, f32), "lhand_bbox": np.zeros(4), "rhand_bbox": np.zeros(4)}


def write_sam3d(folder: Path, aa, transl, *, layout: str = "pkl") -> tuple[Written, np.ndarray]:
    """SAM-3D-Body outputs of people in the producers' convention, and their joints (N, 24, 3) camera frame.

    ``layout="pkl"``: ``process_one_image``'s list of person dicts, pickled (``pickle.dump(outputs, f)``);
    ``"npz"``: one person per ``.npz`` without ``focal_length``/``mask`` (the MHR repository's
    ``sam3d_body_outputs/img_subj00.npz``; the intrinsics come from the keypoints); ``"npz_list"``: the list
    as an object array, ``np.savez(path, outputs=outputs)``; ``"pt"``: the list through ``torch.save`` (tensors).
    """
    J = sam3d_joints_cam(aa, transl)
    outputs = [sam3d_person(J[i]) for i in range(J.shape[0])]
    if layout == "npz":
        path = folder / "img_subj00.npz"
        np.savez(path, **{k: v for k, v in outputs[0].items() if k not in ("focal_length", "mask")})
    elif layout == "npz_list":
        path = folder / "sam3d_outputs.npz"
        np.savez(path, outputs=np.array(outputs, dtype=object))
    elif layout == "pt":
        path = folder / "sam3d_outputs.pt"
        torch.save([{k: torch.as_tensor(v) for k, v in p.items() if v is not None} for p in outputs], path)
    else:
        path = folder / "sam3d_outputs.pkl"
        path.write_bytes(pickle.dumps(outputs))
    return Written(path, SAM3D_F, IMAGE_W / 2, IMAGE_H / 2, fmt="sam3d"), J


def write_aist(folder: Path, aa, transl) -> Path:
    """AIST++ ``motions/<seq>.pkl``: plain pickle of ``smpl_poses (T, 72)``, ``smpl_trans``, ``smpl_scaling``."""
    scaling = 93.0
    data = {"smpl_loss": 0.01, "smpl_poses": aa.reshape(-1, 72), "smpl_scaling": np.array([scaling]),
            "smpl_trans": transl * scaling}
    path = folder / "gBR_sBM_cAll_d04_mBR0_ch01.pkl"
    with open(path, "wb") as fh:
        pickle.dump(data, fh)
    return path


def write_amass(folder: Path, aa, transl, *, smplx: bool = False) -> Path:
    """AMASS release ``.npz`` (SMPL-H: poses (T, 156), SMPL-X: (T, 165)), z-up world."""
    T = aa.shape[0]
    width = 165 if smplx else 156
    poses = np.zeros((T, width))
    poses[:, :66] = aa[:, :22].reshape(T, 66)
    path = folder / ("smplx_neutral_stageii.npz" if smplx else "poses.npz")
    extra = {"surface_model_type": "smplx", "mocap_frame_rate": 120.0} if smplx else {"mocap_framerate": 120.0}
    np.savez(path, poses=poses, trans=transl, betas=np.zeros(16), gender="neutral", **extra)
    return path


# ----------------------------------------------------------------------------- smplik's side


def our_joints(person) -> np.ndarray:
    """Our body's posed joints (24, 3) in the world for an EstimatedPerson."""
    from smplik.body_model import load_body_model

    m = load_body_model(person.gender)
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float32)  # noqa: E731
    return m.joints(t(person.global_orient), t(person.body_pose), t(person.transl), t(person.betas)).double().numpy()


def overlay_pixels(people_list, width: int = IMAGE_W, height: int = IMAGE_H, ground=None) -> np.ndarray:
    """(N, 2, 2) pixels of pelvis and head through the scene's overlay camera (OpenGL, as pyrender draws)."""
    from workflows.scene.previews import image_camera

    chars = tuple(SceneCharacter(f"p{i}", p.gender, p.betas, pose=p.to_pose()) for i, p in enumerate(people_list))
    scene = Scene(chars, camera=people_list[0].camera, ground=ground)
    cam = image_camera(scene, width, height)
    out = []
    for p in people_list:
        J = our_joints(p)[[0, 15]]
        x = (np.linalg.inv(cam.T_world_camera) @ np.c_[J, np.ones(2)].T).T[:, :3]
        out.append(np.stack([cam.cx + cam.fx * x[:, 0] / -x[:, 2], cam.cy - cam.fy * x[:, 1] / -x[:, 2]], -1))
    return np.stack(out)


def write_vibe(folder: Path, aa, transl, betas, *, pare: bool = False, frames: int = 3) -> Written:
    """VIBE ``demo.py`` (``joblib.dump(vibe_results, 'vibe_output.pkl')``) or PARE ``run_on_video`` (``pose``
    as rotation matrices, plus ``smpl_joints2d``): ``{person_id: output_dict}`` over ``frames`` frames, the
    people at frame 1 only for person 2 (a track that starts later). ``orig_cam = [sx, sy, tx, ty]`` is the
    weak-perspective camera that draws a body at depth ``tz`` the size a 60-degree pinhole draws it
    (``convert_crop_cam_to_orig_img`` of a crop camera, ``lib/utils/demo_utils.py``)."""
    f = FOCAL["vibe"]
    out = {}
    for i in range(aa.shape[0]):
        tz = transl[i, 2]
        cam = np.array([2 * f / (IMAGE_W * tz), 2 * f / (IMAGE_H * tz), transl[i, 0], transl[i, 1]])
        ids = np.arange(frames) if i == 0 else np.arange(1, frames)
        n = ids.shape[0]
        pose = np.broadcast_to(aa[i].reshape(1, 72), (n, 72)).astype(np.float32)
        d = {"pred_cam": np.zeros((n, 3), np.float32), "orig_cam": np.broadcast_to(cam, (n, 4)).astype(np.float32),
             "verts": np.zeros((n, 6890, 3), np.float32),
             "pose": _R(pose.reshape(n, 24, 3)).astype(np.float32) if pare else pose,
             "betas": np.broadcast_to(betas[i], (n, 10)).astype(np.float32), "joints3d": np.zeros((n, 49, 3)),
             "joints2d": None, "bboxes": np.tile([320.0, 240.0, 200.0, 200.0], (n, 1)), "frame_ids": ids}
        if pare:
            d["smpl_joints2d"] = np.zeros((n, 49, 2), np.float32)
        out[i + 1] = d
    path = folder / ("pare_output.pkl" if pare else "vibe_output.pkl")
    joblib.dump(out, path)
    return Written(path, f, IMAGE_W / 2, IMAGE_H / 2, fmt="vibe")


def weak_perspective_pixels(w: Written, aa: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """(N, 2, 2) pelvis and head as VIBE's renderer draws them (``WeakPerspectiveCamera``): SMPL's output
    joints (no transl) at ``u = W/2 (1 + sx (x + tx))``, ``v = H/2 (1 + sy (y + ty))``."""
    J = producer_joints(aa, np.zeros_like(transl))[:, [PELVIS, HEAD]]
    sx, sy = (2 * w.f / (IMAGE_W * transl[:, 2]))[:, None], (2 * w.f / (IMAGE_H * transl[:, 2]))[:, None]
    u = IMAGE_W / 2 * (1 + sx * (J[..., 0] + transl[:, :1]))
    v = IMAGE_H / 2 * (1 + sy * (J[..., 1] + transl[:, 1:2]))
    return np.stack([u, v], -1)


def write_easymocap(folder: Path, people_zup: list[dict]) -> Path:
    """EasyMocap ``write_smpl`` (``easymocap/mytools/file_utils.py``): ``output/smpl/000000.json``, a list of
    ``{"id", "Rh": [[3]], "Th": [[3]], "poses": [[72]], "shapes": [[10]]}`` (one frame, z-up world)."""
    import json

    path = folder / "000000.json"
    path.write_text(json.dumps([{"id": p["id"], "Rh": [list(map(float, p["Rh"]))], "Th": [list(map(float, p["Th"]))],
                                 "poses": [list(map(float, p["poses"]))], "shapes": [list(map(float, p["shapes"]))]}
                                for p in people_zup], indent=4))
    return path


def write_glamr(folder: Path, aa, transl, betas, *, frames: int = 3) -> tuple[Written, np.ndarray]:
    """GLAMR ``global_recon/run_demo.py``: the optimiser's ``data`` dict pickled, ``person_data[id]`` with
    ``smpl_pose (T, 69)``, ``smpl_beta``, ``smpl_orient_cam``, ``root_trans_cam`` (the pelvis, HybrIK's
    ``root_trans``), ``cam_K``, and the world (z-up) ``smpl_orient_world`` / ``root_trans_world`` from
    ``cam_pose_inv``. Returns the fixture and ``cam_pose_inv`` (4, 4) (world <- camera)."""
    f, cx, cy = FOCAL["hybrik"], IMAGE_W / 2 + 3.0, IMAGE_H / 2 - 2.0
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    T_wc = np.eye(4)
    T_wc[:3, :3] = Rotation.from_euler("xz", [-100.0, 30.0], degrees=True).as_matrix()  # camera looks along +y-ish
    T_wc[:3, 3] = [0.5, -2.0, 1.6]
    pelvis = producer_joints(aa, transl)[:, 0]
    person_data = {}
    for i in range(aa.shape[0]):
        R_w = Rotation.from_matrix(T_wc[:3, :3]) * Rotation.from_rotvec(aa[i, 0])
        person_data[i] = {
            "smpl_pose": np.tile(aa[i, 1:].reshape(1, 69), (frames, 1)),
            "smpl_beta": np.tile(betas[i], (frames, 1)), "smpl_orient_cam": np.tile(aa[i, 0], (frames, 1)),
            "root_trans_cam": np.tile(pelvis[i], (frames, 1)), "cam_K": np.tile(K, (frames, 1, 1)),
            "smpl_orient_world": np.tile(R_w.as_rotvec(), (frames, 1)),
            "root_trans_world": np.tile(T_wc[:3, :3] @ pelvis[i] + T_wc[:3, 3], (frames, 1)),
            "frames": np.arange(frames), "visible": np.ones(frames)}
    data = {"seq_name": "demo", "person_data": person_data, "seq_len": frames,
            "cam_pose_inv": np.tile(T_wc, (frames, 1, 1)), "cam_pose": np.tile(np.linalg.inv(T_wc), (frames, 1, 1)),
            "meta": {"algo": "global_recon", "num_fr": frames}}
    path = folder / "demo_result.pkl"
    with open(path, "wb") as fh:
        pickle.dump(data, fh)
    return Written(path, f, cx, cy, fmt="glamr"), T_wc


def write_tram(folder: Path, aa, transl, betas, *, focal: float = 900.0, starts: tuple[int, ...] = (0, 1),
               frames: int = 3, cam_R: np.ndarray | None = None, cam_T: np.ndarray | None = None
               ) -> tuple[Written, list[Path]]:
    """TRAM: ``scripts/estimate_humans.py`` ``np.save(f'{hps_folder}/hps_track_{k}.npy', results)`` with the dict of
    torch tensors of ``lib/models/hmr_vimo.py`` ``HMR_VIMO.inference`` (``pred_rotmat (T, 24, 3, 3)``, ``pred_trans
    (T, 1, 3)``, ...), and ``scripts/estimate_camera.py`` ``np.save(f'{seq_folder}/camera.npy', camera)``.
    Person k's track starts at video frame ``starts[k]``; every row repeats the person's pose. ``cam_R (F, 3, 3)``,
    ``cam_T (F, 3)``: the SLAM camera-to-world trajectory (default: identity)."""
    seq = folder / "results" / "example_video"
    (seq / "hps").mkdir(parents=True, exist_ok=True)
    R = torch.as_tensor(_R(aa), dtype=torch.float32)
    paths = []
    for k in range(aa.shape[0]):
        frame = torch.arange(starts[k], starts[k] + frames)
        results = {"pred_cam": torch.rand(frames, 3), "pred_pose": torch.zeros(frames, 144),
                   "pred_shape": torch.as_tensor(betas[k], dtype=torch.float32).expand(frames, 10).clone(),
                   "pred_rotmat": R[k].expand(frames, 24, 3, 3).clone(),
                   "pred_trans": torch.as_tensor(transl[k], dtype=torch.float32).expand(frames, 1, 3).clone(),
                   "frame": frame}
        paths.append(seq / "hps" / f"hps_track_{k}.npy")
        np.save(paths[-1], results)
    cam_int = np.array([focal, focal, IMAGE_W / 2, IMAGE_H / 2])
    n_frames = max(starts) + frames
    cam_R = np.tile(np.eye(3), (n_frames, 1, 1)) if cam_R is None else cam_R
    cam_T = np.zeros((n_frames, 3)) if cam_T is None else cam_T
    np.save(seq / "camera.npy", {"pred_cam_R": cam_R, "pred_cam_T": cam_T, "img_focal": cam_int[0],
                                 "img_center": cam_int[2:]})
    return Written(paths[0], focal, IMAGE_W / 2, IMAGE_H / 2, fmt="tram"), paths


SMPLERX_FOCAL, SMPLERX_INPUT = (5000.0, 5000.0), (256, 192)
"""SMPLer-X's ``cfg.focal`` and ``cfg.input_body_shape`` (``main/config.py``), which scale to each person's box."""


def write_smplerx(folder: Path, aa, transl, betas, boxes: list[tuple[float, float, float, float]], *,
                  frame: int = 1, meta: bool = True) -> tuple[list[Path], list[Written]]:
    """SMPLer-X ``main/inference.py``: per person ``np.savez(smplx/{frame:05}_{bbox_id}.npz, **smplx_pred)`` and
    ``meta/{frame:05}_{bbox_id}.json`` (``focal``, ``princpt`` scaled from ``cfg.focal`` to the box ``bbox``
    (x, y, w, h)). ``transl`` is the SMPL-X ``cam_trans`` in that person's own camera."""
    (folder / "smplx").mkdir(parents=True, exist_ok=True)
    (folder / "meta").mkdir(parents=True, exist_ok=True)
    paths, cams = [], []
    for i, (x, y, w, h) in enumerate(boxes):
        pred = {"global_orient": aa[i, :1].reshape(-1, 3), "body_pose": aa[i, 1:22].reshape(-1, 3),
                "left_hand_pose": np.zeros((15, 3)), "right_hand_pose": np.zeros((15, 3)), "jaw_pose": np.zeros((1, 3)),
                "leye_pose": np.zeros((1, 3)), "reye_pose": np.zeros((1, 3)), "betas": betas[i].reshape(-1, 10),
                "expression": np.zeros((1, 10)), "transl": transl[i].reshape(-1, 3)}
        paths.append(folder / "smplx" / f"{frame:05}_{i}.npz")
        np.savez(paths[-1], **{k: v.astype(np.float32) for k, v in pred.items()})
        focal = [SMPLERX_FOCAL[0] / SMPLERX_INPUT[1] * w, SMPLERX_FOCAL[1] / SMPLERX_INPUT[0] * h]
        princpt = [SMPLERX_INPUT[1] / 2 / SMPLERX_INPUT[1] * w + x, SMPLERX_INPUT[0] / 2 / SMPLERX_INPUT[0] * h + y]
        if meta:
            (folder / "meta" / f"{frame:05}_{i}.json").write_text(json.dumps(
                {"focal": focal, "princpt": princpt, "bbox": [x, y, w, h], "bbox_mmdet": [x, y, w, h], "bbox_id": i,
                 "img_path": f"frames/{frame:06d}.jpg"}, indent=4))
        cams.append(Written(paths[-1], float(np.mean(focal)), princpt[0], princpt[1], family="smplx", fmt="smplerx"))
    return paths, cams


def write_agora(folder, aa, transl, betas, *, smplx: bool, pose2rot: bool = True):
    """agora_evaluation docs/prediction_format.md: one pickle per person, ``<image>_personId_<k>.pkl``."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(len(aa)):
        body = aa[k, 1:22] if smplx else aa[k, 1:]
        if pose2rot:
            params = {"global_orient": aa[k, :1].reshape(1, 3) if smplx else aa[k, :1].reshape(1, 1, 3),
                      "body_pose": body.reshape(1, -1) if smplx else body.reshape(1, -1, 3)}
        else:
            params = {"global_orient": Rotation.from_rotvec(aa[k, :1]).as_matrix().reshape(1, 1, 3, 3),
                      "body_pose": Rotation.from_rotvec(body).as_matrix().reshape(1, -1, 3, 3)}
        params.update({"transl": transl[k].reshape(1, 3), "betas": betas[k].reshape(1, 10)})
        if smplx:
            params.update({"left_hand_pose": np.zeros((1, 45)), "right_hand_pose": np.zeros((1, 45)),
                           "jaw_pose": np.zeros((1, 3)), "leye_pose": np.zeros((1, 3)), "reye_pose": np.zeros((1, 3)),
                           "expression": np.zeros((1, 10))})
        pred = {"params": {k2: v.astype(np.float32) for k2, v in params.items()}, "pose2rot": pose2rot,
                "joints": np.zeros((24, 2), np.float32), "gender": "neutral", "num_betas": 10}
        paths.append(folder / f"ag_trainset_renderpeople_bfh_archviz_5_10_cam00_00000_personId_{k}.pkl")
        with open(paths[-1], "wb") as fh:
            pickle.dump(pred, fh)
    return paths


def write_smplifyx(path, aa, t, *, body: str = "smplx"):
    """smplify-x fit_single_frame: pickle.dump({'camera_' + k: ...camera params, **body_model params}, protocol=2)."""
    bp = aa[1:22].reshape(1, 63) if body == "smplx" else aa[1:].reshape(1, 69)
    result = {"camera_rotation": np.eye(3)[None].astype(np.float32), "camera_translation": t.reshape(1, 3),
              "betas": np.zeros((1, 10), np.float32), "global_orient": aa[:1].reshape(1, 3), "body_pose": bp,
              "left_hand_pose": np.zeros((1, 12)), "right_hand_pose": np.zeros((1, 12)), "jaw_pose": np.zeros((1, 3)),
              "leye_pose": np.zeros((1, 3)), "reye_pose": np.zeros((1, 3)), "expression": np.zeros((1, 10))}
    with open(path, "wb") as fh:
        pickle.dump({k: np.asarray(v, np.float32) for k, v in result.items()}, fh, protocol=2)


def write_humandata(path: Path, aa, transl, betas, *, rows: list[int], images: list[str] | None = None) -> Path:
    """mmhuman3d ``HumanData.dump``: ``np.savez_compressed(path, **dict_to_dump)``, the ``smpl`` dict saved as an
    object array, one row per person instance (``rows`` index the people), ``image_path`` per row."""
    smpl = {"global_orient": aa[rows, 0], "body_pose": aa[rows, 1:], "betas": betas[rows], "transl": transl[rows]}
    extra = {} if images is None else {"image_path": np.array(images)}
    np.savez_compressed(path, smpl=smpl, bbox_xywh=np.zeros((len(rows), 5)), __data_len__=len(rows),
                        __key_strict__=False, **extra)
    return path
