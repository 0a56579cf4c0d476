"""The child process of :mod:`smplik.data.fbx`: parse one FBX file with ufbx and write its joint transforms.

Run as ``python -m smplik.data.fbx_worker`` with a JSON request on stdin (``path``, ``take``, ``max_joints``,
``max_frames``, ``frames``, ``max_fbx_bytes``, ``out``). Writes ``out`` (an ``.npz`` of ``rest`` (J, 4, 4) and
``world`` (T, J, 4, 4), metres, y up) and prints one JSON line (names, parents, frame rate, takes, units, axes,
where the rest pose came from), or ``{"error": ...}`` naming the problem.

ufbx 0.0.5's element wrappers are returned without a reference of their own (the scene's cache keeps a
borrowed pointer), so a wrapper dropped and fetched again is a dangling pointer: every element fetched here
gets one extra reference (:func:`_own`) and no scene is ever freed; the process exits when done.
"""

from __future__ import annotations

import ctypes
import json
import os
import sys

import numpy as np

_incref = ctypes.pythonapi.Py_IncRef
_incref.argtypes = [ctypes.py_object]
_incref.restype = None
_AXES = {0: "x", 1: "-x", 2: "y", 3: "-y", 4: "z", 5: "-z"}


def _own(element):
    """Give a ufbx element wrapper the reference its getter did not (see the module docstring)."""
    if element is not None:
        _incref(element)
    return element


def _matrix(m) -> np.ndarray:
    """ufbx ``Matrix`` (4 columns of 3) -> (4, 4) row-major acting on column vectors."""
    out = np.eye(4)
    out[:3, :4] = np.asarray(m, dtype=np.float64).reshape(4, 3).T
    return out


