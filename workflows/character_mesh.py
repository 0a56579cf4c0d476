"""A glTF/GLB character's own skinned mesh, posed by linear blend skinning with its skin weights.

Per joint ``k`` the bind pose is ``T_world_joint_bind[k] = [A_k | P_k]`` (linear part ``A_k`` with any
armature scale, position ``P_k``; :func:`shape_inversion.gltf_io.read_rig`); a :class:`CustomPose`
gives the posed world rotation ``G_k`` (relative to the bind pose) and position ``p_k``, so the
posed joint is ``[G_k A_k | p_k]`` and the skinning matrix is ``M_k = [G_k | p_k - G_k P_k]``.
A vertex ``v`` in bind space is posed as ``sum_k w_k M_k (T_world_bind v)`` (glTF's ``JOINTS_0`` /
``WEIGHTS_0``, four influences; the glTF 2.0 specification, "Skins"). Everything is in the file's
world units and axes; :meth:`CustomCharacter.file_to_canon_points` takes it to character space.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from shape_inversion.gltf_io import DracoUnavailableError, GltfError, GltfRig, draco_primitive, read_accessor
from workflows.character import CustomCharacter, CustomPose

MAX_MESH_VERTICES = 2_000_000
"""Largest skinned mesh drawn (vertices, all primitives together)."""


@dataclass(frozen=True, eq=False)
class SkinnedMesh:
    """The skinned triangles of one skin (V vertices, F faces, J joints of :class:`GltfRig` order).

    Attributes:
        vertices_world: (V, 3) bind-pose vertices in world space (file units).
        faces: (F, 3) vertex indices.
        joints: (V, 4) joint indices (into the rig's parents-first joint order).
        weights: (V, 4) weights, rows summing to 1.
    """

    vertices_world: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    weights: np.ndarray


def skinned_mesh(rig: GltfRig) -> SkinnedMesh | None:
    """The triangles of every mesh node that uses ``rig``'s skin, or None when there is none.

    Draco-compressed primitives (``KHR_draco_mesh_compression``) are decoded with DracoPy; without it, one
    warning says the mesh cannot be shown and None is returned (never a silently empty mesh).
    """
    gltf, doc = rig.doc.gltf, rig.doc
    remap = skin_to_rig_index(rig)  # skin joint index -> rig index
    verts, faces, joints, weights = [], [], [], []
    count = 0
    for node in gltf.nodes or []:
        if node.mesh is None or node.skin != rig.skin or not 0 <= node.mesh < len(gltf.meshes or []):
            continue
        for prim in gltf.meshes[node.mesh].primitives or []:
            attrs = prim.attributes
            if prim.mode not in (None, 4) or attrs.POSITION is None or attrs.JOINTS_0 is None \
                    or attrs.WEIGHTS_0 is None:
                continue  # only skinned triangle lists
            try:
                draco = draco_primitive(doc, prim, max_vertices=MAX_MESH_VERTICES - count)
            except DracoUnavailableError as exc:
                warnings.warn(f"{exc}: the character's own mesh cannot be shown", stacklevel=2)
                return None
            if draco is not None:
                decoded, f_draco = draco
                if any(k not in decoded for k in ("POSITION", "JOINTS_0", "WEIGHTS_0")):
                    raise GltfError(f"{doc.path}: mesh {node.mesh}: the Draco buffer lacks POSITION, JOINTS_0 or "
                                    "WEIGHTS_0")
                v, j, w = decoded["POSITION"], decoded["JOINTS_0"], decoded["WEIGHTS_0"]
            else:
                v = read_accessor(doc, attrs.POSITION)
                j = read_accessor(doc, attrs.JOINTS_0)
                w = read_accessor(doc, attrs.WEIGHTS_0)
            if v.shape[1:] != (3,) or j.shape != (len(v), 4) or w.shape != (len(v), 4):
                raise GltfError(f"{doc.path}: mesh {node.mesh}: POSITION/JOINTS_0/WEIGHTS_0 shapes do not match")
            if j.min(initial=0) < 0 or j.max(initial=0) >= len(remap):
                raise GltfError(f"{doc.path}: mesh {node.mesh}: JOINTS_0 names a joint outside skin #{rig.skin}")
            if draco is not None:
                f = f_draco.reshape(-1)
            else:
                f = read_accessor(doc, prim.indices).reshape(-1) if prim.indices is not None else np.arange(len(v))
            if f.size % 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
                raise GltfError(f"{doc.path}: mesh {node.mesh}: invalid triangle indices")
            count += len(v)
            if count > MAX_MESH_VERTICES:
                raise GltfError(f"{doc.path}: skinned mesh has more than {MAX_MESH_VERTICES} vertices")
            faces.append(f.reshape(-1, 3) + sum(len(x) for x in verts))
            verts.append(v)
            joints.append(remap[j.astype(np.int64)])
            weights.append(w)
    if not verts:
        return None
    V = np.concatenate(verts)
    V_world = V @ rig.bind_to_world[:3, :3].T + rig.bind_to_world[:3, 3]
    W = np.concatenate(weights)
    W = W / np.maximum(W.sum(1, keepdims=True), 1e-12)
    return SkinnedMesh(V_world, np.concatenate(faces), np.concatenate(joints), W)


def skin_to_rig_index(rig: GltfRig) -> np.ndarray:
    """(S,) the rig joint (index into ``rig.joint_nodes``) that moves each of the skin's S joints.

    The rig may hold only some of the skin's joints (a Rigify rig read from its ``DEF-`` bones, the hierarchy
    holding the body of a UE mannequin with ``ik_*`` roots): a joint left out moves with its nearest kept
    ancestor node (the root joint when it has none).
    """
    gltf, doc = rig.doc.gltf, rig.doc
    skin_joints = list(gltf.skins[rig.skin].joints or []) if 0 <= rig.skin < len(gltf.skins or []) else []
    size = max(len(skin_joints), max(rig.skin_order, default=-1) + 1)
    remap = np.full(size, -1, dtype=np.int64)
    remap[list(rig.skin_order)] = np.arange(len(rig.skin_order))
    kept = {int(node): k for k, node in enumerate(rig.joint_nodes)}
    for s, node in enumerate(skin_joints):
        if remap[s] >= 0:
            continue
        n = int(node) if isinstance(node, int) and 0 <= node < len(doc.parent) else -1
        while n >= 0 and n not in kept:
            n = doc.parent[n]
        remap[s] = kept.get(n, 0)
    remap[remap < 0] = 0
    return remap


def pose_mesh(mesh: SkinnedMesh, rig: GltfRig, R_world: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    """Posed vertices (V, 3), file units, by LBS.

    ``R_world`` (J, 3, 3): posed joint rotations relative to the bind pose; ``p_world`` (J, 3): joint positions.
    """
    P_bind = rig.T_world_joint_bind[:, :3, 3]
    t = p_world - np.einsum("jab,jb->ja", R_world, P_bind)  # (J, 3)
    R_v = np.einsum("vk,vkab->vab", mesh.weights, R_world[mesh.joints])  # blended linear part (V, 3, 3)
    t_v = np.einsum("vk,vka->va", mesh.weights, t[mesh.joints])
    return np.einsum("vab,vb->va", R_v, mesh.vertices_world) + t_v


def character_mesh_canon(char: CustomCharacter, pose: CustomPose) -> tuple[np.ndarray, np.ndarray] | None:
    """The character's own posed mesh in character space: (vertices (V, 3) metres, faces (F, 3)), or None."""
    rig = char.skeleton.gltf
    if rig is None:
        return None
    mesh = skinned_mesh(rig)
    if mesh is None:
        return None
    R, p = pose.positions(char)
    return char.file_to_canon_points(pose_mesh(mesh, rig, R, p)), mesh.faces


