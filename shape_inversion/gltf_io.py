"""Safe glTF 2.0 / GLB access: buffers, bounds-checked accessors, node world transforms, skins.

Parsing of the JSON and GLB chunks is pygltflib's (``GLTF2.load_json`` / ``GLTF2.load_binary``);
this module adds what a hostile-but-fair file needs:

* **Buffers.** The GLB binary chunk, ``data:`` base64 URIs, or external files resolved **inside
  the .gltf file's folder only** (no absolute path, no ``..``, no ``http:``/``file:`` scheme). A
  buffer shorter than its declared ``byteLength`` is refused (a GLB cut short).
* **Accessors.** Every accessor read is checked against its buffer view and buffer length
  (offset, stride, count, component size) before any byte is read; sparse accessors are refused.
* **Nodes.** World matrices compose every node's transform from the scene root
  (``T_world_node = T_world_parent @ T_parent_node``; ``matrix`` or TRS, quaternions ``(x, y, z, w)``);
  a node with two parents or a cycle is refused.

Matrices are 4x4 row-major numpy arrays acting on column vectors (glTF stores them column-major).
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from urllib.parse import unquote

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.limits import DEFAULT_MAX_JOINTS, Limit, LimitError, check_array, check_input_file

MAX_GLTF_BYTES = 512 * 1024 * 1024
"""Largest glTF/GLB file or external buffer read (bytes)."""
GLTF_NODES = Limit("nodes (glTF file)", "SMPLIK_MAX_GLTF_NODES", 100_000)
"""Most nodes of one glTF/GLB/VRM file, counted in its JSON before pygltflib parses it or any node is traversed
(real characters have a few hundred; a file of 200,000 extra nodes is refused at once)."""

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_TYPE_SIZE = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class GltfError(ValueError):
    """A glTF/GLB file is malformed, unsafe or unsupported; the message names the file and the item."""


@dataclass(frozen=True, eq=False)
class GltfFile:
    """A loaded glTF document with its buffers.

    Attributes:
        path: the file.
        gltf: the pygltflib document.
        buffers: bytes of every buffer, each at least its declared ``byteLength``.
        world: (N, 4, 4) ``T_world_node`` of every node in the default pose.
        parent: (N,) parent node index, -1 for roots.
    """

    path: Path
    gltf: object = field(repr=False)
    buffers: tuple[bytes, ...] = field(repr=False)
    world: np.ndarray = field(repr=False)
    parent: tuple[int, ...] = ()

    def accessor(self, index: int) -> np.ndarray:
        """Accessor ``index`` as an array (count, n) or (count, 4, 4) for MAT4 (row-major), bounds-checked."""
        return read_accessor(self, index)


def node_local_matrix(node, where: str = "node") -> np.ndarray:
    """``T_parent_node`` (4, 4) of a pygltflib node (``matrix`` if given, else T @ R @ S).

    ``where`` starts each error line (the file and node, ``"scene.glb: nodes[3]"``)."""
    where = f"{where} ({node.name!r})" if node.name is not None else where
    if node.matrix is not None:
        m = np.asarray(node.matrix, dtype=np.float64)
        if m.shape != (16,):
            raise GltfError(f"{where}: 'matrix' must have 16 numbers")
        return m.reshape(4, 4).T  # glTF stores column-major
    T = np.eye(4)
    if node.translation is not None:
        T[:3, 3] = np.asarray(node.translation, dtype=np.float64).reshape(3)
    if node.rotation is not None:
        q = np.asarray(node.rotation, dtype=np.float64).reshape(4)
        if not np.linalg.norm(q) > 1e-12:
            raise GltfError(f"{where}.rotation: is a zero quaternion")
        T[:3, :3] = Rotation.from_quat(q).as_matrix()  # glTF quaternions are (x, y, z, w)
    if node.scale is not None:
        T[:3, :3] = T[:3, :3] * np.asarray(node.scale, dtype=np.float64).reshape(3)[None, :]
    return T


def _buffer_bytes(path: Path, gltf, index: int) -> bytes:
    buf = gltf.buffers[index]
    uri = buf.uri
    where = f"{path}: buffers[{index}]"
    if uri in (None, ""):
        ext = getattr(buf, "extensions", None) or {}
        fallback = any(isinstance(ext.get(k), dict) and ext[k].get("fallback") for k in
                       ("EXT_meshopt_compression", "KHR_meshopt_compression"))
        if fallback and isinstance(buf.byteLength, int) and 0 <= buf.byteLength <= MAX_GLTF_BYTES:
            return bytes(buf.byteLength)  # a meshopt fallback buffer: its views are not read (the extension is
            # optional in this file, and only bufferViews without it are)
        if index != 0:
            raise GltfError(f"{where}: has no uri (only buffer 0 may be the GLB binary chunk)")
        data = gltf.binary_blob()
        if data is None:
            raise GltfError(f"{where}: no GLB binary chunk and no uri")
    elif uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        if ";base64" not in head:
            raise GltfError(f"{where}: only base64 data URIs are supported")
        try:
            data = base64.b64decode(payload, validate=True)
        except (binascii.Error, ValueError):
            raise GltfError(f"{where}: invalid base64 data URI") from None
    else:
        rel = unquote(uri)
        pure = PurePosixPath(rel.replace("\\", "/"))
        if ":" in rel or pure.is_absolute() or ".." in pure.parts or rel.startswith("/"):
            raise GltfError(f"{where}: buffer uri {uri[:80]!r} is refused: external buffers must be relative "
                            "paths inside the glTF file's folder (no absolute path, '..' or scheme)")
        folder = path.resolve().parent
        target = (folder / Path(*pure.parts)).resolve()
        if folder not in target.parents:
            raise GltfError(f"{where}: buffer uri {uri[:80]!r} leaves the glTF file's folder")
        try:
            size = check_input_file(target, "external buffer")  # a named pipe would block for ever: refused
            if size > MAX_GLTF_BYTES:
                raise GltfError(f"{where}: external buffer {target.name} is {size} bytes (limit {MAX_GLTF_BYTES})")
            data = target.read_bytes()
        except LimitError as exc:
            raise GltfError(f"{where}: {exc}") from None
        except OSError as exc:
            raise GltfError(f"{where}: cannot read external buffer {uri[:80]!r}: {exc.strerror or exc}") from None
    length = buf.byteLength
    if not isinstance(length, int) or length < 0:
        raise GltfError(f"{where}: invalid byteLength {length!r}")
    if len(data) < length:
        raise GltfError(f"{where}: holds {len(data)} bytes but declares byteLength {length} (file truncated?)")
    return bytes(data)


def _world_matrices(path: Path, gltf) -> tuple[np.ndarray, tuple[int, ...]]:
    nodes = gltf.nodes or []
    n = len(nodes)
    parent = [-1] * n
    for p, node in enumerate(nodes):
        for c in node.children or []:
            if not isinstance(c, int) or not 0 <= c < n:
                raise GltfError(f"{path}: nodes[{p}].children holds an invalid node index {c!r}")
            if parent[c] != -1 or c == p:
                raise GltfError(f"{path}: node {c} has several parents (the node graph must be a tree)")
            parent[c] = p
    local = np.stack([node_local_matrix(node, f"{path}: nodes[{i}]") for i, node in enumerate(nodes)]) if n \
        else np.zeros((0, 4, 4))
    if not np.isfinite(local).all():
        raise GltfError(f"{path}: a node transform holds a non-finite value")
    world = np.full((n, 4, 4), np.nan)
    roots = [i for i in range(n) if parent[i] < 0]
    stack = list(roots)
    done = 0
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below, naming the node
        while stack:  # iterative: deep node chains need no recursion
            i = stack.pop()
            world[i] = local[i] if parent[i] < 0 else world[parent[i]] @ local[i]
            done += 1
            stack.extend(nodes[i].children or [])
    if done != n:
        raise GltfError(f"{path}: the node graph has a cycle")
    bad = np.flatnonzero(~np.isfinite(world).all(axis=(1, 2)) | (np.abs(world) > MAX_TRANSFORM).any(axis=(1, 2)))
    if len(bad):  # finite factors can compose to inf (a root matrix 1e200 times a scale 1e200)
        k = int(bad[0])
        raise GltfError(f"{path}: node {k} ({nodes[k].name or 'unnamed'!r}): its world transform (the product of "
                        f"its ancestors' transforms) is not finite or beyond {MAX_TRANSFORM:g}")
    return world, tuple(parent)


MAX_TRANSFORM = 1e12
"""Largest magnitude of a composed node world matrix entry (metres or scale factors; larger is not a character)."""


def _nonfinite_key(node: object, where: str = "") -> str | None:
    """The JSON path (``accessors[0].count``) of the first non-finite number in ``node``, else None."""
    if isinstance(node, float) and not np.isfinite(node):
        return where or "the top level"
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        found = _nonfinite_key(value, f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}".lstrip("."))
        if found:
            return found
    return None


def _check_json_numbers(path: Path, binary: bool, max_joints: int = DEFAULT_MAX_JOINTS) -> None:
    """Refuse a glTF whose JSON holds ``Infinity``, ``NaN`` or a number beyond float range (not JSON; Python's
    parser and pygltflib take them and fail later with an ``OverflowError``), naming the key; and one with more
    nodes than :data:`GLTF_NODES` or a skin of more than ``max_joints`` joints, before anything is parsed or
    traversed."""
    data = path.read_bytes()
    if binary:
        if len(data) < 20 or data[16:20] != b"JSON":
            return  # pygltflib names the broken header
        data = data[20:20 + struct.unpack_from("<I", data, 12)[0]]
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError):
        return  # pygltflib names the problem
    if not isinstance(doc, dict):
        return  # pygltflib names the problem
    nodes, skins = doc.get("nodes"), doc.get("skins")
    if isinstance(nodes, list):
        try:
            GLTF_NODES.check(len(nodes), f"{path}: nodes")
        except LimitError as exc:
            raise GltfError(str(exc)) from None
    for i, skin in enumerate(skins if isinstance(skins, list) else []):
        joints = skin.get("joints") if isinstance(skin, dict) else None
        if isinstance(joints, list) and len(joints) > max_joints:
            raise GltfError(f"{path}: skins[{i}] has {len(joints)} joints, more than the limit {max_joints} (raise "
                            "it with --max-joints if this file is legitimate)")
    key = _nonfinite_key(doc)
    if key is not None:
        raise GltfError(f"{path}: '{key}' holds a non-finite number (Infinity, NaN or beyond float range)")


def _is_index(value: object, low: int = 0, high: float = float("inf")) -> bool:
    """``value`` is a JSON integer (not a bool, not a float) in [low, high]."""
    return type(value) is int and low <= value <= high


def _check_buffer_views(path: Path, gltf, buffers: tuple[bytes, ...]) -> None:
    """Every bufferView names a loaded buffer and lies inside it (glTF 2.0 §5.11: ``buffer`` and ``byteLength``
    are required integers), so that every command reading the file (SMPL-SI, the mesh, scene export) agrees."""
    for i, view in enumerate(gltf.bufferViews or []):
        where = f"{path}: bufferViews[{i}]"
        if not _is_index(view.buffer, 0, len(buffers) - 1):
            raise GltfError(f"{where}: 'buffer' must be the index of one of its {len(buffers)} buffers, got "
                            f"{view.buffer!r:.40}")
        offset = 0 if view.byteOffset is None else view.byteOffset
        if not _is_index(offset) or not _is_index(view.byteLength, 1):
            raise GltfError(f"{where}: 'byteOffset'/'byteLength' must be integers (byteLength >= 1), got "
                            f"{view.byteOffset!r:.40}/{view.byteLength!r:.40}")
        if offset + view.byteLength > len(buffers[view.buffer]):
            raise GltfError(f"{where}: bytes {offset}..{offset + view.byteLength} lie outside buffer {view.buffer} "
                            f"({len(buffers[view.buffer])} bytes)")
        if view.byteStride is not None and not _is_index(view.byteStride, 4, 252):
            raise GltfError(f"{where}: 'byteStride' must be an integer in [4, 252], got {view.byteStride!r:.40}")


MESHOPT_EXTENSIONS = ("EXT_meshopt_compression", "KHR_meshopt_compression")
MAX_MESHOPT_BYTES = MAX_GLTF_BYTES
"""Most bytes all meshopt-compressed bufferViews of one file may decode to (each view's ``count * byteStride``)."""


def _decode_meshopt_views(path: Path, gltf, buffers: tuple[bytes, ...]) -> tuple[bytes, ...]:
    """``buffers`` with every bufferView that carries ``EXT_meshopt_compression`` / ``KHR_meshopt_compression``
    decoded into its place (``bufferView.buffer`` at ``bufferView.byteOffset``; the fallback buffer without a uri
    starts as zeros), so that every accessor read afterwards sees the uncompressed bytes
    (:mod:`shape_inversion.meshopt_codec`)."""
    from shape_inversion.meshopt_codec import MeshoptError, decode_gltf_buffer

    out: dict[int, bytearray] = {}
    total = 0
    for i, view in enumerate(gltf.bufferViews or []):
        ext = getattr(view, "extensions", None) or {}
        name = next((k for k in MESHOPT_EXTENSIONS if k in ext), None)
        if name is None:
            continue
        where = f"{path}: bufferViews[{i}].extensions.{name}"
        spec = ext[name]
        if not isinstance(spec, dict):
            raise GltfError(f"{where}: must be an object")
        src, count, stride = spec.get("buffer"), spec.get("count"), spec.get("byteStride")
        offset, length = spec.get("byteOffset", 0), spec.get("byteLength")
        if not _is_index(src, 0, len(buffers) - 1):
            raise GltfError(f"{where}: 'buffer' must be the index of one of its {len(buffers)} buffers, got "
                            f"{src!r:.40}")
        if not (_is_index(offset) and _is_index(length, 1) and _is_index(count) and _is_index(stride, 1, 256)):
            raise GltfError(f"{where}: 'byteOffset', 'byteLength', 'count' and 'byteStride' must be integers "
                            "(byteLength >= 1, byteStride 1..256)")
        if offset + length > len(buffers[src]):
            raise GltfError(f"{where}: compressed bytes {offset}..{offset + length} lie outside buffer {src} "
                            f"({len(buffers[src])} bytes)")
        size = count * stride
        if size > view.byteLength:
            raise GltfError(f"{where}: count {count} x byteStride {stride} = {size} bytes do not fit the bufferView's "
                            f"byteLength {view.byteLength}")
        total += size
        if total > MAX_MESHOPT_BYTES:
            raise GltfError(f"{where}: the compressed views decode to more than {MAX_MESHOPT_BYTES} bytes")
        try:
            data = decode_gltf_buffer(buffers[src][offset:offset + length], count, stride, spec.get("mode"),
                                      spec.get("filter", "NONE"))
        except MeshoptError as exc:
            raise GltfError(f"{where}: {exc}") from None
        target = out.setdefault(view.buffer, bytearray(buffers[view.buffer]))
        start = view.byteOffset or 0
        target[start:start + size] = data
    if not out:
        return buffers
    return tuple(bytes(out[i]) if i in out else b for i, b in enumerate(buffers))


READ_EXTENSIONS = frozenset({
    *MESHOPT_EXTENSIONS,  # decoded here (meshopt_codec)
    "KHR_draco_mesh_compression",  # decoded with DracoPy (draco_primitive)
    "KHR_mesh_quantization",  # integer / normalized accessors: read_accessor
    "KHR_texture_basisu", "EXT_texture_webp", "EXT_texture_avif", "KHR_texture_transform",  # textures: not read
    "KHR_materials_unlit", "KHR_materials_emissive_strength", "KHR_materials_clearcoat", "KHR_materials_ior",
    "KHR_materials_specular", "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_sheen",
    "KHR_materials_iridescence", "KHR_materials_anisotropy", "KHR_materials_dispersion",
    "KHR_materials_pbrSpecularGlossiness", "KHR_materials_variants", "KHR_lights_punctual", "KHR_xmp_json_ld",
    "KHR_materials_diffuse_transmission", "KHR_node_visibility", "EXT_lights_image_based",
    "KHR_animation_pointer", "EXT_mesh_gpu_instancing", "VRM", "VRMC_vrm", "VRMC_springBone",
    "VRMC_materials_mtoon", "VRMC_node_constraint",
})
"""glTF extensions a file may *require* (``extensionsRequired``) and still be read: geometry ones decoded here,
material, texture and light ones because no material, texture or light is read."""

_HOW_TO_DECOMPRESS: dict[str, str] = {}
"""A hint per unreadable extension (none at present: every ratified one is in :data:`READ_EXTENSIONS`)."""


def _check_required_extensions(path: Path, gltf) -> None:
    """Refuse, in one line naming it, a file that requires an extension smplik cannot read (glTF 2.0 §3.12:
    a loader must not load a file whose ``extensionsRequired`` it does not support)."""
    required = gltf.extensionsRequired or []
    if not isinstance(required, list):
        raise GltfError(f"{path}: 'extensionsRequired' must be a list of extension names")
    for name in required:
        if name not in READ_EXTENSIONS:
            how = _HOW_TO_DECOMPRESS.get(str(name), "export the file without it")
            raise GltfError(f"{path}: requires the glTF extension {str(name)[:60]}, which smplik cannot read; "
                            f"{how}")


def load_gltf(path: str | Path, *, max_joints: int = DEFAULT_MAX_JOINTS) -> GltfFile:
    """Load a ``.gltf`` (JSON, external or data-URI buffers) or ``.glb`` file; raises :class:`GltfError`.

    Its node count (:data:`GLTF_NODES`) and every skin's joint count (``max_joints``) are checked in the JSON
    before pygltflib parses it."""
    import pygltflib

    path = Path(path)
    try:
        size = check_input_file(path, "glTF file")  # through links: z.glb -> /dev/zero is a device, refused
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except LimitError as exc:
        raise GltfError(str(exc)) from None
    except OSError as exc:
        raise GltfError(f"Cannot read glTF file {path}: {exc.strerror or exc}") from None
    if size > MAX_GLTF_BYTES:
        raise GltfError(f"{path}: {size} bytes exceeds the glTF size limit {MAX_GLTF_BYTES}")
    _check_json_numbers(path, magic == b"glTF", max_joints)
    try:
        gltf = pygltflib.GLTF2.load_binary(path) if magic == b"glTF" else pygltflib.GLTF2.load_json(path)
    except (ValueError, KeyError, TypeError, AttributeError, IndexError, OverflowError, struct.error,
            UnicodeDecodeError, json.JSONDecodeError, RecursionError, OSError) as exc:  # pygltflib's failure types
        raise GltfError(f"Cannot read glTF file {path}: {type(exc).__name__}: {str(exc)[:120]}") from None
    if gltf is None:
        raise GltfError(f"Cannot read glTF file {path}: not a glTF document")
    _check_required_extensions(path, gltf)
    buffers = tuple(_buffer_bytes(path, gltf, i) for i in range(len(gltf.buffers or [])))
    _check_buffer_views(path, gltf, buffers)
    buffers = _decode_meshopt_views(path, gltf, buffers)
    try:
        world, parent = _world_matrices(path, gltf)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, GltfError):
            raise
        raise GltfError(f"{path}: invalid node transform ({exc})") from None
    return GltfFile(path, gltf, buffers, world, parent)


