"""``smplik scene export``: the (edited, re-solved) scene back onto each character, as files a DCC tool opens.

Per character with a solved pose (:func:`export_scene`):

* **BVH** ``<name>.bvh``: a custom character's own skeleton posed by retargeting
  (:func:`workflows.character.smpl_to_custom`; a BVH source keeps its joints, OFFSETs, channel
  layout and rotation order, :func:`workflows.character.custom_bvh_text`); an SMPL character's
  24-joint SMPL skeleton (its ``scale * J(betas)`` OFFSETs, metres, y-up; root ``Xposition
  Yposition Zposition Zrotation Yrotation Xrotation``, other joints ``Zrotation Yrotation Xrotation``).
* **GLB** ``<name>.glb``: a glTF/GLB character's own file (mesh, materials, skin) with its joint
  nodes posed, its own animation clips kept and the pose added as one more clip (``pose``); an SMPL
  character as a skinned SMPL mesh (its rest mesh, 24 joints, SMPL's skin weights reduced to the four
  largest) posed the same way; so is a character read from BVH/JSON (no mesh of its own): its SMPL-SI body,
  at its shape and scale (:func:`glb_notes` says so in one line).
* **One world frame.** Every file of a scene is in the scene's world frame (metres, y-up, the scene's
  floor and facing), so several exported characters line up in a 3D tool: a custom character's GLB gets
  one extra root node ``smplik_world`` taking its own frame (units, axes) to the scene's; its BVH keeps
  its source's layout (joints, channels, rotation orders, End Sites) with OFFSETs, rotations and root
  positions converted to the world frame (``bvh_frame="source"`` keeps the file's own units and axes).
  The pose frames come first, then the source's own MOTION frames (converted the same way).

Several poses per character (``poses``: a frame sequence) export as one animation. Joint node
transforms are written as translation/rotation/scale (glTF quaternions ``(x, y, z, w)``).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from shape_inversion.gltf_io import MESHOPT_EXTENSIONS, node_local_matrix
from smplik.atomic import write_bytes_atomic, write_text_atomic
from smplik.conventions import JOINT_NAMES, PARENTS
from smplik.data.bvh import format_bvh
from smplik.pose import Pose
from smplik.rotations import matrix_to_euler_deg_np
from workflows.character import (
    JOINT_CHANNELS,
    ROOT_CHANNELS,
    CustomCharacter,
    CustomPose,
    character_from_estimate,
    custom_bvh_text,
    smpl_to_custom,
)
from workflows.scene.characters import SceneCharacter
from workflows.scene.document import Scene

FORMATS = ("bvh", "glb")


class ExportError(ValueError):
    """A scene cannot be exported (unknown format, missing character file, ...)."""


def export_scene(scene: Scene, out_dir: str | Path, *, formats: Sequence[str] = ("bvh", "glb"),
                 base_dir: str | Path | None = None, frame_time: float = 1 / 30,
                 poses: Mapping[str, Sequence[Pose]] | None = None, bvh_frame: str = "world",
                 keep_source_frames: bool = True) -> list[Path]:
    """Write every posed character of ``scene`` to ``out_dir`` as ``formats``; returns the files written.

    Args:
        scene: the scene (poses in SMPL space, see :mod:`workflows.scene`).
        out_dir: output folder (created).
        formats: any of ``"bvh"``, ``"glb"``.
        base_dir: folder that relative skeleton paths in the scene are relative to (the scene file's).
        frame_time: seconds per frame of the written animations.
        poses: optional frame sequences per character name (SMPL space) instead of its single pose.
        bvh_frame: ``"world"`` (default): a custom character's BVH in the scene's world frame (metres, y-up,
            its floor and facing), lined up with every other character and GLB of the scene; ``"source"``:
            in its file's own units and axes.
        keep_source_frames: a BVH character's own MOTION frames follow the exported ones (a scene's pose);
            False for an animation, whose frames are the whole clip.

    Raises: ExportError / SkeletonError / RigError naming the character and the problem.
    """
    formats = tuple(dict.fromkeys(str(f).strip().lower() for f in formats))
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ExportError(f"Unknown export format(s) {bad or formats}; choose from {', '.join(FORMATS)}.")
    if bvh_frame not in ("world", "source"):
        raise ExportError(f"Unknown BVH frame {bvh_frame!r}; choose 'world' or 'source'.")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    written: list[Path] = []
    for i, c in enumerate(scene.characters):
        frames = list(poses.get(c.name, ())) if poses else []
        if not frames and c.pose is not None:
            frames = [c.pose]
        if not frames:
            continue
        stem = _safe_stem(c.name, i)
        if c.skeleton is None:
            if "bvh" in formats:
                written.append(write_text_atomic(out_dir / f"{stem}.bvh", smpl_bvh_text(c, frames, frame_time)))
            if "glb" in formats:
                written.append(write_bytes_atomic(out_dir / f"{stem}.glb", smpl_glb_bytes(c, frames, frame_time)))
            continue
        path = Path(c.skeleton.path)
        if not path.is_absolute():
            path = base / path
        if not path.is_file():
            raise ExportError(f"character {c.name!r}: skeleton file {path} not found")
        char = character_from_estimate(path, c.skeleton.options, c.betas, c.scale, c.gender)
        custom = [smpl_to_custom(_with_betas(p, c), char) for p in frames]
        if "bvh" in formats:
            text = custom_bvh_text(char, custom, frame_time, keep_source_frames=keep_source_frames,
                                   frame=bvh_frame)
            written.append(write_text_atomic(out_dir / f"{stem}.bvh", text))
        if "glb" in formats:  # its own mesh, or (a BVH / joints JSON has none) its SMPL-SI body: glb_notes
            data = (posed_character_glb(char, custom, frame_time) if char.skeleton.gltf is not None
                    else fbx_character_glb(char, custom, frame_time) if char.skeleton.format == "fbx" else None)
            if data is None:
                data = smpl_glb_bytes(c, frames, frame_time)
            written.append(write_bytes_atomic(out_dir / f"{stem}.glb", data))
    return written


def export_names(scene: Scene, formats: Sequence[str], *, posed: Sequence[str] | None = None) -> list[str]:
    """The file names :func:`export_scene` writes for ``scene`` (``posed``: the names of the characters with
    frames; default those with a pose), for comparing with the command's inputs before any work."""
    formats = [f for f in dict.fromkeys(str(f).strip().lower() for f in formats) if f in FORMATS]
    names = []
    for i, c in enumerate(scene.characters):
        if (c.name in posed) if posed is not None else c.pose is not None:
            names += [f"{_safe_stem(c.name, i)}.{f}" for f in formats]
    return names


