"""The six virtual-bone features of SMPL-SI (smpl-ik.txt section 4).

A skeleton is summarised by six distances between SMPL joints, all on the right side of the
body (plus the head), in metres:

====  =======================  ==============================
 k    pair                     meaning
====  =======================  ==============================
 0    right_hip - right_knee   thigh length
 1    right_knee - right_ankle shin length
 2    head - right_ankle       head to ankle (overall height)
 3    head - right_wrist       head to wrist (arm reach)
 4    right_shoulder - elbow   upper-arm length
 5    right_elbow - wrist      forearm length
====  =======================  ==============================

They are invariant to rotation and translation, so the skeleton's frame does not matter; the
pose does (head - ankle and head - wrist change with the pose), which is why features are taken
in the rest pose: SMPL's T-pose on the bank side, the character's rest/bind pose on the query side.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from smplik.conventions import JOINT_INDEX

FEATURE_PAIRS: tuple[tuple[str, str], ...] = (
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("head", "right_ankle"),
    ("head", "right_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
)
"""SMPL joint pairs whose distances are the features, in feature order."""

FEATURE_NAMES: tuple[str, ...] = tuple(f"{a}-{b}" for a, b in FEATURE_PAIRS)
"""Human-readable feature names, e.g. ``"right_hip-right_knee"``."""

NUM_FEATURES = len(FEATURE_PAIRS)

REQUIRED_JOINTS: tuple[str, ...] = tuple(dict.fromkeys(j for pair in FEATURE_PAIRS for j in pair))
"""SMPL joints a skeleton must provide for SMPL-SI (right hip/knee/ankle/shoulder/elbow/wrist, head)."""

_IDX_A = [JOINT_INDEX[a] for a, _ in FEATURE_PAIRS]
_IDX_B = [JOINT_INDEX[b] for _, b in FEATURE_PAIRS]


def joints_to_features(joints: Tensor) -> Tensor:
    """Features of SMPL-ordered joints. joints (..., 24, 3) -> (..., 6), same units as the joints."""
    if joints.shape[-2:] != (24, 3):
        raise ValueError(f"Invalid joints shape {tuple(joints.shape)}; expected (..., 24, 3).")
    return torch.linalg.vector_norm(joints[..., _IDX_A, :] - joints[..., _IDX_B, :], dim=-1)


def named_joints_to_features(joints: dict[str, np.ndarray]) -> np.ndarray:
    """Features of a skeleton given as ``{smpl_joint_name: position (3,)}``. Returns (6,) float64.

    Raises:
        KeyError: a required joint (see :data:`REQUIRED_JOINTS`) is missing, named in the message.
    """
    missing = [j for j in REQUIRED_JOINTS if j not in joints]
    if missing:
        raise KeyError(f"Missing SMPL joints for the features: {', '.join(missing)}.")
    return np.array([np.linalg.norm(np.asarray(joints[a], float) - np.asarray(joints[b], float))
                     for a, b in FEATURE_PAIRS])