def read_accessor(doc: GltfFile, index: int) -> np.ndarray:
    """Accessor ``index`` of ``doc`` as float64/int array (count, n), MAT4 as (count, 4, 4) row-major."""
    gltf, where = doc.gltf, f"{doc.path}: accessors[{index}]"
    if not isinstance(index, int) or not 0 <= index < len(gltf.accessors or []):
        raise GltfError(f"{doc.path}: accessor index {index!r} out of range")
    acc = gltf.accessors[index]
    if acc.sparse is not None:
        raise GltfError(f"{where}: sparse accessors are not supported")
    dtype = _COMPONENTS.get(acc.componentType)
    ncomp = _TYPE_SIZE.get(acc.type)
    if dtype is None or ncomp is None:
        raise GltfError(f"{where}: unsupported componentType {acc.componentType!r} / type {acc.type!r}")
    count = acc.count
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise GltfError(f"{where}: invalid count {count!r}")
    try:  # the float64 array this accessor becomes, before anything is allocated (a count of 5e7 MAT4s: 6.4 GB)
        check_array((count, ncomp), 8, f"{where} ({acc.type} x {count})")
    except LimitError as exc:
        raise GltfError(str(exc)) from None
    if acc.bufferView is None:
        out = np.zeros((count, ncomp))
    else:
        if not 0 <= acc.bufferView < len(gltf.bufferViews or []):
            raise GltfError(f"{where}: bufferView {acc.bufferView!r} out of range")
        view = gltf.bufferViews[acc.bufferView]
        if not 0 <= view.buffer < len(doc.buffers):
            raise GltfError(f"{where}: buffer {view.buffer!r} out of range")
        data = doc.buffers[view.buffer]
        item = np.dtype(dtype).itemsize * ncomp
        stride = view.byteStride or item
        v_off, a_off = view.byteOffset or 0, acc.byteOffset or 0
        if stride < item or v_off < 0 or a_off < 0 or view.byteLength is None or view.byteLength < 0:
            raise GltfError(f"{where}: invalid byteStride/byteOffset/byteLength in bufferView {acc.bufferView}")
        need = a_off + (stride * (count - 1) + item if count else 0)
        if need > view.byteLength or v_off + view.byteLength > len(data):
            raise GltfError(f"{where}: needs {need} bytes of bufferView {acc.bufferView} (byteLength "
                            f"{view.byteLength}, buffer {len(data)} bytes): reads past the end of its buffer")
        raw = np.frombuffer(data, dtype=np.uint8, count=view.byteLength, offset=v_off)[a_off:]
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, item), strides=(stride, 1)) if count else \
            np.zeros((0, item), dtype=np.uint8)
        out = np.ascontiguousarray(rows).view(dtype).reshape(count, ncomp)
        if acc.normalized and dtype != np.float32:
            out = np.maximum(out / np.iinfo(dtype).max, -1.0)
    out = out.astype(np.float64) if np.dtype(out.dtype).kind == "f" or acc.normalized else out.astype(np.int64)
    if out.dtype.kind == "f" and not np.isfinite(out).all():
        raise GltfError(f"{where}: holds non-finite values")
    if acc.type == "MAT4":
        return out.reshape(count, 4, 4).transpose(0, 2, 1)  # column-major -> row-major
    return out