def scene_reads(scene: Scene, base_dir: str | Path | None) -> list[Path]:
    """The files a scene refers to and a command reads (its characters' skeleton files, its rig maps, its
    image), resolved against ``base_dir`` (the scene file's folder) as :func:`export_scene` resolves them."""
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    paths = [Path(c.skeleton.path) for c in scene.characters if c.skeleton is not None]
    paths += [Path(c.skeleton.map) for c in scene.characters if c.skeleton is not None and c.skeleton.map]
    if getattr(scene, "image", None):
        paths.append(Path(scene.image))
    return [p if p.is_absolute() else base / p for p in paths]


GLTF_SUFFIXES = (".glb", ".gltf", ".vrm")
"""Character files that carry their own mesh (read as glTF by :func:`shape_inversion.skeleton_io.read_character`)."""


def glb_notes(scene: Scene, formats: Sequence[str], base_dir: str | Path | None = None) -> list[str]:
    """One line per custom character whose exported GLB is its SMPL-SI body rather than its own mesh (a BVH
    or joints JSON has no mesh): what a user is told next to the ``wrote`` lines of an export. ``base_dir``: the
    scene file's folder, against which relative skeleton paths are resolved (as :func:`export_scene` does)."""
    if "glb" not in [str(f).strip().lower() for f in formats]:
        return []
    base = Path(base_dir) if base_dir is not None else Path.cwd()

    def has_skin(path: str) -> bool:  # an FBX character's GLB is its own skinned mesh when it has one
        from smplik.data.fbx import FbxError, read_fbx_mesh

        file = Path(path) if Path(path).is_absolute() else base / path
        try:
            return read_fbx_mesh(file) is not None
        except FbxError:
            return False

    return [f"{c.name}: {Path(c.skeleton.path).name} has no {'skinned ' if fbx else ''}mesh; its GLB is the SMPL "
            f"body of its SMPL-SI shape and scale, posed the same"
            for c in scene.characters
            if c.skeleton is not None and Path(c.skeleton.path).suffix.lower() not in GLTF_SUFFIXES
            for fbx in [Path(c.skeleton.path).suffix.lower() == ".fbx"]
            if not (fbx and has_skin(c.skeleton.path))]


def _safe_stem(name: str, index: int) -> str:
    stem = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name).strip("._")[:80]
    return stem or f"character_{index}"