def _trs(translation: np.ndarray, quat_xyzw: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(..., 3), (..., 4), (..., 3) -> (..., 4, 4) ``T @ R @ S``."""
    from scipy.spatial.transform import Rotation

    shape = translation.shape[:-1]
    out = np.broadcast_to(np.eye(4), shape + (4, 4)).copy()
    q = quat_xyzw.reshape(-1, 4)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norm > 1e-12, q / np.maximum(norm, 1e-12), np.array([0.0, 0.0, 0.0, 1.0]))
    out[..., :3, :3] = Rotation.from_quat(q).as_matrix().reshape(shape + (3, 3)) * scale[..., None, :]
    out[..., :3, 3] = translation
    return out


def _compose(local: np.ndarray, parent: list[int]) -> np.ndarray:
    """(..., N, 4, 4) local transforms of every node (parents first) -> world transforms."""
    world = np.empty_like(local)
    for i, p in enumerate(parent):
        world[..., i, :, :] = local[..., i, :, :] if p < 0 else world[..., p, :, :] @ local[..., i, :, :]
    return world


def _transform_arrays(transforms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.array([list(x.translation) for x in transforms], dtype=np.float64)
    q = np.array([list(x.rotation) for x in transforms], dtype=np.float64)
    s = np.array([list(x.scale) for x in transforms], dtype=np.float64)
    return t, q, s


def run(request: dict) -> dict:
    import ufbx

    path = str(request["path"])
    with open(path, "rb") as fh:
        data = fh.read(int(request["max_fbx_bytes"]) + 1)
    try:
        scene = ufbx.load_memory(data, target_axes=ufbx.axes_right_handed_y_up, target_unit_meters=1.0,
                                 ignore_geometry=not request.get("mesh"), ignore_embedded=True,
                                 load_external_files=False,
                                 inherit_mode_handling=ufbx.InheritModeHandling.COMPENSATE, filename=path)
    except ufbx.UfbxError as exc:
        text = " ".join(str(exc).split())[:160]
        return {"error": f"{path}: not a readable FBX file ({type(exc).__name__}: {text})"}
    _own(scene)
    nodes = [_own(n) for n in scene.nodes]
    index = {n.typed_id: k for k, n in enumerate(nodes)}
    node_parent = []
    for n in nodes:
        p = _own(n.parent)
        node_parent.append(-1 if p is None else index[p.typed_id])
    if any(p >= k for k, p in enumerate(node_parent)):  # not parents first: order by depth
        return {"error": f"{path}: the FBX node tree is not listed parents first"}
    clusters = []
    for skin in [_own(s) for s in scene.skin_deformers]:
        for cluster in [_own(c) for c in skin.clusters]:
            bone = _own(cluster.bone_node)
            if bone is not None:
                clusters.append((index[bone.typed_id], _matrix(cluster.bind_to_world)))
    is_root = [bool(n.is_root) for n in nodes]
    joints = {k for k, n in enumerate(nodes) if not is_root[k] and _own(n.bone) is not None}
    joints |= {k for k, _ in clusters if not is_root[k]}
    if not joints:
        joints = {k for k, n in enumerate(nodes) if not is_root[k] and _own(n.mesh) is None
                  and _own(n.camera) is None and _own(n.light) is None}
    if not joints:
        return {"error": f"{path}: the FBX file holds no skeleton (no bone, skin cluster or empty node)"}
    if len(joints) > int(request["max_joints"]):
        return {"error": f"{path}: {len(joints)} joints, more than the limit {request['max_joints']} (raise it "
                         "with max_joints / --max-joints if this file is legitimate)"}
    order = sorted(joints)
    jindex = {k: j for j, k in enumerate(order)}
    parents = []
    for k in order:
        p = node_parent[k]
        while p >= 0 and p not in jindex:
            p = node_parent[p]
        parents.append(-1 if p < 0 else jindex[p])
    names = [nodes[k].name or f"joint{j}" for j, k in enumerate(order)]
    seen: set[str] = set()
    for j, name in enumerate(names):  # FBX allows repeated names; a joint map does not
        if name in seen:
            names[j] = f"{name}.{j}"
        seen.add(names[j])
    static_world = np.stack([_matrix(n.node_to_world) for n in nodes])
    rest = static_world[order].copy()
    bound = np.zeros(len(order), bool)
    for k, T in clusters:
        if k in jindex and not bound[jindex[k]]:
            rest[jindex[k]] = T
            bound[jindex[k]] = True
    if bound.all():
        rest_source = "bind pose (skin clusters)"
    elif bound.any():
        for j, p in enumerate(parents):  # parents first: a bound ancestor's bind transform carries the rest
            if not bound[j] and p >= 0:
                rest[j] = rest[p] @ np.linalg.inv(static_world[order[p]]) @ static_world[order[j]]
        rest_source = f"bind pose (skin clusters; {int((~bound).sum())} unbound joint(s) at their default pose)"
    else:
        rest_source = "the nodes' default transforms (no bind pose in the file)"
    takes = []
    stacks = [_own(s) for s in scene.anim_stacks]
    for stack in stacks:
        animated = sum(len(_own(layer).anim_props) for layer in stack.layers)
        takes.append({"name": stack.name, "start": float(stack.time_begin), "end": float(stack.time_end),
                      "animated": int(animated)})
    take = request.get("take")
    chosen = None
    if takes:
        if take is None:
            chosen = max(range(len(takes)), key=lambda k: (takes[k]["animated"] > 0, takes[k]["animated"],
                                                           takes[k]["end"] - takes[k]["start"]))
        elif isinstance(take, int):
            if not 0 <= take < len(takes):
                return {"error": f"{path}: take #{take} does not exist; the file has {len(takes)} take(s)"}
            chosen = take
        elif take in [t["name"] for t in takes]:
            chosen = [t["name"] for t in takes].index(take)
        else:
            return {"error": f"{path}: no take {take!r}; takes: {', '.join(repr(t['name']) for t in takes)}"}
    elif take is not None:
        return {"error": f"{path}: take {take!r} asked for, but the file has no animation take"}
    settings = scene.settings
    fps = float(settings.frames_per_second)
    if not np.isfinite(fps) or not 1.0 <= fps <= 1000.0:
        fps = 30.0
    world = static_world[order][None]
    if chosen is not None and request.get("frames", True):
        from smplik.limits import BVH_FRAMES, LimitError, check_array

        t = takes[chosen]
        span = t["end"] - t["start"]
        span = span if np.isfinite(span) and span > 0 else 0.0
        count = int(round(span * fps)) + 1
        try:
            BVH_FRAMES.check(count, f"{path}: take {t['name']!r}")
            if request.get("max_frames") is not None:
                count = min(count, max(1, int(request["max_frames"])))
            check_array((count, len(nodes), 4, 4), 8, f"{path}: {count} frames of {len(nodes)} nodes")
        except LimitError as exc:
            return {"error": str(exc)}
        anim = _own(stacks[chosen].anim)
        need = sorted({a for k in order for a in _ancestors(k, node_parent)})
        sub_parent = [need.index(node_parent[k]) if node_parent[k] >= 0 else -1 for k in need]
        trans = np.empty((count, len(need), 3))
        quats = np.empty((count, len(need), 4))
        scales = np.empty((count, len(need), 3))
        for f in range(count):
            time = t["start"] + f / fps
            trans[f], quats[f], scales[f] = _transform_arrays(
                [ufbx.evaluate_transform(anim, nodes[k], time) for k in need])
        local = _trs(trans, quats, scales)
        world = _compose(local, sub_parent)[:, [need.index(k) for k in order]]
    arrays = {"rest": rest, "world": world}
    if request.get("mesh"):
        arrays.update(_skinned_mesh(nodes, index, jindex))
    np.savez(request["out"], **arrays)
    axes = settings.axes
    up = _AXES.get(int(settings.original_axis_up), "y")
    meta = scene.metadata
    return {"names": names, "parents": parents, "fps": fps, "takes": takes,
            "take": None if chosen is None else takes[chosen]["name"],
            "unit_m": float(settings.original_unit_meters), "up": up, "rest": rest_source,
            "creator": str(meta.creator), "version": int(meta.version), "ascii": bool(meta.ascii),
            "axes": [int(axes.right), int(axes.up), int(axes.front)]}


MAX_MESH_VERTICES = 2_000_000


def _skinned_mesh(nodes: list, index: dict, jindex: dict) -> dict[str, np.ndarray]:
    """Every skinned mesh as world bind-pose triangles: ``mesh_vertices`` (V, 3) metres y up, ``mesh_faces``
    (F, 3), ``mesh_joints`` (V, 4) joint indices, ``mesh_weights`` (V, 4) (the four largest, summing to 1).
    Polygons are fanned into triangles; a mesh's bind space is its most-weighted cluster's geometry-to-world."""
    verts, faces, joints, weights = [], [], [], []
    count = 0
    for node in nodes:
        mesh = _own(node.mesh)
        if mesh is None:
            continue
        skins = [_own(k) for k in mesh.skin_deformers]
        if not skins:
            continue
        skin = skins[0]
        clusters = [_own(c) for c in skin.clusters]
        if not clusters:
            continue
        V = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        count += len(V)
        if count > MAX_MESH_VERTICES:
            break
        bind = _matrix(max(clusters, key=lambda c: c.num_weights).geometry_to_world)
        VI = np.asarray(mesh.vertex_indices, dtype=np.int64)
        tris = []
        for begin, n in (tuple(f) for f in mesh.faces):
            for k in range(1, n - 1):
                tris.append((begin, begin + k, begin + k + 1))
        if not tris:
            continue
        F = VI[np.asarray(tris, dtype=np.int64)]
        cl_joint = []
        for c in clusters:
            bone = _own(c.bone_node)
            cl_joint.append(jindex.get(index.get(bone.typed_id, -1), -1) if bone is not None else -1)
        sv = [tuple(x) for x in skin.vertices]
        sw = np.asarray([tuple(x) for x in skin.weights], dtype=np.float64).reshape(-1, 2)
        J4 = np.zeros((len(V), 4), np.int64)
        W4 = np.zeros((len(V), 4))
        for v, (begin, num, _) in enumerate(sv[:len(V)]):
            rows = sw[int(begin):int(begin) + int(num)]
            rows = rows[np.argsort(-rows[:, 1])][:4]
            for k, (c, w) in enumerate(rows):
                j = cl_joint[int(c)] if 0 <= int(c) < len(cl_joint) else -1
                if j >= 0:
                    J4[v, k], W4[v, k] = j, w
        total = W4.sum(axis=1, keepdims=True)
        W4 = np.where(total > 0, W4 / np.maximum(total, 1e-12), np.array([1.0, 0, 0, 0]))
        faces.append(F + sum(len(x) for x in verts))
        verts.append(V @ bind[:3, :3].T + bind[:3, 3])
        joints.append(J4)
        weights.append(W4)
    if not verts:
        return {}
    return {"mesh_vertices": np.concatenate(verts), "mesh_faces": np.concatenate(faces),
            "mesh_joints": np.concatenate(joints), "mesh_weights": np.concatenate(weights)}


def _ancestors(k: int, parent: list[int]) -> list[int]:
    out = []
    while k >= 0:
        out.append(k)
        k = parent[k]
    return out


def main() -> None:
    request = json.loads(sys.stdin.read())
    try:
        header = run(request)
    except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
        header = {"error": f"{request.get('path')}: cannot read the FBX file ({type(exc).__name__}: "
                           f"{str(exc)[:160]})"}
    except ImportError:
        header = {"error": "reading FBX needs the ufbx package: pip install 'smplik[fbx]' (or pip install ufbx)"}
    sys.stdout.write(json.dumps(header) + "\n")
    sys.stdout.flush()
    os._exit(0)  # no scene teardown (see the module docstring)


if __name__ == "__main__":
    main()