@dataclass(frozen=True, eq=False)
class GltfRig:
    """One skin of a glTF file: its joints and bind pose in world space.

    Attributes:
        doc: the loaded file.
        skin: skin index.
        joint_nodes: (J,) node index of every joint, parents before children.
        skin_order: (J,) index of each joint in the skin's ``joints`` list (what ``JOINTS_0`` refers to).
        inverse_bind: (J, 4, 4) inverse bind matrices (identity when absent).
        bind_to_world: (4, 4) ``T_world_bind``: bind space (where the mesh vertices and
            ``inv(inverse_bind)`` live) to world (see :func:`read_rig`).
        T_world_joint_bind: (J, 4, 4) the bind pose in world space.
    """

    doc: GltfFile
    skin: int
    joint_nodes: tuple[int, ...]
    skin_order: tuple[int, ...]
    inverse_bind: np.ndarray = field(repr=False)
    bind_to_world: np.ndarray = field(repr=False)
    T_world_joint_bind: np.ndarray = field(repr=False)


MAX_BIND_CANDIDATES = 64
"""Most ancestor frames of the root joint tried as the bind space (:func:`read_rig`); a chain of 100,000 nodes
above the skeleton costs no more than 64."""


def read_rig(doc: GltfFile, skin: int = 0, bind: str = "inverse_bind") -> GltfRig:
    """The skin's joints and bind pose.

    ``bind="inverse_bind"``: ``T_world_joint = T_world_bind @ inv(IBM_joint)``, where ``T_world_bind`` is
    the identity when the IBMs are in world space (Blender's exporter folds the armature's scale and the
    root nodes into them) or the world transform of an ancestor node of the root joint when they are
    relative to it (an armature scaled 0.01 or a z-up root node left out), the skinned mesh node's world
    transform (three.js binds there), or such an ancestor's frame without its uniform scale (an armature
    scaled after binding): among those whose bone lengths match the nodes' (bone lengths do not change
    with the pose), whichever puts the joints nearest their nodes' default world positions.
    ``bind="nodes"``: the joint nodes' world matrices in the default pose.
    """
    gltf = doc.gltf
    skins = gltf.skins or []
    if not 0 <= skin < len(skins):
        raise GltfError(f"{doc.path}: no skin #{skin} (the file has {len(skins)} skins)")
    joints = tuple(skins[skin].joints or [])
    if not joints:
        raise GltfError(f"{doc.path}: skin #{skin} has no joints")
    if any(not isinstance(j, int) or not 0 <= j < len(doc.world) for j in joints) or len(set(joints)) != len(joints):
        raise GltfError(f"{doc.path}: skin #{skin} names invalid or repeated joint nodes")
    J = len(joints)
    if skins[skin].inverseBindMatrices is not None:
        ibm = read_accessor(doc, skins[skin].inverseBindMatrices)
        if ibm.shape != (J, 4, 4):
            raise GltfError(f"{doc.path}: skin #{skin}: {ibm.shape[0]} inverse bind matrices for {J} joints")
    else:
        ibm = np.broadcast_to(np.eye(4), (J, 4, 4)).copy()
    index = {n: k for k, n in enumerate(joints)}
    depth = _depths(doc.parent, joints, index)  # parents first: sort by the number of joint ancestors (stable)
    order = tuple(sorted(range(J), key=lambda k: depth[k]))
    joints, ibm = tuple(joints[k] for k in order), ibm[list(order)]
    root = 0
    if bind != "nodes":
        try:
            inv = np.linalg.inv(ibm)
        except np.linalg.LinAlgError:
            import warnings

            warnings.warn(f"{doc.path}: skin #{skin} has a singular inverse bind matrix (gltfpack writes all-zero ones "
                          "for a skin without a mesh): the joints' default pose is used as the bind pose", stacklevel=2)
            bind = "nodes"
    if bind == "nodes":
        T_bind = doc.world[list(joints)].copy()
        to_world = np.eye(4)
    else:
        parent_world = doc.world[doc.parent[joints[root]]] if doc.parent[joints[root]] >= 0 else np.eye(4)
        node_p = doc.world[list(joints), :3, 3]

        def mismatch(B: np.ndarray) -> float:
            return float(np.median(np.linalg.norm((B @ inv)[:, :3, 3] - node_p, axis=-1)))

        # IBMs in world space (Blender), relative to the skinned mesh's node (three.js binds the skeleton at the
        # mesh's world transform) or to an ancestor of the skeleton root (the armature, a scale 0.01 node, a z-up
        # root node left out): each of these world transforms is a candidate
        meshes = [doc.world[i] for i, node in enumerate(gltf.nodes or []) if node.skin == skin]
        candidates = [np.eye(4), *meshes[:1], parent_world]
        a = doc.parent[joints[root]]
        while a >= 0 and len(candidates) < MAX_BIND_CANDIDATES:  # the nearest ancestors (real files: a few)
            candidates.append(doc.world[a])
            a = doc.parent[a]
        # an ancestor scaled after binding (an armature scaled 0.01 whose bones were then written in cm, the
        # IBMs left in the bind-time metres): the same ancestor frame without its uniform scale
        for B in candidates[1:]:
            scale = abs(float(np.linalg.det(B[:3, :3]))) ** (1 / 3)
            if scale > 0 and abs(scale - 1) > 1e-6:
                unscaled = B.copy()
                unscaled[:3, :3] /= scale
                candidates.append(unscaled)
        # bone lengths do not change with the pose: a candidate must give the nodes' size (the default pose of
        # an animated file is not the bind pose, so positions alone may favour a collapsed skeleton)
        index = {n: k for k, n in enumerate(joints)}
        par = [_joint_parent(doc, n, index) for n in joints]
        bones = [k for k in range(J) if par[k] >= 0]

        def size_ratio(B: np.ndarray) -> float:
            P = (B @ inv)[:, :3, 3]
            lengths = np.array([[np.linalg.norm(P[k] - P[par[k]]), np.linalg.norm(node_p[k] - node_p[par[k]])]
                                for k in bones]).reshape(-1, 2)
            ok = (lengths > 1e-9).all(axis=1)
            return float(np.median(lengths[ok, 0] / lengths[ok, 1])) if ok.any() else 1.0

        sized = [B for B in candidates if abs(np.log(max(size_ratio(B), 1e-12))) < np.log(1.5)]
        if "KHR_mesh_quantization" in (gltf.extensionsUsed or []) and bones:
            # gltfpack / glTF-Transform fold the mesh's dequantization into the IBMs: the same frames with it undone
            # (only where the bone lengths say the IBMs are scaled; a file quantized elsewhere keeps its frames)
            dequantized = [B @ D for B in candidates[:3]
                           if (D := _dequantization(B, inv[:, :3, 3], node_p, par, bones)) is not None
                           and abs(np.log(D[0, 0])) > 1e-3]
            sized = [*dequantized, *sized] if dequantized else sized
        to_world = min(sized or candidates, key=mismatch)
        T_bind = to_world @ inv
    return GltfRig(doc, skin, joints, order, ibm, to_world, T_bind)