def _with_betas(pose: Pose, c: SceneCharacter) -> Pose:
    import dataclasses

    return dataclasses.replace(pose, betas=np.asarray(c.betas, dtype=np.float64), gender=c.gender)


# ----------------------------------------------------------------------------- GLB writing


@dataclass
class _GlbData:
    """The binary chunk being written, with its buffer views and accessors (all on buffer 0)."""

    blob: bytearray
    accessors: list
    views: list

    def add(self, array: np.ndarray, component: int, kind: str, target: int | None = None,
            minmax: bool = False) -> int:
        """Append ``array`` (N, ...) as a new buffer view + accessor; returns the accessor index."""
        import pygltflib

        data = np.ascontiguousarray(array).tobytes()
        while len(self.blob) % 4:
            self.blob.append(0)
        self.views.append(pygltflib.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data),
                                               target=target))
        self.blob.extend(data)
        flat = np.asarray(array).reshape(len(array), -1)
        self.accessors.append(pygltflib.Accessor(
            bufferView=len(self.views) - 1, componentType=component, count=len(array), type=kind,
            min=[float(x) for x in flat.min(0)] if minmax else None,
            max=[float(x) for x in flat.max(0)] if minmax else None))
        return len(self.accessors) - 1

    def glb(self, gltf) -> bytes:
        """The GLB bytes of ``gltf`` with this binary chunk as its one buffer."""
        import pygltflib

        gltf.accessors, gltf.bufferViews = self.accessors, self.views
        gltf.buffers = [pygltflib.Buffer(byteLength=len(self.blob))]
        gltf.set_binary_blob(bytes(self.blob))
        return b"".join(gltf.save_to_bytes())


# ----------------------------------------------------------------------------- SMPL characters


