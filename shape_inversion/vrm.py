"""VRM humanoid bone tables (one file per external convention): VRM 0.x and 1.0 -> SMPL joints.

A ``.vrm`` file is a GLB whose JSON carries the avatar's own humanoid table:

* VRM 0.x: ``extensions.VRM.humanoid.humanBones``, a list of ``{"bone": "leftUpperArm", "node": 12, ...}``
  (vrm-c/UniVRM ``glTF_VRM_HumanoidBone``);
* VRM 1.0: ``extensions.VRMC_vrm.humanoid.humanBones``, an object ``{"leftUpperArm": {"node": 12}, ...}``
  (vrm-c/vrm-specification ``VRMC_vrm.humanoid.humanBones.schema.json``).

Bone names follow Unity's ``HumanBodyBones`` in lower camel case. ``chest`` is SMPL's spine3 when the
table has no ``upperChest`` (an optional bone), else spine2.
"""

from __future__ import annotations

from collections.abc import Mapping

from shape_inversion.gltf_io import GltfError, GltfFile
from smplik.conventions import JOINT_NAMES

VRM_TO_SMPL: dict[str, str] = {
    "hips": "pelvis", "spine": "spine1", "neck": "neck", "head": "head",
    "leftUpperLeg": "left_hip", "rightUpperLeg": "right_hip", "leftLowerLeg": "left_knee",
    "rightLowerLeg": "right_knee", "leftFoot": "left_ankle", "rightFoot": "right_ankle",
    "leftToes": "left_foot", "rightToes": "right_foot", "leftShoulder": "left_collar",
    "rightShoulder": "right_collar", "leftUpperArm": "left_shoulder", "rightUpperArm": "right_shoulder",
    "leftLowerArm": "left_elbow", "rightLowerArm": "right_elbow", "leftHand": "left_wrist",
    "rightHand": "right_wrist", "leftMiddleProximal": "left_hand", "rightMiddleProximal": "right_hand",
}
"""VRM humanoid bone -> SMPL joint (``chest``/``upperChest`` handled by :func:`humanoid_to_smpl`)."""


def humanoid_nodes(doc: GltfFile) -> dict[str, int]:
    """The file's VRM humanoid table ``{bone name: node index}`` (VRM 1.0 first, then 0.x); {} when absent.

    Raises :class:`GltfError` when the table is malformed (a node index out of range, a bone without a node).
    """
    ext = doc.gltf.extensions or {}
    n_nodes = len(doc.gltf.nodes or [])
    table: dict[str, int] = {}
    v1 = ext.get("VRMC_vrm")
    v0 = ext.get("VRM")
    for key, value in (("VRMC_vrm", v1), ("VRM", v0)):
        if value is not None and not isinstance(value, Mapping):
            raise GltfError(f"{doc.path}: extensions.{key} must be an object, got {type(value).__name__}")
        humanoid = value.get("humanoid") if isinstance(value, Mapping) else None
        if humanoid is not None and not isinstance(humanoid, Mapping):
            raise GltfError(f"{doc.path}: extensions.{key}.humanoid must be an object, got "
                            f"{type(humanoid).__name__}")
    if isinstance(v1, Mapping):
        bones = (v1.get("humanoid") or {}).get("humanBones") or {}
        if not isinstance(bones, Mapping):
            raise GltfError(f"{doc.path}: VRMC_vrm.humanoid.humanBones must be an object")
        for bone, entry in bones.items():
            table[str(bone)] = entry.get("node") if isinstance(entry, Mapping) else None
    elif isinstance(v0, Mapping):
        bones = (v0.get("humanoid") or {}).get("humanBones") or []
        if not isinstance(bones, list):
            raise GltfError(f"{doc.path}: VRM.humanoid.humanBones must be a list")
        for entry in bones:
            if isinstance(entry, Mapping) and isinstance(entry.get("bone"), str):
                table[entry["bone"]] = entry.get("node")
    for bone, node in table.items():
        if isinstance(node, bool) or not isinstance(node, int) or not 0 <= node < n_nodes:
            raise GltfError(f"{doc.path}: VRM humanoid bone {bone!r}: node {node!r} is not a node index")
    if table and "hips" not in table:
        raise GltfError(f"{doc.path}: VRM humanoid table has no 'hips' bone")
    return table


def humanoid_to_smpl(table: Mapping[str, int]) -> dict[str, int]:
    """SMPL joint -> node index from a VRM humanoid table."""
    out = {smpl: table[bone] for bone, smpl in VRM_TO_SMPL.items() if bone in table}
    if "upperChest" in table:
        out["spine3"] = table["upperChest"]
        if "chest" in table:
            out["spine2"] = table["chest"]
    elif "chest" in table:
        out["spine3"] = table["chest"]
    return {s: out[s] for s in JOINT_NAMES if s in out}