def _dequantization(B: np.ndarray, Q: np.ndarray, node_p: np.ndarray, par: list[int],
                    bones: list[int]) -> np.ndarray | None:
    """The dequantization transform ``D`` (4, 4), a uniform scale ``s`` and a translation ``t``, that gltfpack and
    glTF-Transform fold into a quantized skin's inverse bind matrices (``IBM' = IBM @ inv(D)``: the mesh's integer
    positions then need no node transform, which glTF ignores on a skinned mesh), so that ``B @ D @ inv(IBM')`` is
    the bind pose again. ``Q`` (J, 3): joint positions ``inv(IBM')`` in the quantized space; ``node_p`` (J, 3): the
    joints' default world positions. ``s`` is the median ratio of bone lengths (the pose does not change them),
    ``t`` the median offset; None when degenerate."""
    try:
        Y = (np.linalg.inv(B[:3, :3]) @ (node_p - B[:3, 3]).T).T  # node positions in B's frame
    except np.linalg.LinAlgError:
        return None
    lq = np.array([np.linalg.norm(Q[k] - Q[par[k]]) for k in bones])
    ly = np.array([np.linalg.norm(Y[k] - Y[par[k]]) for k in bones])
    ok = (lq > 1e-12) & (ly > 1e-12)
    if not ok.any():
        return None
    scale = float(np.median(ly[ok] / lq[ok]))
    D = np.eye(4)
    D[:3, :3] *= scale
    D[:3, 3] = np.median(Y - scale * Q, axis=0)
    return D if np.isfinite(D).all() and scale > 0 else None