def _smpl_rest_and_locals(c: SceneCharacter, frames: Sequence[Pose]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scaled rest joints (24, 3), local rotations (T, 24, 3, 3) and pelvis positions (T, 3), character space."""
    import torch

    from smplik.body_model import load_body_model
    from smplik.rotations import axis_angle_to_matrix

    model = load_body_model(c.gender)
    J = model.rest_joints(torch.as_tensor(np.asarray(c.betas), dtype=torch.float32)).double().numpy()
    aa = np.stack([np.concatenate([p.global_orient[None], p.body_pose]) for p in frames])
    R = axis_angle_to_matrix(torch.as_tensor(aa, dtype=torch.float64)).numpy()
    pelvis = np.stack([(J[0] + np.asarray(p.transl)) for p in frames]) * c.scale
    return J * c.scale, R, pelvis


def smpl_bvh_text(c: SceneCharacter, frames: Sequence[Pose], frame_time: float = 1 / 30) -> str:
    """BVH of an SMPL character's skeleton (metres, y-up, character space) with one frame per pose."""
    J, R, pelvis = _smpl_rest_and_locals(c, frames)
    offsets = np.array([np.zeros(3) if p < 0 else J[k] - J[p] for k, p in enumerate(PARENTS)])
    channels = [ROOT_CHANNELS if p < 0 else JOINT_CHANNELS for p in PARENTS]
    euler = matrix_to_euler_deg_np(R, "ZYX")  # (T, 24, 3)
    values = np.concatenate([pelvis, euler.reshape(len(frames), -1)], axis=1)
    return format_bvh(JOINT_NAMES, PARENTS, offsets, channels, values, frame_time)


def smpl_glb_bytes(c: SceneCharacter, frames: Sequence[Pose], frame_time: float = 1 / 30) -> bytes:
    """A skinned SMPL mesh GLB of the character (rest mesh, 24 joints), posed by the frames (animation)."""
    import torch

    from smplik.body_model import load_body_model

    model = load_body_model(c.gender)
    zero = torch.zeros(1, 3)
    with torch.no_grad():
        verts, _ = model.vertices(zero, torch.zeros(1, 23, 3), zero,
                                  torch.as_tensor(np.asarray(c.betas), dtype=torch.float32)[None])
    J, R, pelvis = _smpl_rest_and_locals(c, frames)
    weights = np.asarray(model.arrays["weights"], dtype=np.float64)
    top = np.argsort(-weights, axis=1)[:, :4]
    w = np.take_along_axis(weights, top, axis=1)
    w = w / np.maximum(w.sum(1, keepdims=True), 1e-12)
    translations = np.empty((len(frames), 24, 3))
    translations[:] = [np.zeros(3) if p < 0 else J[k] - J[p] for k, p in enumerate(PARENTS)]
    translations[:, 0] = pelvis
    return skinned_glb_bytes(verts[0].double().numpy() * c.scale, model.faces, top, w, list(JOINT_NAMES),
                             list(PARENTS), J, translations, R, frame_time)


def skinned_glb_bytes(vertices: np.ndarray, faces: np.ndarray, joints: np.ndarray, weights: np.ndarray,
                      names: Sequence[str], parents: Sequence[int], rest_positions: np.ndarray,
                      translations: np.ndarray, rotations: np.ndarray, frame_time: float,
                      clips: Sequence[tuple[str, np.ndarray, np.ndarray, float]] = ()) -> bytes:
    """A GLB with one skinned mesh and its joint nodes, posed by frame 0 and animated over all frames.

    vertices (V, 3) bind pose; faces (F, 3); joints/weights (V, 4); rest_positions (J, 3) world bind
    positions (bind rotations identity); translations (T, J, 3) node translations (parent frame);
    rotations (T, J, 3, 3) node local rotations. ``clips``: more animations ``(name, translations,
    rotations, frame_time)`` kept before the pose clip (a source file's own takes).
    """
    import pygltflib

    J = len(names)
    out = _GlbData(bytearray(), [], [])
    add = out.add

    pos = add(vertices.astype(np.float32), pygltflib.FLOAT, "VEC3", pygltflib.ARRAY_BUFFER, minmax=True)
    jnt = add(joints.astype(np.uint16), pygltflib.UNSIGNED_SHORT, "VEC4", pygltflib.ARRAY_BUFFER)
    wgt = add(weights.astype(np.float32), pygltflib.FLOAT, "VEC4", pygltflib.ARRAY_BUFFER)
    idx = add(faces.reshape(-1).astype(np.uint32), pygltflib.UNSIGNED_INT, "SCALAR", pygltflib.ELEMENT_ARRAY_BUFFER)
    ibm = np.broadcast_to(np.eye(4), (J, 4, 4)).copy()
    ibm[:, :3, 3] = -rest_positions
    ibm_acc = add(ibm.transpose(0, 2, 1).astype(np.float32), pygltflib.FLOAT, "MAT4")  # column-major
    nodes = []
    for k in range(J):
        children = [c for c in range(J) if parents[c] == k]
        nodes.append(pygltflib.Node(name=names[k], children=children or None))
    mesh_node = len(nodes)
    nodes.append(pygltflib.Node(name="body", mesh=0, skin=0))
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(generator="smplik scene export", version="2.0"),
        scenes=[pygltflib.Scene(nodes=[k for k in range(J) if parents[k] < 0] + [mesh_node])], scene=0,
        nodes=nodes,
        meshes=[pygltflib.Mesh(name="body", primitives=[pygltflib.Primitive(
            attributes=pygltflib.Attributes(POSITION=pos, JOINTS_0=jnt, WEIGHTS_0=wgt), indices=idx)])],
        skins=[pygltflib.Skin(joints=list(range(J)), inverseBindMatrices=ibm_acc, skeleton=0)],
    )
    for clip_name, clip_t, clip_R, clip_dt in clips:
        clip_q = Rotation.from_matrix(clip_R.reshape(-1, 3, 3)).as_quat().reshape(len(clip_R), J, 4)
        _animate(gltf, add, list(range(J)), clip_t, clip_q, np.ones_like(clip_t), clip_dt, name=clip_name)
    quats = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(len(rotations), J, 4)
    scales = np.ones_like(translations)
    _animate(gltf, add, list(range(J)), translations, quats, scales, frame_time)
    return out.glb(gltf)


def _world_locals(char: CustomCharacter, R_file: np.ndarray, p_file: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, K, 3, 3) world rotations and (T, K, 3) positions in file axes -> node translations (T, K, 3) and local
    rotations (T, K, 3, 3) in the scene's world frame (``C R C^T``, ``units * C p - shift``)."""
    C, s, shift = char.C_canon_file, char.units_m, char.shift
    G = C @ R_file @ C.T
    p = s * p_file @ C.T - shift
    par = np.asarray(char.parents)
    has = par >= 0
    local = G.copy()
    local[:, has] = np.swapaxes(G[:, par[has]], -1, -2) @ G[:, has]
    t = p.copy()
    t[:, has] = np.einsum("tkba,tkb->tka", G[:, par[has]], p[:, has] - p[:, par[has]])
    return t, local


