"""The VMC protocol's frames and bones (pure math; the OSC transport is :mod:`workflows.tracking.live`).

VMC protocol (https://protocol.vmc.info, the Performer and Marionette specifications of
sh-akira/VirtualMotionCaptureProtocol): OSC over UDP, Unity's coordinates.

Conventions, fixed here once:

* **Unity** (what every VMC message carries): left-handed, y up, +z forward (a humanoid avatar faces +z), +x to
  the avatar's right, metres; quaternions ``(x, y, z, w)`` (the argument order of the messages, and scipy's).
* **SMPL / smplik** (what :mod:`smplik.tracking` works in): right-handed, y up, +z forward, +x to the body's left,
  metres, floor at y = 0; rotation matrices act on column vectors.
* The two frames differ by the mirror ``S = diag(-1, 1, 1)`` (x negated): a point ``p_unity = S p_smpl`` and a
  rotation ``R_unity = S R_smpl S`` (the same physical turn written in the other handedness); ``S`` is its own
  inverse, so the same two functions convert both ways.
* **Bones**: :data:`VMC_BONES`, Unity's ``HumanBodyBones`` names driven by SMPL's first 22 joints (SMPL's hands,
  joints 22 and 23, have no Unity humanoid counterpart: the ``Hand`` bone is SMPL's wrist). Parents agree:
  Unity's humanoid tree is SMPL's tree on these joints. A bone message carries its *local* pose, as Unity's
  ``Transform.localPosition`` / ``localRotation`` under its parent bone (``Hips`` under the model's root); the
  rest pose is SMPL's T-pose with identity local rotations, as a normalised VRM 0.x avatar's.
* **Root**: the model root, at the world origin with the identity rotation; ``Hips`` then carries the body's
  world position and rotation (its local pose under that root).
"""

from __future__ import annotations

import numpy as np

from smplik.conventions import JOINT_INDEX, PARENTS
from smplik.tracking.io import HMD_TO_HEAD_M

VMC_BONES: tuple[tuple[str, str], ...] = (
    ("Hips", "pelvis"), ("LeftUpperLeg", "left_hip"), ("RightUpperLeg", "right_hip"), ("Spine", "spine1"),
    ("LeftLowerLeg", "left_knee"), ("RightLowerLeg", "right_knee"), ("Chest", "spine2"),
    ("LeftFoot", "left_ankle"), ("RightFoot", "right_ankle"), ("UpperChest", "spine3"),
    ("LeftToes", "left_foot"), ("RightToes", "right_foot"), ("Neck", "neck"),
    ("LeftShoulder", "left_collar"), ("RightShoulder", "right_collar"), ("Head", "head"),
    ("LeftUpperArm", "left_shoulder"), ("RightUpperArm", "right_shoulder"), ("LeftLowerArm", "left_elbow"),
    ("RightLowerArm", "right_elbow"), ("LeftHand", "left_wrist"), ("RightHand", "right_wrist"),
)
"""(Unity ``HumanBodyBones`` name, SMPL joint name) of every bone sent, in SMPL joint order (parents first)."""

BONE_JOINTS = np.array([JOINT_INDEX[j] for _, j in VMC_BONES])
"""SMPL joint index (22,) of each of :data:`VMC_BONES`."""

MIRROR = np.diag([-1.0, 1.0, 1.0])
"""``S``: Unity <-> SMPL (x negated; module docstring)."""

HMD_TO_HEAD_SMPL_M = np.diag([-1.0, 1.0, -1.0]) @ HMD_TO_HEAD_M
"""The SMPL head joint relative to a headset, in the head's SMPL frame (+z forward): 7 cm down, 9 cm behind the
eyes (:data:`smplik.tracking.io.HMD_TO_HEAD_M`, there in OpenVR's -z-forward frame)."""

ROOT_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
"""``/VMC/Ext/Root/Pos`` values after the name: the world origin, the identity rotation."""


def mirror_points(p: np.ndarray) -> np.ndarray:
    """Unity <-> SMPL positions: (..., 3) -> (..., 3), x negated."""
    p = np.array(p, dtype=np.float64)
    p[..., 0] *= -1.0
    return p


def mirror_rotations(R: np.ndarray) -> np.ndarray:
    """Unity <-> SMPL rotation matrices: (..., 3, 3) -> (..., 3, 3), ``S R S``."""
    return MIRROR @ np.asarray(R, dtype=np.float64) @ MIRROR


def unity_quat_to_smpl_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Unity quaternions (..., 4) ``(x, y, z, w)`` (normalised here) -> SMPL rotation matrices (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q_xyzw, dtype=np.float64)
    return mirror_rotations(Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3))


