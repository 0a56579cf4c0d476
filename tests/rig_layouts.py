"""Characters in the layouts of real producers' glTF exports, written from the committed real rigs (no tests here).

* :func:`write_sketchfab_ik_rig`: Sketchfab's glTF download (``Sketchfab_model`` / ``root`` / ``GLTF_SceneRootNode``
  / ``Armature_N`` / ``GLTF_created_0`` / ``GLTF_created_0_rootJoint`` above the bones, every name tagged ``_<n>``
  by Sketchfab's converter) of a Blender rig named ``hips_IK``, ``leg_upper.L``, ``arm_lower.R``... with IK helper
  bones (``foot_IK.L``, ``heel_IK.L``, ``knee_pole.L``, ``hand_IK.L``, ``elbow_pole.L``) beside the body in the skin,
  as the held-out Sketchfab file of issue #42 names them (``GLTF_created_0_rootJoint``, ``hips_IK_28``,
  ``leg_upper.L_6``). Written from ``tests/data/rigs/sketchfab_anime_boy_skeleton.glb`` (a real Sketchfab download).
* :func:`write_ue4_mannequin`: Epic's UE4 mannequin skeleton re-exported by Blender (``root`` at the floor,
  ``pelvis``, ``spine_01..03``, ``clavicle_l``, ``upperarm_l``, ``thigh_l``, ``calf_l``, ``ball_l``, ...) with
  the IK bone hierarchies under ``root`` (``ik_foot_root`` -> ``ik_foot_l/r``, ``ik_hand_root`` ->
  ``ik_hand_gun`` -> ``ik_hand_l/r``) listed *first* in the skin, so the body's ``JOINTS_0`` indices run past the
  joints a reader keeps (the ``IndexError: index 221 is out of bounds for axis 0 with size 93`` of issue #42).
  Written from ``tests/data/rigs/threejs_Soldier.glb`` (a real skinned Mixamo character with its mesh).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

RIGS = Path(__file__).resolve().parent / "data" / "rigs"


def _translation(p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


class _Editor:
    """Adds joint nodes to a pygltflib document's skin 0 (their inverse bind matrices in the skin's bind frame)."""

    def __init__(self, src: Path) -> None:
        import pygltflib

        from shape_inversion.gltf_io import load_gltf, read_rig

        self.doc = pygltflib.GLTF2.load_binary(src)
        loaded = load_gltf(src)
        self.world = {i: loaded.world[i] for i in range(len(loaded.world))}
        self.bind = read_rig(loaded).bind_to_world
        self.ibm = loaded.accessor(self.doc.skins[0].inverseBindMatrices)  # (J, 4, 4) skin order, row-major
        self.joints_0 = {}  # accessor index -> decoded JOINTS_0
        self.added: list[int] = []
        self.blob = bytearray(self.doc.binary_blob())
        for mesh in self.doc.meshes or []:
            for prim in mesh.primitives:
                if prim.attributes.JOINTS_0 is not None:
                    self.joints_0[prim.attributes.JOINTS_0] = loaded.accessor(prim.attributes.JOINTS_0)

    def by_name(self, name: str) -> int:
        return next(i for i, n in enumerate(self.doc.nodes) if n.name == name)

    def add(self, name: str, parent: int, world_pos) -> int:
        import pygltflib

        local = np.linalg.inv(self.world[parent]) @ _translation(np.asarray(world_pos, dtype=np.float64))
        k = len(self.doc.nodes)
        self.doc.nodes.append(pygltflib.Node(name=name, translation=local[:3, 3].tolist()))
        self.doc.nodes[parent].children = [*(self.doc.nodes[parent].children or []), k]
        self.world[k] = self.world[parent] @ local
        self.added.append(k)
        return k

    def _append(self, data: bytes, **accessor) -> int:
        import pygltflib

        off = len(self.blob) + (-len(self.blob) % 4)
        self.blob += b"\0" * (off - len(self.blob)) + data
        self.doc.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=off, byteLength=len(data)))
        self.doc.accessors.append(pygltflib.Accessor(bufferView=len(self.doc.bufferViews) - 1, **accessor))
        return len(self.doc.accessors) - 1

    def save(self, out: Path, *, added_first: bool = False) -> Path:
        skin = self.doc.skins[0]
        new = np.stack([np.linalg.inv(np.linalg.inv(self.bind) @ self.world[k]) for k in self.added])
        old_joints = list(skin.joints)
        if added_first:
            joints, ibm, shift = [*self.added, *old_joints], np.concatenate([new, self.ibm]), len(self.added)
        else:
            joints, ibm, shift = [*old_joints, *self.added], np.concatenate([self.ibm, new]), 0
        skin.joints = joints
        skin.inverseBindMatrices = self._append(ibm.transpose(0, 2, 1).astype("<f4").tobytes(), componentType=5126,
                                                count=len(ibm), type="MAT4")
        for mesh in self.doc.meshes or []:
            for prim in mesh.primitives:
                j = prim.attributes.JOINTS_0
                if j is not None and shift:
                    data = (self.joints_0[j] + shift).astype("<u2").tobytes()
                    prim.attributes.JOINTS_0 = self._append(data, componentType=5123, count=len(self.joints_0[j]),
                                                            type="VEC4")
        self.doc.buffers[0].byteLength = len(self.blob)
        self.doc.set_binary_blob(bytes(self.blob))
        self.doc.save_binary(str(out))
        return out


def write_sketchfab_ik_rig(out: Path) -> Path:
    """The Sketchfab layout with ``hips_IK_<n>`` / ``leg_upper.L_<n>`` names and IK helper bones (module doc)."""
    ed = _Editor(RIGS / "sketchfab_anime_boy_skeleton.glb")
    rename = {"Root": "root", "J_Bip_C_Hips": "hips_IK", "J_Bip_C_Spine": "spine", "J_Bip_C_Chest": "chest",
              "J_Bip_C_UpperChest": "chest_upper", "J_Bip_C_Neck": "neck", "J_Bip_C_Head": "head"}
    for s in "LR":
        rename.update({f"J_Bip_{s}_Shoulder": f"shoulder.{s}", f"J_Bip_{s}_UpperArm": f"arm_upper.{s}",
                       f"J_Bip_{s}_LowerArm": f"arm_lower.{s}", f"J_Bip_{s}_Hand": f"hand.{s}",
                       f"J_Bip_{s}_UpperLeg": f"leg_upper.{s}", f"J_Bip_{s}_LowerLeg": f"leg_lower.{s}",
                       f"J_Bip_{s}_Foot": f"foot.{s}", f"J_Bip_{s}_ToeBase": f"toe.{s}"})
        for finger in ("Index", "Little", "Middle", "Ring", "Thumb"):
            for k in "123":
                rename[f"J_Bip_{s}_{finger}{k}"] = f"finger_{finger.lower()}_{k}.{s}"
    for node in ed.doc.nodes:
        m = re.fullmatch(r"(.*)_(\d+)", node.name or "")
        if m and m.group(1) in rename:
            node.name = f"{rename[m.group(1)]}_{m.group(2)}"
    names = {n.name.rsplit("_", 1)[0]: i for i, n in enumerate(ed.doc.nodes) if re.search(r"_\d+$", n.name or "")}
    root = ed.by_name("root_111")
    pos = {k: ed.world[i][:3, 3] for k, i in names.items()}
    forward = np.array([0.0, 0.0, 0.3])  # the character faces +z (glTF's front)
    tag = 200
    for s in "LR":
        foot = ed.add(f"foot_IK.{s}_{tag}", root, pos[f"foot.{s}"])
        ed.add(f"heel_IK.{s}_{tag + 1}", foot, pos[f"foot.{s}"] * [1, 0, 1] - [0, 0, 0.05])
        ed.add(f"knee_pole.{s}_{tag + 2}", root, pos[f"leg_lower.{s}"] + forward)
        ed.add(f"hand_IK.{s}_{tag + 3}", root, pos[f"hand.{s}"])
        ed.add(f"elbow_pole.{s}_{tag + 4}", root, pos[f"arm_lower.{s}"] - forward)
        tag += 5
    return ed.save(out)


UE4_NAMES = {"Hips": "pelvis", "Spine": "spine_01", "Spine1": "spine_02", "Spine2": "spine_03", "Neck": "neck_01",
             "Head": "head"}
for _side, _s in (("Left", "l"), ("Right", "r")):
    UE4_NAMES.update({f"{_side}Shoulder": f"clavicle_{_s}", f"{_side}Arm": f"upperarm_{_s}",
                      f"{_side}ForeArm": f"lowerarm_{_s}", f"{_side}Hand": f"hand_{_s}", f"{_side}UpLeg": f"thigh_{_s}",
                      f"{_side}Leg": f"calf_{_s}", f"{_side}Foot": f"foot_{_s}", f"{_side}ToeBase": f"ball_{_s}"})
    for _f, _u in (("Thumb", "thumb"), ("Index", "index"), ("Middle", "middle"), ("Ring", "ring"), ("Pinky", "pinky")):
        for _k in "123":
            UE4_NAMES[f"{_side}Hand{_f}{_k}"] = f"{_u}_0{_k}_{_s}"


def write_ue4_mannequin(out: Path) -> Path:
    """The UE4 mannequin layout with IK root bones listed first in the skin (module doc)."""
    ed = _Editor(RIGS / "threejs_Soldier.glb")
    for node in ed.doc.nodes:
        if (node.name or "").startswith("mixamorig:"):
            node.name = UE4_NAMES.get(node.name.split(":", 1)[1], node.name.split(":", 1)[1].lower())
    pelvis = ed.by_name("pelvis")
    top = next(i for i, n in enumerate(ed.doc.nodes) if pelvis in (n.children or []))
    floor = ed.world[top][:3, 3]
    root = ed.add("root", top, floor)  # UE's root bone at the floor; the pelvis moves under it
    ed.doc.nodes[top].children = [c for c in ed.doc.nodes[top].children if c != pelvis]
    ed.doc.nodes[root].children = [pelvis]
    local = np.linalg.inv(ed.world[root]) @ ed.world[pelvis]
    node = ed.doc.nodes[pelvis]
    if node.matrix is not None:
        node.matrix = local.T.reshape(-1).tolist()
    else:
        from scipy.spatial.transform import Rotation

        scale = np.linalg.norm(local[:3, :3], axis=0)
        node.translation = local[:3, 3].tolist()
        node.rotation = Rotation.from_matrix(local[:3, :3] / scale).as_quat().tolist()
        node.scale = scale.tolist()
    p = {n.name: ed.world[i][:3, 3] for i, n in enumerate(ed.doc.nodes) if n.name in ("foot_l", "foot_r", "hand_l",
                                                                                       "hand_r")}
    foot_root = ed.add("ik_foot_root", root, floor)
    ed.add("ik_foot_l", foot_root, p["foot_l"])
    ed.add("ik_foot_r", foot_root, p["foot_r"])
    hand_root = ed.add("ik_hand_root", root, floor)
    gun = ed.add("ik_hand_gun", hand_root, p["hand_r"])
    ed.add("ik_hand_l", gun, p["hand_l"])
    ed.add("ik_hand_r", gun, p["hand_r"])
    ed.doc.skins[0].skeleton = root
    return ed.save(out, added_first=True)