def fbx_character_glb(char: CustomCharacter, poses: Sequence[CustomPose], frame_time: float = 1 / 30) -> bytes | None:
    """An FBX character's own skinned mesh (bind pose from its skin clusters), its joints named as in the file,
    posed by ``poses`` (the ``pose`` clip) with the file's take kept as a clip, in the scene's world frame.

    None when the file has no skinned mesh (an animation-only clip) or its rest pose is not the bind pose
    (``--rest frame0``): the caller writes the SMPL-SI body instead.
    """
    from smplik.data.fbx import FbxError, read_fbx_mesh

    sk = char.skeleton
    if sk.rest_rotations is not None and not np.allclose(sk.rest_rotations, np.eye(3), atol=1e-9):
        return None
    try:
        mesh = read_fbx_mesh(sk.source)
    except FbxError:
        return None
    if mesh is None:
        return None
    index = {n: k for k, n in enumerate(char.names)}
    to_char = np.zeros(len(mesh.joint_names), dtype=np.int64)  # a joint the character left out: its kept ancestor
    for j in range(len(mesh.joint_names)):
        a = j
        while a >= 0 and mesh.joint_names[a] not in index:
            a = mesh.parents[a]
        to_char[j] = index[mesh.joint_names[a]] if a >= 0 else 0
    C, s, shift = char.C_canon_file, char.units_m, char.shift
    vertices = s * mesh.vertices @ C.T - shift
    rest = s * np.asarray(sk.positions) @ C.T - shift
    Rp = np.stack([pose.positions(char)[0] for pose in poses])
    pp = np.stack([pose.positions(char)[1] for pose in poses])
    t, local = _world_locals(char, Rp, pp)
    clips = []
    motion = sk.bvh
    if motion is not None and motion.num_frames > 1 and motion.joint_names == char.names:
        take = Path(sk.source).stem + " take"
        ct, cl = _world_locals(char, motion.global_rotations, motion.positions)
        clips.append((take, ct, cl, motion.frame_time))
    return skinned_glb_bytes(vertices, mesh.faces, to_char[mesh.joints], mesh.weights, list(char.names),
                             list(char.parents), rest, t, local, frame_time, clips)


def _animate(gltf, add, node_ids: Sequence[int], translations: np.ndarray, quats: np.ndarray, scales: np.ndarray,
             frame_time: float, name: str = "pose") -> None:
    """Set the nodes' TRS to frame 0 and add one animation over all T frames (LINEAR samplers)."""
    import pygltflib

    for k, n in enumerate(node_ids):
        node = gltf.nodes[n]
        node.matrix = None
        node.translation = [float(x) for x in translations[0, k]]
        node.rotation = [float(x) for x in quats[0, k]]
        node.scale = [float(x) for x in scales[0, k]]
    T = len(translations)
    times = add((np.arange(T) * frame_time).astype(np.float32)[:, None], pygltflib.FLOAT, "SCALAR", minmax=True)
    samplers, channels = [], []
    for k, n in enumerate(node_ids):
        for path, values, kind in (("translation", translations[:, k], "VEC3"), ("rotation", quats[:, k], "VEC4"),
                                   ("scale", scales[:, k], "VEC3")):
            out = add(values.astype(np.float32), pygltflib.FLOAT, kind)
            samplers.append(pygltflib.AnimationSampler(input=times, output=out, interpolation="LINEAR"))
            channels.append(pygltflib.AnimationChannel(
                sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(node=n, path=path)))
    kept = list(gltf.animations or [])  # the source's own clips stay; the pose is one more clip
    names = {a.name for a in kept}
    base = name
    name = base if base not in names else next(f"{base}_{k}" for k in range(1, len(names) + 2)
                                               if f"{base}_{k}" not in names)
    gltf.animations = kept + [pygltflib.Animation(name=name, samplers=samplers, channels=channels)]


# ----------------------------------------------------------------------------- glTF characters