def own_mesh_item(char: CustomCharacter, pose: CustomPose, color=(0.85, 0.72, 0.60, 1.0)):
    """The character's own posed mesh as a :class:`smplik.render.MeshItem` (character space), or None."""
    from smplik.render import MeshItem

    posed = character_mesh_canon(char, pose)
    return None if posed is None else MeshItem(posed[0], posed[1], color)


def scene_character_own_mesh(character, color=(0.85, 0.72, 0.60, 1.0), base_dir=None):
    """A scene character's own posed mesh (glTF/GLB characters with a pose), else None.

    ``character`` is a :class:`workflows.scene.SceneCharacter`; its skeleton file is re-read with its
    stored options and its ``(betas, scale)``. A relative skeleton path is resolved against ``base_dir``
    (the scene file's folder; default: the current folder), as :func:`workflows.scene.export.export_scene` does.
    """
    import dataclasses
    from pathlib import Path

    from workflows.character import character_from_estimate, smpl_to_custom

    sk = character.skeleton
    if sk is None or character.pose is None or Path(sk.path).suffix.lower() not in (".glb", ".gltf"):
        return None
    path = Path(sk.path) if base_dir is None or Path(sk.path).is_absolute() else Path(base_dir) / sk.path
    if not path.is_file():
        return None
    char = character_from_estimate(str(path), sk.options, character.betas, character.scale, character.gender)
    pose = smpl_to_custom(dataclasses.replace(character.pose, betas=character.betas), char)
    return own_mesh_item(char, pose, color)