def _depths(parent: tuple[int, ...], members: tuple[int, ...] | list[int], index: dict[int, int]) -> list[int]:
    """The number of strict ancestors of each of ``members`` (node indices) that are members too (``index``: the
    members as keys); linear time (each node's count is computed once), so a deep chain costs O(n), not O(n^2)."""
    memo: dict[int, int] = {}
    out = []
    for n in members:
        chain, x = [], n
        while x >= 0 and x not in memo:
            chain.append(x)
            x = parent[x]
        for q in reversed(chain):
            p = parent[q]
            memo[q] = 0 if p < 0 else memo[p] + (1 if p in index else 0)
        out.append(memo[n])
    return out


def read_node_rig(doc: GltfFile, node: int, *, max_joints: int = DEFAULT_MAX_JOINTS) -> GltfRig:
    """A skeleton of plain nodes (no skin): the whole hierarchy holding ``node``, in its default pose.

    For a humanoid defined on nodes only (a VRM whose humanoid table names unskinned nodes).
    ``skin`` is -1; the bind pose is the nodes' world transforms. More than ``max_joints`` nodes are refused
    as soon as they are counted.
    """
    top = node
    while doc.parent[top] >= 0:
        top = doc.parent[top]
    members, stack = [], [top]
    while stack:
        n = stack.pop()
        members.append(n)
        if len(members) > max_joints:
            raise GltfError(f"{doc.path}: the node hierarchy of node {node} has more than {max_joints} nodes (the "
                            "joint limit; raise it with --max-joints if this file is legitimate)")
        stack.extend(doc.gltf.nodes[n].children or [])
    index = {n: k for k, n in enumerate(members)}
    depth = dict(zip(members, _depths(doc.parent, members, index), strict=True))
    joints = tuple(sorted(members, key=lambda n: (depth[n], n)))
    world = doc.world[list(joints)].copy()
    return GltfRig(doc, -1, joints, tuple(range(len(joints))), np.linalg.inv(world), np.eye(4), world)