def _decompose(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(4, 4) affine without shear -> translation (3,), quaternion (x, y, z, w), scale (3,)."""
    L = M[:3, :3]
    scale = np.linalg.norm(L, axis=0)
    R = L / np.maximum(scale, 1e-300)[None, :]
    if np.linalg.det(R) < 0:
        scale[0], R[:, 0] = -scale[0], -R[:, 0]
    u, _, vt = np.linalg.svd(R)  # nearest rotation
    return M[:3, 3].copy(), Rotation.from_matrix(u @ vt).as_quat(), scale


def posed_character_glb(char: CustomCharacter, poses: Sequence[CustomPose], frame_time: float = 1 / 30) -> bytes:
    """The character's own glTF/GLB (mesh, materials, skin) with its joint nodes posed and animated over ``poses``.

    Posed joint ``k``: ``T_world_joint = [G_k A_k | p_k]`` (bind linear part ``A_k``, see
    :mod:`workflows.character_mesh`); its node's new local transform is ``T_world_parent^-1 T_world_joint``
    with the parent's posed world transform; other nodes keep theirs. All buffers are merged into
    the GLB binary chunk; images referenced by external URIs keep their URIs.
    """

    rig = char.skeleton.gltf
    if rig is None:
        raise ExportError(f"{char.skeleton.source}: not a glTF character")
    doc = rig.doc
    gltf = copy.deepcopy(doc.gltf)
    blob = bytearray()
    bases = []
    for data in doc.buffers:
        while len(blob) % 4:
            blob.append(0)
        bases.append(len(blob))
        blob.extend(data)
    for view in gltf.bufferViews or []:
        view.byteOffset = (view.byteOffset or 0) + bases[view.buffer]
        view.buffer = 0
        if view.extensions:  # meshopt views were decoded into their (fallback) buffer when read: written plain
            view.extensions = {k: v for k, v in view.extensions.items() if k not in MESHOPT_EXTENSIONS}
    gltf.extensionsUsed = [e for e in gltf.extensionsUsed or [] if e not in MESHOPT_EXTENSIONS]
    gltf.extensionsRequired = [e for e in gltf.extensionsRequired or [] if e not in MESHOPT_EXTENSIONS]
    out = _GlbData(blob, list(gltf.accessors or []), list(gltf.bufferViews or []))
    add = out.add
    n_nodes = len(doc.world)
    local = np.stack([node_local_matrix(node, f"{doc.path}: nodes[{i}]") for i, node in enumerate(doc.gltf.nodes)])
    order = _parents_first(doc.parent)
    joint_of = {n: k for k, n in enumerate(rig.joint_nodes)}
    A = rig.T_world_joint_bind[:, :3, :3]
    T, J = len(poses), len(rig.joint_nodes)
    trans, quats, scales = np.empty((T, J, 3)), np.empty((T, J, 4)), np.empty((T, J, 3))
    for t, pose in enumerate(poses):
        R, p = pose.positions(char)
        world = np.empty((n_nodes, 4, 4))
        for n in order:
            par = doc.parent[n]
            W_par = world[par] if par >= 0 else np.eye(4)
            if n in joint_of:
                k = joint_of[n]
                world[n] = np.eye(4)
                world[n][:3, :3], world[n][:3, 3] = R[k] @ A[k], p[k]
                trans[t, k], quats[t, k], scales[t, k] = _decompose(np.linalg.inv(W_par) @ world[n])
            else:
                world[n] = W_par @ local[n]
    _animate(gltf, add, list(rig.joint_nodes), trans, quats, scales, frame_time)
    _put_in_world(gltf, char)
    return out.glb(gltf)


def _put_in_world(gltf, char: CustomCharacter) -> None:
    """Parent the default scene's root nodes to one node ``smplik_world`` taking the file's frame to the scene's.

    ``p_world = units * C p_file - shift`` (:class:`~workflows.character.CustomCharacter`): every character
    of a scene then lands in the scene's one world frame (metres, y-up, the scene's floor and facing),
    so several exported GLBs line up in a 3D tool.
    """
    import pygltflib

    M = np.eye(4)
    M[:3, :3] = char.units_m * char.C_canon_file
    M[:3, 3] = -char.shift
    scenes = gltf.scenes or [pygltflib.Scene(nodes=[n for n in range(len(gltf.nodes)) if not any(
        n in (m.children or []) for m in gltf.nodes)])]
    k = gltf.scene if gltf.scene is not None else 0
    roots = list(scenes[k].nodes or [])
    gltf.nodes.append(pygltflib.Node(name="smplik_world", matrix=[float(x) for x in M.T.reshape(-1)],
                                     children=roots))
    scenes[k].nodes = [len(gltf.nodes) - 1]
    gltf.scenes, gltf.scene = scenes, k


def _parents_first(parent: Sequence[int]) -> list[int]:
    children: dict[int, list[int]] = {}
    for n, p in enumerate(parent):
        children.setdefault(p, []).append(n)
    order, stack = [], list(children.get(-1, []))
    while stack:
        n = stack.pop()
        order.append(n)
        stack.extend(children.get(n, []))
    return order
