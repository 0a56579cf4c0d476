"""Example character files in real producers' layouts, written by tests and benchmarks (none is committed).

Every writer takes the same skeleton: SMPL's 24 rest joints in metres, y-up, facing +z
(``joints_m`` (24, 3)), so each file's SMPL-SI estimate can be compared with the plain-metres one.

* :func:`write_mixamo_bvh`: Mixamo's BVH (``mixamorig:`` names, centimetres, **every joint**
  ``CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation``, position channels equal
  to the OFFSETs), as Mixamo's downloader "BVH" writes and Blender's ``io_anim_bvh`` reads
  (``import_bvh.py``: ``bvh_node.rest_head_local`` from OFFSET, animated location from the channels).
* :func:`write_rokoko_bvh`: Rokoko Studio-style BVH (Rokoko's names ``LeftThigh/LeftShin/LeftFoot/
  LeftToe``, ``LeftUpperArm``-less ``LeftArm/LeftForeArm``, centimetres, 6 channels on every joint).
* :func:`write_cmu_bvh`: the cgspeed CMU conversion (CMU units 1/0.45 inch, root 6 channels, others
  ``Zrotation Yrotation Xrotation``; names as ``shape_inversion/presets`` ``cmu``).
* :func:`write_mixamo_gltf`: a GLB/glTF as Blender's glTF exporter writes a Mixamo character
  (``io_export_scene_gltf2``: an ``Armature`` node rotated +90 deg about x (z-up armature) and scaled
  0.01 (centimetre bones), ``mixamorig:`` joint nodes, inverse bind matrices in world space, a skinned
  mesh child of the armature) under an extra non-identity root node; ``external_bin`` writes a
  ``.gltf`` with its buffer in ``<stem>.bin`` beside it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_NAMES, PARENTS
from smplik.data.bvh import format_bvh
from smplik.data.retarget import load_preset
from workflows.examples_gen import MIXAMO_NAMES

ROKOKO_NAMES = {
    "pelvis": "Hips", "left_hip": "LeftThigh", "right_hip": "RightThigh", "spine1": "Spine1",
    "left_knee": "LeftShin", "right_knee": "RightShin", "spine2": "Spine2", "left_ankle": "LeftFoot",
    "right_ankle": "RightFoot", "spine3": "Spine3", "left_foot": "LeftToe", "right_foot": "RightToe",
    "neck": "Neck", "left_collar": "LeftShoulder", "right_collar": "RightShoulder", "head": "Head",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm", "left_elbow": "LeftForeArm",
    "right_elbow": "RightForeArm", "left_wrist": "LeftHand", "right_wrist": "RightHand",
    "left_hand": "LeftFinger3Metacarpal", "right_hand": "RightFinger3Metacarpal",
}

CMU_NAMES = load_preset("cmu").joints

CMU_UNIT_M = 0.0254 / 0.45


def _offsets(joints: np.ndarray) -> np.ndarray:
    return np.array([joints[k] if p < 0 else joints[k] - joints[p] for k, p in enumerate(PARENTS)])


def _write_bvh(path: Path, names: list[str], joints_units: np.ndarray, channels: list[tuple[str, ...]],
               rows: np.ndarray) -> Path:
    text = format_bvh(names, list(PARENTS), _offsets(joints_units), channels, rows, 1 / 30)
    path.write_text(text)
    return path


def _six_channel_rows(offsets: np.ndarray, frames: int = 2) -> np.ndarray:
    """Every joint: its translation (= OFFSET) then 3 zero rotations; frame 1 bends the right knee."""
    row = np.concatenate([np.concatenate([o, np.zeros(3)]) for o in offsets])
    rows = np.tile(row, (frames, 1))
    if frames > 1:
        rows[1, 6 * JOINT_NAMES.index("right_knee") + 4] = 40.0  # Xrotation of the knee (ZXY order)
    return rows


def write_mixamo_bvh(path: Path, joints_m: np.ndarray) -> Path:
    names = [f"mixamorig:{MIXAMO_NAMES[n]}" for n in JOINT_NAMES]
    J = joints_m * 100.0
    chans = [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")] * 24
    return _write_bvh(path, names, J, chans, _six_channel_rows(_offsets(J)))


def write_rokoko_bvh(path: Path, joints_m: np.ndarray) -> Path:
    names = [ROKOKO_NAMES[n] for n in JOINT_NAMES]
    J = joints_m * 100.0
    chans = [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")] * 24
    return _write_bvh(path, names, J, chans, _six_channel_rows(_offsets(J)))


def write_cmu_bvh(path: Path, joints_m: np.ndarray) -> Path:
    names = [CMU_NAMES[n] for n in JOINT_NAMES]
    J = joints_m / CMU_UNIT_M
    chans = [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")] + \
        [("Zrotation", "Yrotation", "Xrotation")] * 23
    rows = np.zeros((1, 6 + 3 * 23))
    rows[0, :3] = J[0]
    return _write_bvh(path, names, J, chans, rows)


def write_plain_json(path: Path, joints_m: np.ndarray) -> Path:
    import json

    path.write_text(json.dumps({"units": "m", "up": "y",
                                "joints": {n: [float(x) for x in joints_m[i]] for i, n in enumerate(JOINT_NAMES)}}))
    return path


ROOT_T = np.array([0.4, 0.0, -0.3])
ROOT_R = Rotation.from_euler("y", 25, degrees=True)
ARMATURE_R = Rotation.from_euler("x", 90, degrees=True)  # z-up armature in a y-up glTF scene
ARMATURE_S = 0.01


def _trs(t=None, r: Rotation | None = None, s: float = 1.0) -> np.ndarray:
    M = np.eye(4)
    if r is not None:
        M[:3, :3] = r.as_matrix()
    M[:3, :3] *= s
    if t is not None:
        M[:3, 3] = t
    return M


def write_mixamo_gltf(path: Path, joints_m: np.ndarray, mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                      *, external_bin: bool = False) -> Path:
    """``mesh``: (vertices (V, 3) metres in the skeleton's frame, faces (F, 3), weights (V, 24)) or None."""
    import pygltflib

    root_M = _trs(ROOT_T, ROOT_R)
    arm_M = root_M @ _trs(None, ARMATURE_R, ARMATURE_S)
    world_pos = joints_m @ ROOT_R.as_matrix().T + ROOT_T  # joints placed in the world by the root node
    arm_inv = np.linalg.inv(arm_M)
    q = world_pos @ arm_inv[:3, :3].T + arm_inv[:3, 3]  # armature-local (centimetres, z-up)
    blob = bytearray()
    views, accessors = [], []

    def add(arr: np.ndarray, comp: int, kind: str, minmax: bool = False) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        while len(blob) % 4:
            blob.append(0)
        views.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
        blob.extend(data)
        flat = arr.reshape(len(arr), -1)
        accessors.append(pygltflib.Accessor(bufferView=len(views) - 1, componentType=comp, count=len(arr), type=kind,
                                            min=flat.min(0).tolist() if minmax else None,
                                            max=flat.max(0).tolist() if minmax else None))
        return len(accessors) - 1

    # Blender's exporter: IBM = inverse of the joint's world matrix (armature scale and rotation folded in)
    joint_world = np.stack([arm_M @ _trs(q[k]) for k in range(24)])
    ibm = np.linalg.inv(joint_world).transpose(0, 2, 1).astype(np.float32)  # column-major
    ibm_acc = add(ibm, pygltflib.FLOAT, "MAT4")
    nodes = [pygltflib.Node(name=f"mixamorig:{MIXAMO_NAMES[n]}",
                            translation=(q[k] - (q[PARENTS[k]] if PARENTS[k] >= 0 else 0)).tolist(),
                            children=[c for c in range(24) if PARENTS[c] == k] or None)
             for k, n in enumerate(JOINT_NAMES)]
    arm_children = [0]
    meshes = []
    if mesh is not None:
        verts, faces, weights = mesh
        top = np.argsort(-weights, axis=1)[:, :4]
        w = np.take_along_axis(weights, top, axis=1)
        w /= w.sum(1, keepdims=True)
        v_world = verts @ ROOT_R.as_matrix().T + ROOT_T  # bind space = world (world-space IBMs)
        prim = pygltflib.Primitive(attributes=pygltflib.Attributes(
            POSITION=add(v_world.astype(np.float32), pygltflib.FLOAT, "VEC3", minmax=True),
            JOINTS_0=add(top.astype(np.uint16), pygltflib.UNSIGNED_SHORT, "VEC4"),
            WEIGHTS_0=add(w.astype(np.float32), pygltflib.FLOAT, "VEC4")),
            indices=add(faces.reshape(-1).astype(np.uint32), pygltflib.UNSIGNED_INT, "SCALAR"))
        meshes = [pygltflib.Mesh(name="Beta_Surface", primitives=[prim])]
        nodes.append(pygltflib.Node(name="Beta_Surface", mesh=0, skin=0))
        arm_children.append(len(nodes) - 1)
    q_arm = ARMATURE_R.as_quat().tolist()
    nodes.append(pygltflib.Node(name="Armature", rotation=q_arm, scale=[ARMATURE_S] * 3, children=arm_children))
    nodes.append(pygltflib.Node(name="Root", translation=ROOT_T.tolist(), rotation=ROOT_R.as_quat().tolist(),
                                children=[len(nodes) - 1]))
    uri = f"{path.stem}.bin" if external_bin else None
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(generator="Khronos glTF Blender I/O (test layout)", version="2.0"),
        scenes=[pygltflib.Scene(nodes=[len(nodes) - 1])], scene=0, nodes=nodes, meshes=meshes,
        skins=[pygltflib.Skin(joints=list(range(24)), inverseBindMatrices=ibm_acc, skeleton=0)],
        accessors=accessors, bufferViews=views, buffers=[pygltflib.Buffer(byteLength=len(blob), uri=uri)])
    if external_bin:
        (path.parent / uri).write_bytes(bytes(blob))
        gltf.save_json(str(path))
    else:
        gltf.set_binary_blob(bytes(blob))
        gltf.save_binary(str(path))
    return path


def smpl_rest(gender: str = "neutral") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Built-in body at beta = 0: rest joints (24, 3), vertices (V, 3), faces (F, 3), weights (V, 24); metres."""
    import torch

    from smplik.body_model import load_body_model

    model = load_body_model(gender)
    with torch.no_grad():
        verts, _ = model.vertices(torch.zeros(1, 3), torch.zeros(1, 23, 3), torch.zeros(1, 3), torch.zeros(1, 10))
    J = model.rest_joints(torch.zeros(10)).double().numpy()
    return J, verts[0].double().numpy(), model.faces, np.asarray(model.arrays["weights"], dtype=np.float64)