def _joint_parent(doc: GltfFile, node: int, index: dict[int, int]) -> int:
    """Index (into the skin's joints) of the nearest ancestor that is a joint, -1 if none."""
    p = doc.parent[node]
    while p >= 0 and p not in index:
        p = doc.parent[p]
    return -1 if p < 0 else index[p]


def joint_parents(rig: GltfRig) -> tuple[int, ...]:
    """(J,) parent joint index of every joint of ``rig`` (nearest joint ancestor), -1 for roots."""
    index = {n: k for k, n in enumerate(rig.joint_nodes)}
    return tuple(_joint_parent(rig.doc, n, index) for n in rig.joint_nodes)


DRACO_EXTENSION = "KHR_draco_mesh_compression"


class DracoUnavailableError(GltfError):
    """A primitive is Draco-compressed and no Draco decoder (DracoPy) is installed."""


class _Reader:
    """Little-endian reads from a Draco buffer; running past its end raises :class:`GltfError`."""

    def __init__(self, data: bytes, where: str) -> None:
        self.data, self.pos, self.where = data, 0, where

    def take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise GltfError(f"{self.where}: the Draco header is cut short")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def u8(self) -> int:
        return self.take(1)[0]

    def varint(self) -> int:
        value = 0
        for shift in range(0, 35, 7):  # a varUI32: at most 5 bytes
            byte = self.u8()
            value |= (byte & 0x7F) << shift
            if not byte & 0x80:
                return value
        raise GltfError(f"{self.where}: invalid variable-length number in the Draco header")


