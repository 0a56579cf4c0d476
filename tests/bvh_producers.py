"""BVH fixture writers in the exact layout of real producers (names, hierarchy, End Sites, channels, units, axes).

Each writer names the producer's code whose layout it follows; the motion itself is made up (a walking body,
small joint rotations), the layout is the producer's:

* :func:`write_axis_neuron_bvh`: Noitom's Perception Neuron / Axis Neuron export, as public Perception Neuron
  streaming tools reproduce its header (a C++ ``bvh_header_template`` string: ``ROOT Hips`` ... ``Spine3``,
  ``RightInHandIndex``; our own bone lengths): centimetres, y up, facing +z, every joint
  ``Yrotation Xrotation Zrotation`` (with displacement: six channels on every joint), **no toe joints** (an End
  Site under each foot), four spine joints ``Spine .. Spine3`` (the arms branch from ``Spine3``), ``Neck``,
  ``Head``, fingers with ``InHand`` metacarpals.
* :func:`write_video2bvh_bvh`: KevinLTT/video2bvh, ``bvh_skeleton/h36m_skeleton.py`` (``H36mSkeleton``) written by
  ``bvh_skeleton/bvh_helper.py`` (``write_bvh``): the Human3.6M 17 keypoints, z up, the T-pose OFFSETs of
  ``initial_directions`` times the mean bone length, ``HeadEndSite`` an End Site (no head joint: the neck is the
  last joint of the head chain), the root ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every
  other joint ``zxy``, 30 frames/s, metres.
* :func:`write_mediapipe_bvh`: the layout issue 42 reports for a MediaPipe-to-BVH tool: every OFFSET the same
  "up" vector times the bone length (helper joints zero), so the body exists only once the rotations are
  applied, as ``tests/test_joint_motion.py``'s ``write_rotation_only_bvh``; its joints lack ``Spine1`` and the
  toes. (The tool's own code was not found in the searchable public code; the layout follows the report.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

# ----------------------------------------------------------------------------- Perception Neuron / Axis Neuron

_NEURON: tuple[tuple[str, str | None, tuple[float, float, float]], ...] = (
    ("Hips", None, (0.0, 96.0, 0.0)),
    ("RightUpLeg", "Hips", (-9.5, -1.6, 0.0)),
    ("RightLeg", "RightUpLeg", (0.0, -42.0, 0.0)),
    ("RightFoot", "RightLeg", (0.0, -43.0, 0.0)),
    ("LeftUpLeg", "Hips", (9.5, -1.6, 0.0)),
    ("LeftLeg", "LeftUpLeg", (0.0, -42.0, 0.0)),
    ("LeftFoot", "LeftLeg", (0.0, -43.0, 0.0)),
    ("Spine", "Hips", (0.0, 16.0, 0.0)),
    ("Spine1", "Spine", (0.0, 10.0, 0.0)),
    ("Spine2", "Spine1", (0.0, 10.5, 0.0)),
    ("Spine3", "Spine2", (0.0, 10.0, 0.0)),
    ("Neck", "Spine3", (0.0, 10.5, 0.0)),
    ("Head", "Neck", (0.0, 9.5, 0.0)),
    ("RightShoulder", "Spine3", (-3.3, 7.0, 0.0)),
    ("RightArm", "RightShoulder", (-13.0, 0.0, 0.0)),
    ("RightForeArm", "RightArm", (-27.0, 0.0, 0.0)),
    ("RightHand", "RightForeArm", (-26.5, 0.0, 0.0)),
    ("RightHandThumb1", "RightHand", (-2.5, 0.2, 3.2)),
    ("RightHandThumb2", "RightHandThumb1", (-3.8, 0.0, 0.0)),
    ("RightHandThumb3", "RightHandThumb2", (-2.6, 0.0, 0.0)),
    ("RightInHandIndex", "RightHand", (-3.3, 0.5, 2.0)),
    ("RightHandIndex1", "RightInHandIndex", (-5.4, -0.1, 1.0)),
    ("RightHandIndex2", "RightHandIndex1", (-3.7, 0.0, 0.0)),
    ("RightHandIndex3", "RightHandIndex2", (-2.1, 0.0, 0.0)),
    ("RightInHandMiddle", "RightHand", (-3.5, 0.5, 0.8)),
    ("RightHandMiddle1", "RightInHandMiddle", (-5.3, -0.1, 0.3)),
    ("RightHandMiddle2", "RightHandMiddle1", (-4.0, 0.0, 0.0)),
    ("RightHandMiddle3", "RightHandMiddle2", (-2.5, 0.0, 0.0)),
    ("LeftShoulder", "Spine3", (3.3, 7.0, 0.0)),
    ("LeftArm", "LeftShoulder", (13.0, 0.0, 0.0)),
    ("LeftForeArm", "LeftArm", (27.0, 0.0, 0.0)),
    ("LeftHand", "LeftForeArm", (26.5, 0.0, 0.0)),
    ("LeftHandThumb1", "LeftHand", (2.5, 0.2, 3.2)),
    ("LeftHandThumb2", "LeftHandThumb1", (3.8, 0.0, 0.0)),
    ("LeftHandThumb3", "LeftHandThumb2", (2.6, 0.0, 0.0)),
    ("LeftInHandIndex", "LeftHand", (3.3, 0.5, 2.0)),
    ("LeftHandIndex1", "LeftInHandIndex", (5.4, -0.1, 1.0)),
    ("LeftHandIndex2", "LeftHandIndex1", (3.7, 0.0, 0.0)),
    ("LeftHandIndex3", "LeftHandIndex2", (2.1, 0.0, 0.0)),
    ("LeftInHandMiddle", "LeftHand", (3.5, 0.5, 0.8)),
    ("LeftHandMiddle1", "LeftInHandMiddle", (5.3, -0.1, 0.3)),
    ("LeftHandMiddle2", "LeftHandMiddle1", (4.0, 0.0, 0.0)),
    ("LeftHandMiddle3", "LeftHandMiddle2", (2.5, 0.0, 0.0)),
)
_NEURON_END = {"RightFoot": (0.0, -7.9, 17.9), "LeftFoot": (0.0, -7.9, 17.9), "Head": (0.0, 16.5, 0.0)}


def _write_hierarchy(joints, end_sites: dict, channels, pad: str = "  ") -> tuple[list[str], list[str]]:
    """HIERARCHY lines and the joints in channel order (depth first, children in listed order)."""
    children: dict[str, list[str]] = {n: [] for n, _, _ in joints}
    for n, p, _ in joints:
        if p is not None:
            children[p].append(n)
    offset = {n: o for n, _, o in joints}
    lines, order = ["HIERARCHY"], []

    def emit(n: str, depth: int, root: bool) -> None:
        ind, inner = pad * depth, pad * (depth + 1)
        order.append(n)
        lines.extend([f"{ind}{'ROOT' if root else 'JOINT'} {n}", f"{ind}{{",
                      f"{inner}OFFSET {' '.join(f'{v:.3f}' for v in offset[n])}", f"{inner}CHANNELS {channels(n)}"])
        for c in children[n]:
            emit(c, depth + 1, False)
        if not children[n]:
            end = end_sites.get(n, (0.0, 0.0, 0.0))
            lines.extend([f"{inner}End Site", f"{inner}{{", f"{inner}{pad}OFFSET {' '.join(f'{v:.3f}' for v in end)}",
                          f"{inner}}}"])
        lines.append(f"{ind}}}")

    emit(joints[0][0], 0, True)
    return lines, order


def write_axis_neuron_bvh(path: str | Path, frames: int = 12, fps: float = 60.0, seed: int = 0,
                          displacement: bool = True) -> Path:
    """A Perception Neuron / Axis Neuron BVH (cm, y up, no toes, Spine..Spine3, ``YXZ``); ``frames`` of a sway.

    ``displacement``: Axis Neuron's "with displacement" export (six channels on every joint, each joint's
    position channels holding its OFFSET), else three rotation channels below the root.
    """
    path = Path(path)
    rot = "Yrotation Xrotation Zrotation"
    six = f"6 Xposition Yposition Zposition {rot}"
    lines, order = _write_hierarchy(_NEURON, _NEURON_END,
                                    lambda n: six if (displacement or n == "Hips") else f"3 {rot}", pad="    ")
    offset = {n: o for n, _, o in _NEURON}
    rng = np.random.default_rng(seed)
    rows = []
    for t in range(frames):
        row: list[float] = []
        for n in order:
            if n == "Hips":
                row += [0.0, 96.0, 2.0 * t]
            elif displacement:
                row += list(offset[n])
            yxz = rng.normal(0.0, 6.0, 3)  # degrees
            if n in ("RightLeg", "LeftLeg"):
                yxz[1] = abs(yxz[1]) + 10.0  # knees bend forward
            row += list(yxz)
        rows.append(" ".join(f"{v:.4f}" for v in row))
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1 / fps:.6f}"] + rows
    path.write_text("\n".join(lines) + "\n")
    return path


# ----------------------------------------------------------------------------- video2bvh (Human3.6M skeleton)

_H36M_CHILDREN = {
    "Hip": ["RightHip", "LeftHip", "Spine"], "RightHip": ["RightKnee"], "RightKnee": ["RightAnkle"],
    "RightAnkle": ["RightAnkleEndSite"], "LeftHip": ["LeftKnee"], "LeftKnee": ["LeftAnkle"],
    "LeftAnkle": ["LeftAnkleEndSite"], "Spine": ["Thorax"], "Thorax": ["Neck", "LeftShoulder", "RightShoulder"],
    "Neck": ["HeadEndSite"], "LeftShoulder": ["LeftElbow"], "LeftElbow": ["LeftWrist"],
    "LeftWrist": ["LeftWristEndSite"], "RightShoulder": ["RightElbow"], "RightElbow": ["RightWrist"],
    "RightWrist": ["RightWristEndSite"],
}
"""``H36mSkeleton.children`` (End Sites included)."""
_H36M_DIRECTIONS = {
    "Hip": (0, 0, 0), "RightHip": (-1, 0, 0), "RightKnee": (0, 0, -1), "RightAnkle": (0, 0, -1),
    "RightAnkleEndSite": (0, -1, 0), "LeftHip": (1, 0, 0), "LeftKnee": (0, 0, -1), "LeftAnkle": (0, 0, -1),
    "LeftAnkleEndSite": (0, -1, 0), "Spine": (0, 0, 1), "Thorax": (0, 0, 1), "Neck": (0, 0, 1),
    "HeadEndSite": (0, 0, 1), "LeftShoulder": (1, 0, 0), "LeftElbow": (1, 0, 0), "LeftWrist": (1, 0, 0),
    "LeftWristEndSite": (1, 0, 0), "RightShoulder": (-1, 0, 0), "RightElbow": (-1, 0, 0), "RightWrist": (-1, 0, 0),
    "RightWristEndSite": (-1, 0, 0),
}
"""``H36mSkeleton.initial_directions``: the T-pose, z up, +x the body's left."""
_H36M_LENGTHS = {"RightHip": 0.13, "RightKnee": 0.45, "RightAnkle": 0.44, "Spine": 0.23, "Thorax": 0.25,
                 "Neck": 0.12, "HeadEndSite": 0.12, "RightShoulder": 0.15, "RightElbow": 0.28, "RightWrist": 0.25}
