"""Preview image of SMPL-SI: the custom skeleton next to its SMPL approximation.

Three panels, one shared camera (front view, smplik frame): the custom skeleton (grey bones,
blue spheres on the joints mapped to SMPL); the custom skeleton overlaid with the SMPL
approximation's 24-joint skeleton (red); the SMPL mesh ``scale * V(betas)``. A legend in the
top-left corner names each colour. The SMPL body is
placed so that its hip centre and ankle height match the character's.
"""

from __future__ import annotations

import numpy as np
import torch

from shape_inversion.estimator import ShapeEstimate
from shape_inversion.skeleton_io import Character
from smplik.body_model import BodyModel
from smplik.conventions import JOINT_INDEX, NUM_BETAS, PARENTS
from smplik.render import MeshItem, Segment, Sphere, View, label_image, render

_BONE = (0.35, 0.35, 0.38, 1.0)
_MAPPED = (0.15, 0.35, 0.85, 1.0)
_SMPL = (0.85, 0.15, 0.15, 1.0)
_MESH = (0.78, 0.72, 0.66, 1.0)
LEGEND = (("your skeleton's bones", _BONE), ("its joints mapped to SMPL", _MAPPED),
          ("SMPL-SI's SMPL skeleton (beta, scale)", _SMPL), ("SMPL-SI's SMPL body", _MESH))
"""The legend drawn in the picture's top-left corner: (text, the colour it names)."""


def smpl_placement(character: Character, smpl_joints: np.ndarray) -> np.ndarray:
    """Translation (3,) that puts SMPL joints (24, 3) on the character (hip centre x/z, ankle height y)."""
    hips = [JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]]
    ankles = [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]]
    char_hips = np.mean([character.joint(n) for n in ("left_hip", "right_hip") if n in character.smpl_joints], axis=0)
    char_ankle_y = np.mean([character.joint(n)[1] for n in ("left_ankle", "right_ankle")
                            if n in character.smpl_joints])
    target = np.array([char_hips[0], char_ankle_y, char_hips[2]])
    source = np.array([smpl_joints[hips, 0].mean(), smpl_joints[ankles, 1].mean(), smpl_joints[hips, 2].mean()])
    return target - source


def render_comparison(character: Character, estimate: ShapeEstimate, model: BodyModel, *,
                      size: tuple[int, int] = (1350, 600)) -> np.ndarray:
    """RGB uint8 image (H, W, 3): custom skeleton | both skeletons | SMPL mesh, with a colour legend
    (:data:`LEGEND`) in the top-left corner."""
    betas = torch.as_tensor(np.asarray(estimate.betas, dtype=np.float32)).reshape(1, NUM_BETAS)
    zeros = torch.zeros(1, 3)
    verts, joints = model.vertices(zeros, torch.zeros(1, 23, 3), zeros, betas)
    verts = verts[0].detach().double().numpy() * estimate.scale
    joints = joints[0].detach().double().numpy() * estimate.scale
    shift = smpl_placement(character, joints)
    verts, joints = verts + shift, joints + shift
    P = character.positions
    extent = max(np.ptp(np.concatenate([P[:, 0], verts[:, 0]])), 0.5 * np.ptp(verts[:, 1]))
    step = np.array([1.15 * extent, 0.0, 0.0])
    radius = 0.012 * max(np.ptp(verts[:, 1]), 0.2)
    mapped = set(character.smpl_joints.values())
    segments, spheres = [], []
    for offset in (-step, np.zeros(3)):
        segments += [Segment(P[j] + offset, P[p] + offset, radius * 0.45, _BONE)
                     for j, p in enumerate(character.skeleton.parents) if p >= 0]
        spheres += [Sphere(P[j] + offset, radius, _MAPPED) for j in sorted(mapped)]
    segments += [Segment(joints[j], joints[p], radius * 0.35, _SMPL) for j, p in enumerate(PARENTS) if p >= 0]
    spheres += [Sphere(joints[j], radius * 0.8, _SMPL) for j in range(len(PARENTS))]
    mesh = MeshItem(verts + step, model.faces, _MESH)
    image = render([mesh], spheres, segments, size=size, view=View(direction=(0.0, 0.0, 1.0), margin=1.05))
    return label_image(image, [text for text, _ in LEGEND], colors=[color for _, color in LEGEND])
