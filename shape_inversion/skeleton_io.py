"""Custom-character skeletons: read BVH, glTF/GLB and named-joint JSON, then map them to SMPL.

Reading gives a :class:`Skeleton` (joint names, parents, rest positions in file units and axes).
:func:`prepare_character` maps it to SMPL's joints through a :class:`~shape_inversion.rigs.RigMap`,
converts it to metres and puts it in smplik's frame: **y-up, the character's left at +x, facing
+z**, hips' midpoint above the origin and the lowest joint at y = 0 (see :mod:`smplik.conventions`).

* **BVH** (:func:`read_bvh`): the rest pose is frame 0 through forward kinematics (``rest="frame0"``;
  CMU files carry a rest pose there) or the zero-rotation OFFSETs (``rest="offsets"``). Rotation
  channels compose in the order they are listed (``Zrotation Yrotation Xrotation`` -> Rz Ry Rx,
  degrees). Position channels of a non-root joint are **added** to its OFFSET (the MakeHuman
  convention; plain BVH files have none on non-root joints); the root's position channels place it.
  This is a self-contained minimal reader (hierarchy + first frame only).
* **glTF / GLB** (:func:`read_gltf`, pygltflib): the joints of the first skin; bind pose from the
  inverse bind matrices (``bind="inverse_bind"``, default) or from the node transforms
  (``bind="nodes"``).
* **JSON** (:func:`read_joint_json`): ``{"units": "m", "up": "y", "joints": {"right_hip": [x, y, z], ...}}``;
  ``units`` and ``up`` are optional.

Units (``units="auto"``): the file's or the rig's unit when it gives a plausible stature
(0.8-2.5 m), else the decimal unit (m, dm, cm, mm) whose stature is nearest 1.7 m. Stature is
estimated as (head - ankle height along up) / 0.84, SMPL's ratio. Non-decimal units (inches, CMU
units) are only taken from the rig/file or given explicitly. Up (``up="auto"``): the axis, with
sign, along which the head is farthest from the ankles.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from shape_inversion.features import named_joints_to_features
from shape_inversion.rigs import RigMap, detect_rig, load_map_file, load_preset, match_joints, missing_message
from smplik.conventions import JOINT_NAMES, PARENTS


class SkeletonError(ValueError):
    """A skeleton file cannot be read, or its units/axes are invalid."""


RestSource = Literal["frame0", "offsets"]
BindSource = Literal["inverse_bind", "nodes"]

UNIT_NAMES: dict[str, float] = {
    "m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "in": 0.0254, "inch": 0.0254, "ft": 0.3048,
    "cmu": 0.0254 / 0.45,
}
"""Unit names accepted by :func:`parse_units` (metres per unit)."""

HEAD_ANKLE_PER_STATURE = 0.84
"""(head joint - ankle joint height) / stature of SMPL-like bodies; used to estimate stature."""

PLAUSIBLE_STATURE_M = (0.8, 2.5)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A skeleton as read from a file.

    Attributes:
        names: joint names (J,).
        parents: parent index per joint, -1 for roots (J,).
        positions: (J, 3) rest/bind positions in file units and axes.
        source: where it came from (file path or ``"<string>"``).
        format: ``"bvh"``, ``"gltf"`` or ``"json"``.
        units: metres per unit stated by the file, if any.
        up: up axis stated by the file, if any.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    positions: np.ndarray
    source: str
    format: str
    units: float | None = None
    up: str | None = None


# ----------------------------------------------------------------------------- BVH


def _euler_matrix(order: str, degrees: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) of intrinsic rotations in channel order, e.g. ``"ZYX"`` -> Rz Ry Rx."""
    if not order:
        return np.eye(3)
    return Rotation.from_euler(order.upper(), degrees, degrees=True).as_matrix()


