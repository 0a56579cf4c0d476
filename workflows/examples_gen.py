"""Generated example material for the demo and tests (no downloads, no ../shared).

* :func:`example_poses`: two procedural, CMU-like poses (a walking stride; a crouch with a reach).
* :func:`write_romp_example`: those people as a ROMP-style ``results`` ``.npz`` in the OpenCV camera
  frame, standing ~4 m in front of a camera 1.4 m above the floor (ROMP's 60-degree field of view).
* :func:`write_background`: a simple synthetic photo (sky, horizon, floor) matching that camera;
  :func:`write_photo`: the same photo with the example people rendered into it.
* :func:`write_mixamo_character`: a Mixamo-named BVH skeleton (``mixamorig:Hips``, ...; centimetres,
  extra unmapped end joints) built from the built-in body with altered proportions (longer legs,
  shorter arms, longer torso), so SMPL-SI has something non-trivial to fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_BETAS, PARENTS, Gender
from smplik.data.bvh import format_bvh
from smplik.data.retarget import load_preset
from smplik.pose import Pose

CAMERA_HEIGHT_M = 1.4
IMAGE_SIZE = (640, 480)
ROMP_FOV_DEG = 60.0

MIXAMO_NAMES: dict[str, str] = {smpl: rig.removeprefix("mixamorig:")
                                 for smpl, rig in load_preset("mixamo").joints.items()}
"""SMPL joint -> Mixamo joint name (without the ``mixamorig:`` prefix)."""

BONE_SCALE = {"leg": 1.08, "arm": 0.93, "spine": 1.06}
"""Proportion changes of the example character relative to the built-in neutral body."""


@dataclass(frozen=True)
class ExamplePerson:
    """A synthetic person in the y-up world (camera at the origin looking down -z)."""

    pose: Pose
    name: str


def _pose(angles: dict[str, tuple[float, float, float]]) -> np.ndarray:
    aa = np.zeros((24, 3))
    for name, v in angles.items():
        aa[JOINT_INDEX[name]] = v
    return aa


def example_poses() -> list[ExamplePerson]:
    """Two people: a walking stride and a crouch reaching forward (y-up world, feet on the floor)."""
    from smplik.body_model import load_body_model

    walk = _pose({
        "pelvis": (0.0, 0.35, 0.0), "left_hip": (-0.45, 0.0, 0.05), "left_knee": (0.25, 0.0, 0.0),
        "right_hip": (0.35, 0.0, -0.05), "right_knee": (0.65, 0.0, 0.0), "right_ankle": (-0.2, 0.0, 0.0),
        "spine2": (0.08, 0.0, 0.0), "left_shoulder": (0.35, 0.0, -1.2), "right_shoulder": (-0.3, 0.0, 1.2),
        "left_elbow": (0.0, -0.5, 0.0), "right_elbow": (0.0, 0.35, 0.0), "head": (0.1, -0.15, 0.0),
    })
    crouch = _pose({
        "pelvis": (0.0, -0.45, 0.0), "left_hip": (-1.25, 0.0, -0.15), "right_hip": (-1.15, 0.0, 0.15),
        "left_knee": (1.7, 0.0, 0.0), "right_knee": (1.6, 0.0, 0.0), "left_ankle": (-0.3, 0.0, 0.0),
        "right_ankle": (-0.35, 0.0, 0.0), "spine1": (0.35, 0.0, 0.0), "spine3": (0.1, 0.0, 0.0),
        "right_shoulder": (0.0, 1.1, 0.25), "right_elbow": (0.0, 0.3, 0.0), "left_shoulder": (0.0, 0.0, -1.1),
        "left_elbow": (0.0, -1.2, 0.0), "head": (0.25, 0.2, 0.0),
    })
    betas = [np.array([0.8, -0.4, 0, 0, 0, 0, 0, 0, 0, 0.0]), np.array([-0.6, 0.8, 0.2, 0, 0, 0, 0, 0, 0, 0.0])]
    places = [(-0.75, -4.0), (0.85, -4.6)]
    floor = -CAMERA_HEIGHT_M
    people = []
    model = load_body_model(Gender.NEUTRAL)
    for name, aa, b, (x, z) in zip(("walker", "croucher"), (walk, crouch), betas, places, strict=True):
        joints = model.joints(torch.as_tensor(aa[0], dtype=torch.float32), torch.as_tensor(aa[1:], dtype=torch.float32),
                              None, torch.as_tensor(b, dtype=torch.float32)).double().numpy()
        lowest = joints[[JOINT_INDEX[j] for j in ("left_ankle", "right_ankle", "left_foot", "right_foot")], 1].min()
        pelvis = joints[0]
        transl = np.array([x - pelvis[0], floor + 0.05 - lowest, z - pelvis[2]])
        people.append(ExamplePerson(Pose(aa[0], aa[1:], transl, b, Gender.NEUTRAL), name))
    return people


def write_romp_example(path: str | Path, people: list[ExamplePerson] | None = None) -> Path:
    """Write ``people`` (default :func:`example_poses`) as a ROMP ``results`` npz in the camera frame."""
    from smplik.atomic import atomic_path
    from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle
    from workflows.estimators.base import M_WORLD_CAMERA, estimator_rest_pelvis, rest_pelvis

    people = example_poses() if people is None else people
    thetas, betas, cam_trans = [], [], []
    for p in people:
        pose = p.pose
        R_cam = M_WORLD_CAMERA @ axis_angle_to_matrix(torch.as_tensor(pose.global_orient)).numpy()
        aa = np.concatenate([matrix_to_axis_angle(torch.as_tensor(R_cam)).numpy(), pose.body_pose.reshape(-1)])
        J0 = rest_pelvis(pose.betas[None], pose.gender)[0]
        J0_smpl = estimator_rest_pelvis(pose.betas[None], pose.gender)[0]
        thetas.append(aa)
        betas.append(pose.betas)
        # ROMP's cam_trans is smplx transl of SMPL: the camera-frame pelvis minus SMPL's rest pelvis
        cam_trans.append(M_WORLD_CAMERA @ (J0 + pose.transl) - J0_smpl)
    results = {"smpl_thetas": np.asarray(thetas, np.float32), "smpl_betas": np.asarray(betas, np.float32),
               "cam_trans": np.asarray(cam_trans, np.float32)}
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, results=results)
    return Path(path)


def write_background(path: str | Path, size: tuple[int, int] = IMAGE_SIZE) -> Path:
    """A synthetic photo for the ROMP example camera: sky, horizon at the image centre, a tiled floor."""
    from smplik.render import save_png

    w, h = size
    f = max(w, h) / 2 / np.tan(np.radians(ROMP_FOV_DEG) / 2)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.zeros((h, w, 3))
    sky = v < h / 2
    t = (v / (h / 2))[..., None]
    img[:] = (1 - t) * np.array([0.55, 0.72, 0.92]) + t * np.array([0.85, 0.9, 0.95])
    # floor: ray through pixel hits y = -CAMERA_HEIGHT (camera frame: y down, so y_cam = +height)
    dy = np.maximum((v - h / 2) / f, 1e-6)
    depth = np.minimum(CAMERA_HEIGHT_M / dy, 1e4)
    x = (u - w / 2) / f * depth
    checker = ((np.floor(x / 0.5) + np.floor(depth / 0.5)) % 2)[..., None]
    floor = np.array([0.62, 0.58, 0.52]) * (0.85 + 0.15 * checker)
    img = np.where(sky[..., None], img, floor)
    save_png((np.clip(img, 0, 1) * 255).astype(np.uint8), path)
    return Path(path)


def write_photo(path: str | Path, people: list[ExamplePerson] | None = None, size: tuple[int, int] = IMAGE_SIZE
                ) -> Path:
    """The synthetic photo with the example people rendered into it through the ROMP example camera.

    The people are drawn in their generating poses (what the estimator "saw"), in flat clothing
    colours, so that an overlay of the solved bodies is visibly right (or wrong). Needs an OpenGL
    backend (:mod:`smplik.render`); :func:`write_background` is the same photo without people.
    """
    from smplik.body_model import load_body_model
    from smplik.render import ImageCamera, MeshItem, render, save_png

    people = example_poses() if people is None else people
    tmp = write_background(Path(path), size)
    from workflows.scene.previews import load_image

    background = load_image(tmp)
    w, h = size
    f = max(w, h) / 2 / np.tan(np.radians(ROMP_FOV_DEG) / 2)
    colors = ((0.35, 0.25, 0.55, 1.0), (0.75, 0.45, 0.2, 1.0))
    meshes = []
    for k, person in enumerate(people):
        pose = person.pose
        model = load_body_model(pose.gender)

        def t(x: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=np.float32))[None]

        with torch.no_grad():
            verts, _ = model.vertices(t(pose.global_orient), t(pose.body_pose), t(pose.transl), t(pose.betas))
        meshes.append(MeshItem(verts[0].double().numpy(), model.faces, colors[k % len(colors)]))
    img = render(meshes, size=size, view=ImageCamera(f, f, w / 2, h / 2, np.eye(4)), background=background)
    save_png(img, path)
    return Path(path)


def mixamo_rest_joints(gender: Gender = Gender.NEUTRAL) -> np.ndarray:
    """(24, 3) rest joints (metres, y-up) of the example character in SMPL order."""
    from smplik.body_model import load_body_model

    J = load_body_model(gender).rest_joints(torch.zeros(NUM_BETAS)).double().numpy()
    groups = {"leg": ("left_knee", "right_knee", "left_ankle", "right_ankle", "left_foot", "right_foot"),
              "arm": ("left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand"),
              "spine": ("spine1", "spine2", "spine3", "neck", "head")}
    factor = {JOINT_INDEX[n]: BONE_SCALE[g] for g, names in groups.items() for n in names}
    out = np.zeros_like(J)
    for j, p in enumerate(PARENTS):
        out[j] = J[j] if p < 0 else out[p] + factor.get(j, 1.0) * (J[j] - J[p])
    out[:, 1] -= out[:, 1].min()
    return out


def write_mixamo_character(path: str | Path, prefix: str = "mixamorig:") -> Path:
    """Write the example Mixamo-named character as a one-frame BVH (centimetres, y-up, T-pose OFFSETs)."""
    from smplik.atomic import write_text_atomic

    J = mixamo_rest_joints() * 100.0
    names = [prefix + MIXAMO_NAMES[n] for n in JOINT_NAMES]
    parents = list(PARENTS)
    positions = [J[j] for j in range(len(JOINT_NAMES))]
    extras = (("HeadTop_End", "head", (0.0, 19.0, 2.0)), ("LeftToe_End", "left_foot", (0.0, 0.0, 7.0)),
              ("RightToe_End", "right_foot", (0.0, 0.0, 7.0)))
    for extra, parent, offset in extras:  # unmapped joints: they inherit their parent's rotation
        names.append(prefix + extra)
        parents.append(JOINT_INDEX[parent])
        positions.append(J[JOINT_INDEX[parent]] + np.asarray(offset))
    P = np.asarray(positions)
    offsets = np.array([P[k] if p < 0 else P[k] - P[p] for k, p in enumerate(parents)])
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation") if p < 0
                else ("Zrotation", "Xrotation", "Yrotation") for p in parents]
    values = np.zeros((1, sum(len(c) for c in channels)))
    end_sites = {len(names) - 3: (0.0, 5.0, 0.0), len(names) - 2: (0.0, 0.0, 3.0), len(names) - 1: (0.0, 0.0, 3.0)}
    text = format_bvh(names, parents, offsets, channels, values, 1 / 30, end_sites)
    return write_text_atomic(path, text)