def _skip_draco_metadata(r: _Reader, depth: int = 0) -> None:
    """Skip one Draco metadata element (entries, then nested elements)."""
    if depth > 32:
        raise GltfError(f"{r.where}: Draco metadata nested too deeply")
    for _ in range(r.varint()):
        r.take(r.u8())  # name
        r.take(r.u8())  # value
    for _ in range(r.varint()):
        r.take(r.u8())  # sub-element name
        _skip_draco_metadata(r, depth + 1)


def draco_declared_counts(data: bytes, where: str) -> tuple[int, int]:
    """``(points, faces)`` a Draco buffer declares, read from its header before anything is decoded (faces 0 for a
    point cloud).

    Layout (google/draco ``docs/spec``: ``ParseHeader``, ``DecodeMetadata``, and the connectivity header of the
    sequential, edgebreaker and point-cloud decoders): ``"DRACO"``, major and minor version, encoder type
    (0 point cloud, 1 triangle mesh), method (0 sequential, 1 edgebreaker / kd-tree), flags (UI16; 0x8000:
    metadata follows); a point cloud then stores its point count as an int32; a mesh (bitstream 2.2) its
    ``num_faces, num_points`` (sequential) or, after a UI8 traversal type, ``num_encoded_vertices, num_faces``
    (edgebreaker) as varUI32. Older mesh bitstreams (before 2.2) are refused (no glTF exporter writes them)."""
    r = _Reader(data, where)
    if r.take(5) != b"DRACO":
        raise GltfError(f"{where}: not a Draco buffer (no 'DRACO' header)")
    major, minor, kind, method = r.u8(), r.u8(), r.u8(), r.u8()
    flags = int.from_bytes(r.take(2), "little")
    if flags & 0x8000:
        for _ in range(r.varint()):  # attribute metadata: id, element
            r.varint()
            _skip_draco_metadata(r)
        _skip_draco_metadata(r)  # the file's metadata
    if kind == 0:
        points = int.from_bytes(r.take(4), "little", signed=True)
        if points < 0:
            raise GltfError(f"{where}: the Draco point cloud declares {points} points")
        return points, 0
    if kind != 1 or (major, minor) < (2, 2) or major > 2:
        raise GltfError(f"{where}: unsupported Draco bitstream (version {major}.{minor}, encoder type {kind})")
    if method == 0:
        faces, points = r.varint(), r.varint()
    else:
        r.u8()  # traversal type
        points, faces = r.varint(), r.varint()
    return points, faces