def read_bvh(source: str | Path, rest: RestSource = "frame0") -> Skeleton:
    """Read a BVH skeleton's rest pose.

    Args:
        source: a path, or the BVH text itself (anything containing ``HIERARCHY``).
        rest: ``"frame0"``: forward kinematics of the first MOTION frame; ``"offsets"``: zero rotations.

    Returns: a :class:`Skeleton` (end sites are not joints).

    Raises: SkeletonError on malformed files, or ``rest="frame0"`` with no frame.
    """
    if rest not in ("frame0", "offsets"):
        raise SkeletonError(f"Unknown rest source {rest!r}; expected 'frame0' or 'offsets'.")
    if isinstance(source, str) and "HIERARCHY" in source:
        text, where = source, "<string>"
    else:
        try:
            with open(source, encoding="utf-8", errors="replace") as fh:
                text = fh.read()
        except OSError as exc:
            raise SkeletonError(f"Cannot read BVH file {source}: {exc}") from exc
        where = str(source)
    head, sep, motion = text.partition("MOTION")
    tokens = head.split()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    stack: list[int] = []
    pending_end = False
    i = 0
    try:
        while i < len(tokens):
            tok = tokens[i]
            if tok in ("ROOT", "JOINT"):
                names.append(tokens[i + 1])
                parents.append(stack[-1] if stack else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append([])
                i += 2
            elif tok == "End":
                pending_end = True
                i += 2
            elif tok == "{":
                stack.append(-2 if pending_end else len(names) - 1)
                pending_end = False
                i += 1
            elif tok == "}":
                stack.pop()
                i += 1
            elif tok == "OFFSET":
                if stack and stack[-1] >= 0:
                    offsets[stack[-1]] = [float(t) for t in tokens[i + 1:i + 4]]
                i += 4
            elif tok == "CHANNELS":
                n = int(tokens[i + 1])
                channels[stack[-1]] = tokens[i + 2:i + 2 + n]
                i += 2 + n
            else:
                i += 1
    except (IndexError, ValueError) as exc:
        raise SkeletonError(f"{where}: malformed BVH hierarchy near token {i} ({exc}).") from exc
    if not names:
        raise SkeletonError(f"{where}: no ROOT joint in the BVH hierarchy.")
    if "-2" in map(str, stack) or stack:
        raise SkeletonError(f"{where}: unbalanced braces in the BVH hierarchy.")
    n_channels = sum(len(c) for c in channels)
    frame = np.zeros(n_channels)
    if rest == "frame0":
        match = re.search(r"Frame Time:[^\n]*\n\s*([^\n]+)", motion) if sep else None
        if match is None:
            raise SkeletonError(f"{where}: no MOTION frame for rest='frame0'; use rest='offsets'.")
        try:
            frame = np.array([float(t) for t in match.group(1).split()])
        except ValueError as exc:
            raise SkeletonError(f"{where}: malformed first MOTION frame ({exc}).") from exc
        if frame.size < n_channels:
            raise SkeletonError(f"{where}: first frame has {frame.size} values, the hierarchy {n_channels} channels.")
    offsets_arr = np.asarray(offsets, dtype=np.float64)
    positions = np.zeros_like(offsets_arr)
    R_world = np.zeros((len(names), 3, 3))
    cursor = 0
    for j, chans in enumerate(channels):
        values = frame[cursor:cursor + len(chans)]
        cursor += len(chans)
        pos = np.zeros(3)
        has_pos = False
        order = ""
        angles = []
        for c, v in zip(chans, values, strict=True):
            axis = "XYZ".index(c[0].upper())
            if c[1:].lower() == "position":
                pos[axis] = v
                has_pos = True
            else:
                order += c[0].upper()
                angles.append(v)
        R_local = _euler_matrix(order, np.asarray(angles)) if rest == "frame0" else np.eye(3)
        p = parents[j]
        if p < 0:
            positions[j] = pos if (has_pos and rest == "frame0") else offsets_arr[j]
            R_world[j] = R_local
        else:
            local = offsets_arr[j] + (pos if rest == "frame0" else 0.0)
            positions[j] = positions[p] + R_world[p] @ local
            R_world[j] = R_world[p] @ R_local
    return Skeleton(tuple(names), tuple(parents), positions, where, "bvh")


# ----------------------------------------------------------------------------- glTF


def _node_local_matrix(node) -> np.ndarray:
    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # glTF stores column-major
    T = np.eye(4)
    if node.translation is not None:
        T[:3, 3] = node.translation
    if node.rotation is not None:
        T[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()  # glTF quaternions are (x, y, z, w)
    if node.scale is not None:
        T[:3, :3] = T[:3, :3] * np.asarray(node.scale, dtype=np.float64)[None, :]
    return T


def _read_accessor_mat4(gltf, accessor_index: int) -> np.ndarray:
    """An accessor of MAT4 float32 as (N, 4, 4) row-major matrices."""
    import pygltflib

    acc = gltf.accessors[accessor_index]
    if acc.type != "MAT4" or acc.componentType != pygltflib.FLOAT:
        raise SkeletonError(f"inverseBindMatrices accessor {accessor_index} is not MAT4 float32.")
    view = gltf.bufferViews[acc.bufferView]
    data = gltf.binary_blob() if gltf.buffers[view.buffer].uri in (None, "") else None
    if data is None:
        gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
        data = gltf.binary_blob()
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or 64
    raw = np.lib.stride_tricks.as_strided(np.frombuffer(data, dtype=np.uint8, offset=start),
                                          shape=(acc.count, 64), strides=(stride, 1))
    return np.ascontiguousarray(raw).view(np.float32).reshape(acc.count, 4, 4).transpose(0, 2, 1).astype(np.float64)


def read_gltf(path: str | Path, bind: BindSource = "inverse_bind", skin: int = 0) -> Skeleton:
    """Read the joints of a glTF/GLB skin in its bind pose.

    Args:
        path: ``.glb`` or ``.gltf`` file.
        bind: ``"inverse_bind"``: joint = inverse of its inverse bind matrix (skin space);
            ``"nodes"``: world transforms of the joint nodes in the node hierarchy.
        skin: which skin.

    Raises: SkeletonError (no skin, bad accessor, unreadable file).
    """
    import pygltflib

    if bind not in ("inverse_bind", "nodes"):
        raise SkeletonError(f"Unknown bind source {bind!r}; expected 'inverse_bind' or 'nodes'.")
    try:
        gltf = pygltflib.GLTF2().load(str(path))
    except Exception as exc:  # pygltflib raises many types on bad input
        raise SkeletonError(f"Cannot read glTF file {path}: {exc}") from exc
    if gltf is None or not gltf.skins or skin >= len(gltf.skins):
        raise SkeletonError(f"{path}: no skin #{skin} (glTF has {len(gltf.skins or [])} skins).")
    joints = list(gltf.skins[skin].joints)
    node_parent = {c: p for p, n in enumerate(gltf.nodes) for c in (n.children or [])}
    names = tuple(gltf.nodes[j].name or f"joint{k}" for k, j in enumerate(joints))
    index = {node: k for k, node in enumerate(joints)}
    parents = []
    for j in joints:
        p = node_parent.get(j)
        while p is not None and p not in index:
            p = node_parent.get(p)
        parents.append(-1 if p is None else index[p])
    ibm_index = gltf.skins[skin].inverseBindMatrices
    if bind == "inverse_bind" and ibm_index is not None:
        world = np.linalg.inv(_read_accessor_mat4(gltf, ibm_index))
    else:
        cache: dict[int, np.ndarray] = {}

        def world_of(n: int) -> np.ndarray:
            if n not in cache:
                p = node_parent.get(n)
                local = _node_local_matrix(gltf.nodes[n])
                cache[n] = local if p is None else world_of(p) @ local
            return cache[n]

        world = np.stack([world_of(j) for j in joints])
    return Skeleton(names, tuple(parents), world[:, :3, 3].copy(), str(path), "gltf", units=None, up="y")


# ----------------------------------------------------------------------------- JSON


def read_joint_json(source: str | Path | Mapping) -> Skeleton:
    """Read ``{"units": ..., "up": ..., "joints": {name: [x, y, z]}}`` (a path or a parsed object)."""
    where = "<object>"
    if not isinstance(source, Mapping):
        where = str(source)
        try:
            source = json.loads(Path(source).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise SkeletonError(f"Cannot read joint JSON {where}: {exc}") from exc
    joints = source.get("joints") if isinstance(source, Mapping) else None
    if not isinstance(joints, Mapping) or not joints:
        raise SkeletonError(f"{where}: expected a 'joints' object of name -> [x, y, z].")
    try:
        positions = np.array([[float(c) for c in joints[n]] for n in joints], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SkeletonError(f"{where}: joint positions must be 3 numbers each ({exc}).") from exc
    if positions.shape[1:] != (3,):
        raise SkeletonError(f"{where}: joint positions must be 3 numbers each.")
    names = tuple(joints)
    smpl_parents = {n: JOINT_NAMES[p] for n, p in zip(JOINT_NAMES, PARENTS, strict=True)
                    if p >= 0}
    parents = tuple(names.index(smpl_parents[n]) if smpl_parents.get(n) in names else -1 for n in names)
    units = source.get("units")
    return Skeleton(names, parents, positions, where, "json",
                    units=None if units in (None, "auto") else parse_units(units),
                    up=None if source.get("up") in (None, "auto") else str(source.get("up")))


def read_skeleton(path: str | Path, *, rest: RestSource = "frame0", bind: BindSource = "inverse_bind") -> Skeleton:
    """Read a skeleton file by extension: ``.bvh``, ``.glb``/``.gltf``, ``.json``."""
    suffix = Path(path).suffix.lower()
    if suffix == ".bvh":
        return read_bvh(Path(path), rest=rest)
    if suffix in (".glb", ".gltf"):
        return read_gltf(path, bind=bind)
    if suffix == ".json":
        return read_joint_json(path)
    raise SkeletonError(f"Unsupported skeleton file {path}: expected .bvh, .glb, .gltf or .json.")


# ----------------------------------------------------------------------------- units, axes, mapping


def parse_units(units: str | float) -> float:
    """Metres per unit from a name (:data:`UNIT_NAMES`) or a number."""
    if isinstance(units, (int, float)) and not isinstance(units, bool):
        value = float(units)
    else:
        key = str(units).strip().lower()
        if key in UNIT_NAMES:
            return UNIT_NAMES[key]
        try:
            value = float(key)
        except ValueError:
            raise SkeletonError(f"Unknown units {units!r}; use one of {', '.join(UNIT_NAMES)}, 'auto', or metres per "
                                "unit as a number.") from None
    if not np.isfinite(value) or value <= 0:
        raise SkeletonError(f"Units must be a positive number of metres per unit, got {units!r}.")
    return value


def parse_up(up: str) -> np.ndarray:
    """Unit vector (3,) of ``"x"``, ``"-z"``, ... in file axes."""
    key = str(up).strip().lower()
    sign = -1.0 if key.startswith("-") else 1.0
    key = key.lstrip("+-")
    if key not in ("x", "y", "z"):
        raise SkeletonError(f"Unknown up axis {up!r}; expected x, y, z (optionally signed, e.g. -z) or auto.")
    vec = np.zeros(3)
    vec["xyz".index(key)] = sign
    return vec


def _axis_name(vec: np.ndarray) -> str:
    k = int(np.argmax(np.abs(vec)))
    return ("-" if vec[k] < 0 else "") + "xyz"[k]


@dataclass(frozen=True, eq=False)
class Character:
    """A skeleton mapped to SMPL, in metres and smplik's frame (y-up, left +x, facing +z).

    Attributes:
        skeleton: the skeleton as read.
        rig: the joint-name map used.
        positions: (J, 3) every joint of the skeleton, metres, smplik frame.
        smpl_joints: SMPL joint name -> index into ``skeleton.names`` for every mapped joint found.
        units_m: metres per file unit used.
        units_source: ``"given"``, ``"file"``, ``"rig"`` or ``"detected"``.
        up: the file's up axis used (``"y"``, ``"-z"``, ...).
        features: (6,) SMPL-SI features, metres.
    """

    skeleton: Skeleton
    rig: RigMap
    positions: np.ndarray
    smpl_joints: dict[str, int]
    units_m: float
    units_source: str
    up: str
    features: np.ndarray

    def joint(self, smpl_name: str) -> np.ndarray:
        """Position (3,) of a mapped SMPL joint, metres."""
        return self.positions[self.smpl_joints[smpl_name]]

    @property
    def head_ankle_height_m(self) -> float:
        """Height of the head joint above the mean ankle joint, metres."""
        ankles = [self.joint(a)[1] for a in ("left_ankle", "right_ankle") if a in self.smpl_joints]
        return float(self.joint("head")[1] - np.mean(ankles))


def _detect_up(head: np.ndarray, ankle: np.ndarray, hint: str | None) -> np.ndarray:
    d = head - ankle
    k = int(np.argmax(np.abs(d)))
    if np.abs(d[k]) < 0.8 * np.linalg.norm(d) and hint:  # tilted skeleton: trust the rig's convention
        return parse_up(hint)
    vec = np.zeros(3)
    vec[k] = np.sign(d[k]) or 1.0
    return vec


def _detect_units(height_units: float, hints: list[float | None]) -> tuple[float, str]:
    for hint, label in zip(hints, ("file", "rig"), strict=True):
        if hint is not None:
            stature = height_units * hint / HEAD_ANKLE_PER_STATURE
            if PLAUSIBLE_STATURE_M[0] <= stature <= PLAUSIBLE_STATURE_M[1]:
                return hint, label
    candidates = [1.0, 0.1, 0.01, 0.001]
    errors = [abs(np.log(max(height_units * c / HEAD_ANKLE_PER_STATURE, 1e-12) / 1.7)) for c in candidates]
    return candidates[int(np.argmin(errors))], "detected"


def prepare_character(skeleton: Skeleton, *, rig: str | RigMap | None = None, map_file: str | Path | None = None,
                      units: str | float = "auto", up: str = "auto") -> Character:
    """Map ``skeleton`` to SMPL joints, convert to metres and to smplik's frame.

    Args:
        rig: a preset name or :class:`RigMap`; ``None`` detects it from the joint names.
        map_file: a user map file (instead of ``rig``).
        units: ``"auto"``, a unit name (``m``, ``cm``, ``dm``, ``mm``, ``in``, ``ft``, ``cmu``) or metres per unit.
        up: ``"auto"`` or the file's up axis (``y``, ``z``, ``-z``...).

    Raises:
        RigError: unknown preset, or required joints missing (named, with the map used).
        SkeletonError: invalid units/axis.
    """
    if rig is not None and map_file is not None:
        raise SkeletonError("Give either a rig preset or a map file, not both.")
    if map_file is not None:
        rig_map = load_map_file(map_file)
    elif isinstance(rig, RigMap):
        rig_map = rig
    elif rig is not None:
        rig_map = load_preset(rig)
    else:
        rig_map = detect_rig(skeleton.names)
    found, _ = match_joints(rig_map, skeleton.names)
    from shape_inversion.rigs import missing_required

    if missing_required(rig_map, found):
        from shape_inversion.rigs import RigError

        raise RigError(missing_message(rig_map, found, source=f"Skeleton {skeleton.source}"))
    P = skeleton.positions
    ankles = [P[found[a]] for a in ("left_ankle", "right_ankle") if a in found]
    ankle = np.mean(ankles, axis=0)
    head = P[found["head"]]
    if str(up).lower() == "auto":
        up_vec = parse_up(skeleton.up) if skeleton.up else _detect_up(head, ankle, rig_map.up)
        if skeleton.up and (head - ankle) @ up_vec <= 0:  # the file's claim contradicts the skeleton
            up_vec = _detect_up(head, ankle, None)
    else:
        up_vec = parse_up(up)
    height = float((head - ankle) @ up_vec)
    if height <= 0:
        raise SkeletonError(f"Skeleton {skeleton.source}: the head is not above the ankles along up = "
                            f"{_axis_name(up_vec)}; pass the right --up.")
    if str(units).lower() == "auto":
        units_m, units_source = _detect_units(height, [skeleton.units, rig_map.units])
    else:
        units_m, units_source = parse_units(units), "given"
    # smplik frame: y = up, x = the character's left (from hips, else shoulders), z = x cross y
    left = None
    for a, b in (("left_hip", "right_hip"), ("left_shoulder", "right_shoulder")):
        if a in found and b in found:
            left = P[found[a]] - P[found[b]]
            break
    if left is None or np.linalg.norm(left - (left @ up_vec) * up_vec) < 1e-9:
        helper = np.eye(3)[int(np.argmin(np.abs(up_vec)))]
        left = helper
    x_axis = left - (left @ up_vec) * up_vec
    x_axis /= np.linalg.norm(x_axis)
    R_canon_file = np.stack([x_axis, up_vec, np.cross(x_axis, up_vec)])  # rows: new axes in file coords
    positions = (P * units_m) @ R_canon_file.T
    hips = [positions[found[h]] for h in ("left_hip", "right_hip") if h in found]
    centre = np.mean(hips, axis=0)
    positions = positions - np.array([centre[0], positions[:, 1].min(), centre[2]])
    features = named_joints_to_features({s: positions[i] for s, i in found.items()})
    return Character(skeleton, rig_map, positions, found, units_m, units_source, _axis_name(up_vec), features)