"""Mean bone lengths (metres) of a Human3.6M subject, per bone (both sides share them, as in video2bvh)."""


def write_video2bvh_bvh(path: str | Path, frames: int = 12, seed: int = 0) -> Path:
    """A BVH as video2bvh's ``H36mSkeleton.poses2bvh`` writes it (z up, metres, ``HeadEndSite`` an End Site)."""
    path = Path(path)
    parent = {c: p for p, cs in _H36M_CHILDREN.items() for c in cs}

    def length(n: str) -> float:
        if n == "Hip":
            return 0.0
        if "EndSite" in n and n != "HeadEndSite":
            return 0.4 * length(parent[n])  # bone_lens[child] = 0.4 * bone_lens[parent]
        return _H36M_LENGTHS[n.replace("Left", "Right")]

    def offset(n: str) -> tuple[float, float, float]:
        d = np.asarray(_H36M_DIRECTIONS[n], float)
        return tuple(d / max(np.linalg.norm(d), 1e-12) * length(n))

    joints = [(n, parent.get(n), offset(n)) for n in _order("Hip") if "EndSite" not in n]
    ends = {p: offset(c) for p, cs in _H36M_CHILDREN.items() for c in cs if "EndSite" in c}
    lines, order = _write_hierarchy(
        joints, ends, lambda n: "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if n == "Hip"
        else "3 Zrotation Xrotation Yrotation", pad="    ")
    rng = np.random.default_rng(seed)
    rows = []
    for t in range(frames):
        row: list[float] = [0.0, -0.02 * t, 0.92]  # the root's world position, z up
        for n in order:
            zxy = rng.normal(0.0, 5.0, 3)
            if n in ("RightKnee", "LeftKnee"):
                zxy[1] = -abs(zxy[1]) - 10.0  # knees bend (x is the body's left: a negative x rotation)
            row += list(zxy)
        rows.append(" ".join(f"{v}" for v in row))  # bvh_helper writes f"{element}"
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1 / 30}"] + rows
    path.write_text("\n".join(lines) + "\n")
    return path