def draco_primitive(doc: GltfFile, prim, *, max_vertices: int = 2_000_000) -> tuple[dict[str, np.ndarray],
                                                                                     np.ndarray] | None:
    """The decoded vertex attributes and triangles (F, 3) of a Draco-compressed primitive, else None.

    ``KHR_draco_mesh_compression`` (the Khronos extension): the primitive's ``extensions`` name a bufferView
    holding one Draco mesh and the Draco unique id of each attribute (``POSITION``, ``JOINTS_0``,
    ``WEIGHTS_0``...); the accessors keep only counts and types. Decoded with DracoPy
    (``pip install 'smplik[draco]'``); attributes are float64 (normalized integers as in glTF) or int64.

    The vertex and triangle counts the buffer declares are checked against ``max_vertices`` before it is
    decoded (:func:`draco_declared_counts`).

    Raises: DracoUnavailableError without DracoPy; GltfError on a malformed extension or Draco buffer.
    """
    ext = (getattr(prim, "extensions", None) or {}).get(DRACO_EXTENSION)
    if ext is None:
        return None
    where = f"{doc.path}: {DRACO_EXTENSION}"
    if not isinstance(ext, dict) or not isinstance(ext.get("bufferView"), int) \
            or not isinstance(ext.get("attributes"), dict):
        raise GltfError(f"{where}: needs an integer bufferView and an attributes object")
    try:
        import DracoPy
    except ImportError:
        raise DracoUnavailableError(f"{doc.path}: the mesh is Draco-compressed ({DRACO_EXTENSION}) and DracoPy is "
                                    "not installed (pip install -e '.[draco]' in the smplik checkout, or "
                                    "pip install DracoPy)") from None
    gltf = doc.gltf
    index = ext["bufferView"]
    if not 0 <= index < len(gltf.bufferViews or []):
        raise GltfError(f"{where}: bufferView {index!r} out of range")
    view = gltf.bufferViews[index]
    if not 0 <= view.buffer < len(doc.buffers):
        raise GltfError(f"{where}: buffer {view.buffer!r} out of range")
    start, length = view.byteOffset or 0, view.byteLength or 0
    data = doc.buffers[view.buffer]
    if start < 0 or length <= 0 or start + length > len(data):
        raise GltfError(f"{where}: bufferView {index} reads past the end of its buffer")
    buffer = bytes(data[start:start + length])
    points, faces = draco_declared_counts(buffer, where)
    if points > max_vertices or faces > 3 * max_vertices:  # before the decoder allocates them
        raise GltfError(f"{where}: the Draco buffer declares {points} vertices and {faces} triangles; at most "
                        f"{max_vertices} vertices (and {3 * max_vertices} triangles) are read")
    try:
        mesh = DracoPy.decode(buffer)
    except Exception as exc:  # DracoPy raises its own error types for corrupt buffers
        raise GltfError(f"{where}: cannot decode the Draco buffer ({type(exc).__name__})") from None
    by_id = {a["unique_id"]: np.asarray(a["data"]) for a in getattr(mesh, "attributes", []) or []}
    out: dict[str, np.ndarray] = {}
    for name, uid in ext["attributes"].items():
        values = by_id.get(uid)
        if values is None and name == "POSITION":
            values = np.asarray(mesh.points)
        if values is None:
            continue
        values = values.reshape(len(values), -1)
        accessor = getattr(prim.attributes, name, None)
        acc = gltf.accessors[accessor] if isinstance(accessor, int) and 0 <= accessor < len(gltf.accessors or []) \
            else None
        if acc is not None and acc.normalized and values.dtype.kind in "iu":
            values = values / np.iinfo(values.dtype).max
        out[name] = values.astype(np.float64) if values.dtype.kind == "f" or name.startswith("WEIGHTS") \
            else values.astype(np.int64)
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    return out, faces