def smpl_matrix_to_unity_quat(R: np.ndarray) -> np.ndarray:
    """SMPL rotation matrices (..., 3, 3) -> Unity quaternions (..., 4) ``(x, y, z, w)``."""
    from scipy.spatial.transform import Rotation

    R = mirror_rotations(R)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(*R.shape[:-2], 4)


def rest_offsets(J_rest: np.ndarray) -> np.ndarray:
    """Rest joints J_rest (24, 3) -> each joint's offset from its parent (24, 3) in the parent's frame (SMPL's
    rest frames are the world's), the root's its own rest position."""
    J = np.asarray(J_rest, dtype=np.float64)
    parents = np.array(PARENTS)
    off = J - J[np.maximum(parents, 0)]
    off[0] = J[0]
    return off


def pose_to_vmc_bones(R_local: np.ndarray, transl: np.ndarray, J_rest: np.ndarray) -> np.ndarray:
    """An SMPL pose -> the ``/VMC/Ext/Bone/Pos`` values of :data:`VMC_BONES`.

    R_local (..., 24, 3, 3) local rotations (the root's in the world), transl (..., 3) smplx translation,
    J_rest (24, 3) -> (..., 22, 7): Unity ``localPosition`` (3) and ``localRotation`` (4, x y z w) per bone:
    ``Hips`` at the pelvis' world position ``J_rest[0] + transl`` with its world rotation (under the root of
    :data:`ROOT_POSE`); every other bone at its rest offset from its parent with its local rotation.
    """
    R = np.asarray(R_local, dtype=np.float64)[..., BONE_JOINTS, :, :]
    lead = R.shape[:-3]
    pos = np.broadcast_to(rest_offsets(J_rest)[BONE_JOINTS], (*lead, len(VMC_BONES), 3)).copy()
    pos[..., 0, :] = pos[..., 0, :] + np.asarray(transl, dtype=np.float64)
    return np.concatenate([mirror_points(pos), smpl_matrix_to_unity_quat(R)], -1)


def vmc_bones_to_pose(bones: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`pose_to_vmc_bones` (what a receiver reads back): bones (..., 22, 7) ->
    ``(R_local (..., 22, 3, 3) SMPL local rotations of :data:`BONE_JOINTS`, p_hips (..., 3) the pelvis' SMPL
    world position)``."""
    b = np.asarray(bones, dtype=np.float64)
    return unity_quat_to_smpl_matrix(b[..., 3:]), mirror_points(b[..., 0, :3])


def unity_fk(bones: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World poses in Unity's frame of bones (..., 22, 7) under :data:`ROOT_POSE`, as a Unity receiver composes
    them (``position = parent.position + parent.rotation * localPosition``, ``rotation = parent.rotation *
    localRotation``) -> ``(positions (..., 22, 3), rotation matrices (..., 22, 3, 3))``, both in Unity's
    coordinates."""
    from scipy.spatial.transform import Rotation

    b = np.asarray(bones, dtype=np.float64)
    R = Rotation.from_quat(b[..., 3:].reshape(-1, 4)).as_matrix().reshape(*b.shape[:-1], 3, 3)
    index = {j: k for k, j in enumerate(BONE_JOINTS)}
    G, p = np.empty_like(R), np.empty(b.shape[:-1] + (3,))
    for k, j in enumerate(BONE_JOINTS):
        if PARENTS[j] < 0:
            G[..., k, :, :], p[..., k, :] = R[..., k, :, :], b[..., k, :3]
            continue
        a = index[PARENTS[j]]
        G[..., k, :, :] = G[..., a, :, :] @ R[..., k, :, :]
        p[..., k, :] = p[..., a, :] + (G[..., a, :, :] @ b[..., k, :3, None])[..., 0]
    return p, G


def device_to_smpl(p_unity: np.ndarray, q_unity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A VMC device pose (``/VMC/Ext/{Hmd,Con,Tra}/Pos``: position (..., 3), quaternion (..., 4) x y z w, Unity)
    -> ``(p (..., 3), R (..., 3, 3))`` in SMPL's frame. A device at the identity looks along Unity's +z, so
    along SMPL's +z with +x to its left: SMPL's joint frames."""
    return mirror_points(p_unity), unity_quat_to_smpl_matrix(q_unity)


def hmd_to_head(p_hmd: np.ndarray, R_hmd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Headset pose in SMPL's frame (p (..., 3), R (..., 3, 3)) -> the SMPL head joint's: the same rotation,
    the position moved by :data:`HMD_TO_HEAD_SMPL_M` in the head's frame."""
    return p_hmd + (R_hmd @ HMD_TO_HEAD_SMPL_M[:, None])[..., 0], R_hmd


def head_to_hmd(p_head: np.ndarray, R_head: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`hmd_to_head` (a simulated headset worn on a known head)."""
    return p_head - (R_head @ HMD_TO_HEAD_SMPL_M[:, None])[..., 0], R_head