def _order(root: str) -> list[str]:
    out = [root]
    for c in _H36M_CHILDREN.get(root, []):
        out += _order(c)
    return out


# ----------------------------------------------------------------------------- MediaPipe-to-BVH (body in rotations)

_MEDIAPIPE: tuple[tuple[str, str | None, int | None], ...] = (
    ("Hips", None, 0), ("LHipJoint", "Hips", None), ("LeftUpLeg", "LHipJoint", 1), ("LeftLeg", "LeftUpLeg", 4),
    ("LeftFoot", "LeftLeg", 7), ("RHipJoint", "Hips", None), ("RightUpLeg", "RHipJoint", 2),
    ("RightLeg", "RightUpLeg", 5), ("RightFoot", "RightLeg", 8), ("Spine", "Hips", 3), ("Spine2", "Spine", 9),
    ("Neck", "Spine2", 12), ("Head", "Neck", 15), ("LCollarRoot", "Spine2", None),
    ("LeftShoulder", "LCollarRoot", 13), ("LeftArm", "LeftShoulder", 16), ("LeftForeArm", "LeftArm", 18),
    ("LeftHand", "LeftForeArm", 20), ("RCollarRoot", "Spine2", None), ("RightShoulder", "RCollarRoot", 14),
    ("RightArm", "RightShoulder", 17), ("RightForeArm", "RightArm", 19), ("RightHand", "RightForeArm", 21),
)
"""Joint, parent, SMPL joint it sits on (None: a zero-OFFSET helper at its parent, giving a branch its own
rotation): no ``Spine1`` (SMPL's spine2) and no toes."""


def _from_up(d: np.ndarray) -> np.ndarray:
    """(T, 3, 3): the smallest rotations taking +y onto the directions d (T, 3)."""
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    axis = np.cross([0.0, 1.0, 0.0], d)
    s, c = np.linalg.norm(axis, axis=-1), d[:, 1]
    return Rotation.from_rotvec(axis / np.maximum(s, 1e-12)[:, None] * np.arctan2(s, c)[:, None]).as_matrix()


def write_mediapipe_bvh(path: str | Path, P: np.ndarray, fps: float = 30.0, unit: float = 0.01) -> Path:
    """Every OFFSET ``0 L 0`` (the same up vector, its bone's length L): the body only in the rotations.

    P (T, 22, 3): SMPL joints (y up, metres) the motion follows; written in ``unit`` metres (centimetres).
    """
    return write_rotation_only_bvh(path, P, _MEDIAPIPE, fps=fps, unit=unit)


def write_rotation_only_bvh(path: str | Path, P: np.ndarray, joints: tuple[tuple[str, str | None, int | None], ...],
                            fps: float = 30.0, unit: float = 0.01) -> Path:
    """A BVH of the skeleton ``joints`` ((name, parent, SMPL joint or None for a zero-OFFSET helper), parents first,
    the root named ``Hips``) whose every OFFSET is ``0 L 0`` (the layout MediaPipe-to-BVH tools write): the body
    lives only in the rotations. P (T, 22, 3): SMPL joints (y up, metres); written in ``unit`` metres."""
    path = Path(path)
    T = len(P)
    names = [n for n, _, _ in joints]
    parent = {n: p for n, p, _ in joints}
    pos: dict[str, np.ndarray] = {}
    for n, p, j in joints:
        pos[n] = P[:, j] if j is not None else pos[p]
    children = {n: [c for c, q, _ in joints if q == n] for n in names}
    length = {n: 0.0 if p is None else float(np.linalg.norm(pos[n][0] - pos[p][0])) for n, p, _ in joints}
    G: dict[str, np.ndarray] = {}
    for n in names:
        real = [c for c in children[n] if length[c] > 1e-9]
        if len(real) == 1:
            G[n] = _from_up(pos[real[0]] - pos[n])
        else:
            G[n] = G[parent[n]] if parent[n] else np.broadcast_to(np.eye(3), (T, 3, 3))
    table = [(n, p, (0.0, length[n] / unit, 0.0)) for n, p, _ in joints]
    lines, order = _write_hierarchy(table, {n: (0.0, 1.0, 0.0) for n in names},
                                    lambda n: ("6 Xposition Yposition Zposition " if parent[n] is None else "3 ")
                                    + "Zrotation Yrotation Xrotation")
    rows = []
    for t in range(T):
        row = list(P[t, 0] / unit)
        for n in order:
            R_local = G[n][t] if parent[n] is None else G[parent[n]][t].T @ G[n][t]
            row += list(Rotation.from_matrix(R_local).as_euler("ZYX", degrees=True))
        rows.append(" ".join(f"{v:.6f}" for v in row))
    lines += ["MOTION", f"Frames: {T}", f"Frame Time: {1 / fps:.6f}"] + rows
    path.write_text("\n".join(lines) + "\n")
    return path
