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

import dataclasses
import functools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from shape_inversion.features import named_joints_to_features
from shape_inversion.gltf_io import GltfError, GltfRig, joint_parents, load_gltf, read_node_rig, read_rig
from shape_inversion.options import BindSource, CharacterOptions, RestSource
from shape_inversion.rigs import RigError, RigMap, detect_rig, load_map_file, load_preset, match_joints, missing_message
from smplik.conventions import JOINT_NAMES, PARENTS
from smplik.data.bvh import DEFAULT_MAX_JOINTS, BVHError, BVHMotion, PositionMode, parse_bvh
from smplik.data.bvh import read_bvh as bvh_read
from smplik.units import UNIT_NAMES, detect_units
from smplik.units import parse_units as _parse_units


class SkeletonError(ValueError):
    """A skeleton file cannot be read, or its units/axes are invalid."""




HEAD_ANKLE_PER_STATURE = 0.84
"""(head joint - ankle joint height) / stature of SMPL-like bodies; used to estimate stature."""

HEAD_PER_STATURE = 0.874
"""(head joint - lowest joint height) / stature of SMPL's template (1.70 m); a head-top joint's stand-in."""

PLAUSIBLE_STATURE_M = (0.8, 2.5)
OWN_SIZE_STATURE_M = (0.06, 28.0)
"""Statures (m) at which a glTF/VRM character (metres by the glTF spec) is read at its own size, a figurine to a
giant (SMPL-SI fits it at human size and scales the body, saying so in one line); outside, its units are detected
(a human exported in centimetres without the 0.01 scale is 170 m tall)."""


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
        bvh: the parsed BVH file (BVH skeletons).
        rest_rotations: (J, 3, 3) ``R_world_joint`` of the source's own convention in the rest pose
            (BVH: frame 0's, or identity); None means identity.
        rest_translations: (J, 3) the BVH local translations of the rest pose (file units).
        gltf: the glTF node tree and skin (glTF skeletons).
        humanoid: SMPL joint -> joint name from the file's own humanoid bone table (VRM 0.x / 1.0).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    positions: np.ndarray
    source: str
    format: str
    units: float | None = None
    up: str | None = None
    bvh: BVHMotion | None = field(default=None, repr=False)
    rest_rotations: np.ndarray | None = field(default=None, repr=False)
    rest_translations: np.ndarray | None = field(default=None, repr=False)
    gltf: GltfRig | None = field(default=None, repr=False)
    humanoid: dict[str, str] | None = None
    """The file's own humanoid table (VRM): SMPL joint name -> joint name."""
    rest: str | None = None
    """BVH: the rest pose used, ``"frame0"`` or ``"offsets"`` (with why, when chosen by ``rest="auto"``)."""


# ----------------------------------------------------------------------------- BVH


def read_bvh(source: str | Path, rest: RestSource = "frame0", *, position_mode: PositionMode = "auto",
             max_joints: int = DEFAULT_MAX_JOINTS) -> Skeleton:
    """Read a BVH skeleton's rest pose with the project's one BVH reader (:func:`smplik.data.bvh.read_bvh`).

    Args:
        source: a path, or the BVH text itself (anything containing ``HIERARCHY``).
        rest: ``"frame0"``: forward kinematics of the first MOTION frame (position channels per
            ``position_mode``); ``"offsets"``: the zero-rotation OFFSET pose; ``"auto"``: frame 0 when the
            file has frames (:func:`read_character` then checks that it is a rest pose).
        position_mode, max_joints: see :func:`smplik.data.bvh.read_bvh`.

    Returns: a :class:`Skeleton` (end sites are not joints) holding the parsed motion in ``bvh``.

    Raises: SkeletonError on malformed files, or ``rest="frame0"`` with no frame.
    """
    if rest not in ("auto", "frame0", "offsets"):
        raise SkeletonError(f"Unknown rest source {rest!r}; expected 'auto', 'frame0' or 'offsets'.")
    try:
        if isinstance(source, str) and "HIERARCHY" in source:
            motion = parse_bvh(source, position_mode=position_mode, max_joints=max_joints)
        else:
            motion = bvh_read(source, position_mode=position_mode, max_joints=max_joints)
    except BVHError as exc:
        raise SkeletonError(str(exc)) from None
    return bvh_skeleton(motion, ("frame0" if motion.num_frames else "offsets") if rest == "auto" else rest)


def bvh_skeleton(motion: BVHMotion, rest: str) -> Skeleton:
    """The :class:`Skeleton` of a parsed BVH file in the rest pose ``"frame0"`` or ``"offsets"``."""
    if rest == "frame0":
        if motion.num_frames == 0:
            raise SkeletonError(f"{motion.name}: no MOTION frame for rest='frame0'; use rest='offsets'.")
        R_rest, positions = motion.global_rotations[0].copy(), motion.positions[0].copy()
        t_rest = motion.local_translations[0].copy()
    else:  # the zero-rotation OFFSET pose
        R_rest, positions = motion.rest_pose()
        t_rest = motion.offsets.copy()
    return Skeleton(motion.joint_names, motion.parents, positions, motion.name, "bvh", bvh=motion,
                    rest_rotations=R_rest, rest_translations=t_rest, rest=rest)


# ----------------------------------------------------------------------------- glTF


def read_gltf(path: str | Path, bind: BindSource = "inverse_bind", skin: int = 0, *,
              max_joints: int = DEFAULT_MAX_JOINTS) -> Skeleton:
    """Read the joints of a glTF/GLB skin in its bind pose, in world space (:mod:`shape_inversion.gltf_io`).

    Args:
        path: ``.glb``, ``.gltf`` or ``.vrm`` file (external buffers inside its folder). A file without a
            skin is read from its node hierarchy (the VRM humanoid's, else the largest node tree).
        bind: ``"inverse_bind"``: the inverse bind matrices placed in the world by the root joint's
            node chain; ``"nodes"``: the joint nodes' world transforms in the default pose.
        skin: which skin.
        max_joints: most joints of the skin (or node hierarchy), checked before any traversal; the file's node
            count is capped by :data:`shape_inversion.gltf_io.GLTF_NODES`.

    Joints are listed parents first. Raises: SkeletonError (no skin, bad accessor, unsafe or unreadable file).
    """
    if bind not in ("inverse_bind", "nodes"):
        raise SkeletonError(f"Unknown bind source {bind!r}; expected 'inverse_bind' or 'nodes'.")
    from shape_inversion.vrm import humanoid_nodes, humanoid_to_smpl

    try:
        doc = load_gltf(path, max_joints=max_joints)
        table = humanoid_nodes(doc)
        if not doc.gltf.skins and table:  # a humanoid on plain nodes: its hierarchy is the skeleton
            rig = read_node_rig(doc, table["hips"], max_joints=max_joints)
        elif not doc.gltf.skins and doc.gltf.nodes:  # no skin (an animation-only file): the largest node tree
            sizes = np.bincount(_tops(doc.parent), minlength=len(doc.parent))
            rig = read_node_rig(doc, int(np.argmax(sizes)), max_joints=max_joints)
        else:
            rig = read_rig(doc, skin=skin, bind=bind)
    except GltfError as exc:
        raise SkeletonError(str(exc)) from None
    nodes = rig.doc.gltf.nodes
    names = tuple(nodes[n].name or f"joint{k}" for k, n in enumerate(rig.joint_nodes))
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise SkeletonError(f"{path}: duplicate joint name {dup!r} in skin #{skin}")
    positions = rig.T_world_joint_bind[:, :3, 3].copy()
    humanoid = None
    if table:
        index = {n: k for k, n in enumerate(rig.joint_nodes)}
        humanoid = {s: names[index[n]] for s, n in humanoid_to_smpl(table).items() if n in index} or None
    return Skeleton(names, joint_parents(rig), positions, str(path), "gltf", units=None, up="y", gltf=rig,
                    humanoid=humanoid)


def _tops(parent: tuple[int, ...]) -> list[int]:
    """The root of every node (linear: each node's root is found once)."""
    top: dict[int, int] = {}
    for n in range(len(parent)):
        chain, x = [], n
        while x not in top and parent[x] >= 0:
            chain.append(x)
            x = parent[x]
        root = top.get(x, x)
        for q in (*chain, x):
            top[q] = root
    return [top[n] for n in range(len(parent))]


# ----------------------------------------------------------------------------- JSON


def read_joint_json(source: str | Path | Mapping, *, max_joints: int = DEFAULT_MAX_JOINTS) -> Skeleton:
    """Read ``{"units": ..., "up": ..., "joints": {name: [x, y, z]}}`` (a path or a parsed object)."""
    where = "<object>"
    if not isinstance(source, Mapping):
        where = str(source)
        from smplik.validation import read_json

        source = read_json(source, SkeletonError, what="joint JSON")  # bounded read (smplik.limits.JSON_BYTES)
    joints = source.get("joints") if isinstance(source, Mapping) else None
    if not isinstance(joints, Mapping) or not joints:
        raise SkeletonError(f"{where}: expected a 'joints' object of name -> [x, y, z].")
    if len(joints) > max_joints:
        raise SkeletonError(f"{where}: {len(joints)} joints, more than the limit {max_joints} (raise it with "
                            "max_joints / --max-joints if this file is legitimate).")
    positions = np.zeros((len(joints), 3))
    for k, (n, value) in enumerate(joints.items()):
        try:
            row = [float(c) for c in value] if isinstance(value, list) else None
        except (TypeError, ValueError):
            row = None
        if row is None or len(row) != 3 or not np.isfinite(row).all():
            raise SkeletonError(f"{where}: joints.{str(n)[:40]}: expected 3 finite numbers, got {str(value)[:40]!r}.")
        positions[k] = row
    names = tuple(joints)
    index = {n: i for i, n in enumerate(names)}
    smpl_parents = {n: JOINT_NAMES[p] for n, p in zip(JOINT_NAMES, PARENTS, strict=True) if p >= 0}
    parents = tuple(index.get(smpl_parents.get(n, ""), -1) for n in names)
    units, up = source.get("units"), source.get("up")
    if up is not None and up != "auto":
        if not isinstance(up, str):
            raise SkeletonError(f"{where}: 'up' must be a string such as 'y' or '-z', got {str(up)[:40]!r}.")
        parse_up(up)
    return Skeleton(names, parents, positions, where, "json",
                    units=None if units in (None, "auto") else parse_units(units),
                    up=None if up in (None, "auto") else up)


def read_fbx_skeleton(path: str | Path, rest: RestSource = "auto", *, take: str | int | None = None,
                      max_joints: int = DEFAULT_MAX_JOINTS) -> Skeleton:
    """Read an FBX skeleton (:mod:`smplik.data.fbx`: ufbx, metres, y up) in its bind pose.

    The file becomes a BVH motion whose OFFSETs are the bind pose (else the nodes' rest) and whose frames
    are one animation take, so every command treats it as it treats a BVH file (export to BVH of its own
    skeleton, its frames as training data). ``rest="frame0"``: the take's first frame instead of the bind pose.
    """
    from smplik.data.fbx import FbxError, read_fbx_info

    if rest not in ("auto", "frame0", "offsets"):
        raise SkeletonError(f"Unknown rest source {rest!r}; expected 'auto', 'frame0' or 'offsets'.")
    try:
        motion, info = read_fbx_info(path, take=take, max_joints=max_joints)
    except FbxError as exc:
        raise SkeletonError(str(exc)) from None
    skeleton = bvh_skeleton(motion, "frame0" if rest == "frame0" else "offsets")
    return dataclasses.replace(skeleton, format="fbx", units=1.0, up="y",
                               rest=info.summary(rest="frame 0 of the take" if rest == "frame0" else None))


def read_skeleton(path: str | Path, *, rest: RestSource = "frame0", bind: BindSource = "inverse_bind",
                  positions: PositionMode = "auto", max_joints: int = DEFAULT_MAX_JOINTS) -> Skeleton:
    """Read a skeleton file by extension: ``.bvh``, ``.fbx``, ``.glb``/``.gltf``/``.vrm``, ``.json``.

    BVH ``rest="auto"`` reads frame 0 (the OFFSETs when the file has no frame); :func:`read_character`
    then decides between frame 0 and the OFFSETs.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".bvh":
        return read_bvh(Path(path), rest=rest, position_mode=positions, max_joints=max_joints)
    if suffix in (".glb", ".gltf", ".vrm"):  # a VRM file is a GLB with a humanoid table
        return read_gltf(path, bind=bind, max_joints=max_joints)
    if suffix == ".json":
        return read_joint_json(path, max_joints=max_joints)
    if suffix == ".fbx":
        return read_fbx_skeleton(path, rest=rest, max_joints=max_joints)
    raise SkeletonError(f"Unsupported skeleton file {path}: expected .bvh, .fbx, .glb, .gltf, .vrm or .json.")


def read_character(path: str | Path, options: CharacterOptions | None = None) -> Character:
    """Read ``path`` and map it to SMPL as ``options`` say (one call for every command taking a character)."""
    o = CharacterOptions() if options is None else options
    skeleton = read_skeleton(path, rest=o.rest, bind=o.bind, positions=o.positions, max_joints=o.max_joints)
    try:
        char = prepare_character(skeleton, rig=o.rig, map_file=o.map, units=o.units, up=o.up, root=o.root)
    except RigError as exc:  # a refusal names the file it is about (the rig mapper sees only joint names)
        if str(path) in str(exc):
            raise
        raise RigError(f"{path}: {exc}") from None
    if o.rest == "auto" and skeleton.bvh is not None and skeleton.rest == "frame0":
        char = _rest_by_evidence(char, o)
    return char


def _rest_by_evidence(char: Character, o: CharacterOptions) -> Character:
    """Frame 0 or the OFFSET pose as the BVH rest pose, whichever makes the more human skeleton.

    Frame 0 with straight limbs and spine (at most 10 degrees more bend than the OFFSETs) is the rest pose.
    Otherwise both candidates are mapped (units detected for each) and SMPL-SI fits each: the one with the
    smaller feature residual wins (a candidate outside the human range loses). Rokoko's OFFSETs are in
    joint-local frames (2.4 m legs), CMU's frame 0 is mid-motion: neither rule alone reads both.
    """
    skeleton = char.skeleton
    try:
        offsets = bvh_skeleton(skeleton.bvh, "offsets")
        off_char = prepare_character(offsets, rig=char.rig, units=o.units, up=o.up, root=o.root)
    except (SkeletonError, RigError, ValueError):
        return dataclasses.replace(char, skeleton=dataclasses.replace(
            skeleton, rest="frame0 (the OFFSET pose cannot be mapped)"))
    bend0, bend_off = rest_bend_deg(char.positions, char.smpl_joints), rest_bend_deg(off_char.positions,
                                                                                    off_char.smpl_joints)
    if bend0 <= bend_off + 10.0:
        why = f"frame0 (frame 0 is a rest pose: {bend0:.0f} deg of bend; the OFFSET pose {bend_off:.0f} deg)"
        return dataclasses.replace(char, skeleton=dataclasses.replace(skeleton, rest=why))
    r0, r_off = proportion_residual_m(char.features), proportion_residual_m(off_char.features)

    def said(r: float) -> str:
        return "not a human" if not np.isfinite(r) else f"residual {r * 1000:.0f} mm"

    if r_off <= r0:
        chosen, rest = off_char, "offsets"
    else:
        chosen, rest = char, "frame0"
    why = (f"{rest} (frame 0 is not a rest pose: its limbs and spine bend {bend0:.0f} deg in all, the OFFSET pose "
           f"{bend_off:.0f} deg; the more human by SMPL-SI: frame 0 {said(r0)}, OFFSETs {said(r_off)})")
    return dataclasses.replace(chosen, skeleton=dataclasses.replace(chosen.skeleton, rest=why))


def proportion_residual_m(features: np.ndarray) -> float:
    """SMPL-SI's largest feature residual (metres) for ``features`` (6,), inf outside the human range."""
    from shape_inversion.estimator import ShapeInversionError

    try:
        with warnings.catch_warnings():  # a weak fit of a candidate is not the character's: no warning
            warnings.simplefilter("ignore")
            return float(_neutral_estimator().estimate(features).max_feature_residual_m)
    except ShapeInversionError:
        return float("inf")


@functools.lru_cache(maxsize=1)
def _neutral_estimator():
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model
    from smplik.conventions import Gender

    return ShapeEstimator.build(load_body_model(Gender.NEUTRAL))


def rest_bend_deg(positions: np.ndarray, found: Mapping[str, int]) -> float:
    """How far a pose is from a rest pose (T or A): degrees of bend at knees, elbows and along the spine,
    plus the angle between the two legs. positions (J, 3); ``found`` SMPL joint -> index."""
    def angle(a: str, b: str, c: str) -> float:
        if not all(k in found for k in (a, b, c)):
            return 0.0
        u, v = positions[found[b]] - positions[found[a]], positions[found[c]] - positions[found[b]]
        return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v)))

    total = sum(angle(f"{s}_{a}", f"{s}_{b}", f"{s}_{c}") for s in ("left", "right")
                for a, b, c in (("hip", "knee", "ankle"), ("shoulder", "elbow", "wrist")))
    total += angle("pelvis", "spine3", "head")
    if all(f"{s}_{j}" in found for s in ("left", "right") for j in ("hip", "ankle")):
        legs = [positions[found[f"{s}_ankle"]] - positions[found[f"{s}_hip"]] for s in ("left", "right")]
        total += float(np.degrees(np.arctan2(np.linalg.norm(np.cross(*legs)), legs[0] @ legs[1])))
    return total


# ----------------------------------------------------------------------------- units, axes, mapping


def parse_units(units: str | float) -> float:
    """Metres per unit from a name (:data:`smplik.units.UNIT_NAMES`) or a number; raises SkeletonError."""
    return _parse_units(units, SkeletonError)


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
        R_canon_file: (3, 3) rotation from file axes to smplik's frame.
        shift: (3,) ``positions = units_m * P_file @ R_canon_file.T - shift``.
    """

    skeleton: Skeleton
    rig: RigMap
    positions: np.ndarray
    smpl_joints: dict[str, int]
    units_m: float
    units_source: str
    up: str
    features: np.ndarray
    R_canon_file: np.ndarray = field(default_factory=lambda: np.eye(3))
    shift: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def mapped_rest(self):
        """The mapped joints at rest (:class:`shape_inversion.joint_fit.MappedRest`, metres) for SMPL-SI's joint fit."""
        from shape_inversion.joint_fit import MappedRest

        return MappedRest.from_skeleton(self.positions, self.skeleton.parents, self.smpl_joints)

    @property
    def joint_map(self) -> dict[str, str]:
        """SMPL joint -> joint name of the map used (SMPL order)."""
        return {s: self.skeleton.names[i] for s, i in self.smpl_joints.items()}

    def map_report(self) -> list[str]:
        """Lines saying which map was chosen (rig, hierarchy, every pair) and the mapper's doubts."""
        how = {"auto": "mapped by topology, geometry and names", "vrm": "the file's humanoid table"}.get(
            self.rig.name, "preset")
        root = f", hierarchy of root joint {self.rig.root!r}" if self.rig.root else ""
        pairs = ", ".join(f"{s}={n}" for s, n in self.joint_map.items())
        lines = [f"rig {self.rig.name} ({how}{root}): {pairs}"] + [f"warning: {w}" for w in self.rig.warnings]
        if self.skeleton.format in ("bvh", "fbx") and self.skeleton.rest:
            lines.append(f"rest pose: {self.skeleton.rest}")
        return lines

    def joint(self, smpl_name: str) -> np.ndarray:
        """Position (3,) of a mapped SMPL joint, metres."""
        return self.positions[self.smpl_joints[smpl_name]]

    @property
    def height_m(self) -> float:
        """Stature: the lowest joint (the feet) to the top of the head, metres.

        The top of the head is the highest joint of the head's subtree (a head-top end bone: Mixamo's
        ``HeadTop_End``, a Blender head bone's tail) when it rises above the head joint by at least 3 % of the
        head's height; else, for a skeleton ending at the head joint, the head joint's height over SMPL's ratio
        (the head joint is at 87.4 % of the stature above SMPL's lowest joint).
        """
        head = self.smpl_joints["head"]
        floor = float(self.positions[:, 1].min())
        head_h = float(self.positions[head, 1]) - floor
        parents = self.skeleton.parents
        def under_head(j: int) -> bool:
            for _ in range(len(parents)):
                if j == head:
                    return True
                if j < 0:
                    return False
                j = parents[j]
            return False

        top = max(float(self.positions[j, 1]) for j in range(len(parents)) if under_head(j)) - floor
        return top if top >= 1.03 * head_h else head_h / HEAD_PER_STATURE

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
    return UNIT_NAMES[detect_units(height_units / HEAD_ANKLE_PER_STATURE)], "detected"


def subset_skeleton(skeleton: Skeleton, keep: list[int]) -> Skeleton:
    """The joints ``keep`` (a whole hierarchy, parents first) of ``skeleton``, re-indexed."""
    index = {j: k for k, j in enumerate(keep)}
    parents = tuple(index.get(skeleton.parents[j], -1) for j in keep)

    def take(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[keep]

    gltf = skeleton.gltf
    if gltf is not None:
        gltf = dataclasses.replace(gltf, joint_nodes=tuple(gltf.joint_nodes[j] for j in keep),
                                   skin_order=tuple(gltf.skin_order[j] for j in keep),
                                   inverse_bind=gltf.inverse_bind[keep],
                                   T_world_joint_bind=gltf.T_world_joint_bind[keep])
    names = tuple(skeleton.names[j] for j in keep)
    humanoid = None if skeleton.humanoid is None else {s: n for s, n in skeleton.humanoid.items() if n in names}
    bvh, t_rest = skeleton.bvh, take(skeleton.rest_translations)
    if bvh is not None and (list(keep) != list(range(bvh.num_joints)) or tuple(parents) != tuple(bvh.parents)):
        # the motion follows the new hierarchy (its joints, End Sites and frames indexed as the skeleton's)
        bvh = sub_motion(bvh, keep, parents)
        if skeleton.rest_rotations is not None:
            R0, P = skeleton.rest_rotations[keep], skeleton.positions[keep]
            t_rest = np.array([P[k] if p < 0 else R0[p].T @ (P[k] - P[p]) for k, p in enumerate(parents)])
    return Skeleton(names, parents, skeleton.positions[keep], skeleton.source, skeleton.format,
                    skeleton.units, skeleton.up, bvh, take(skeleton.rest_rotations), t_rest, gltf, humanoid,
                    skeleton.rest)


def sub_motion(motion: BVHMotion, keep: Sequence[int], parents: Sequence[int]) -> BVHMotion:
    """The joints ``keep`` of a BVH motion under new ``parents`` (indices into ``keep``, parents first).

    World rotations and positions of every frame are kept; local ones are recomputed for the new hierarchy,
    joints whose distance to their new parent changes (a removed joint between them bent) get position
    channels; the zero-rotation pose is still the OFFSET pose (:func:`smplik.data.fbx.motion_from_world`).
    """
    from smplik.data.fbx import motion_from_world

    keep = list(keep)
    _, p_off = motion.rest_pose()
    T_rest = np.broadcast_to(np.eye(4), (len(keep), 4, 4)).copy()
    T_rest[:, :3, 3] = p_off[keep]
    T_world = np.broadcast_to(np.eye(4), (motion.num_frames, len(keep), 4, 4)).copy()
    T_world[..., :3, :3] = motion.global_rotations[:, keep]
    T_world[..., :3, 3] = motion.positions[:, keep]
    return motion_from_world(motion.name, [motion.joint_names[j] for j in keep], tuple(parents), T_rest, T_world,
                             motion.frame_time)


def reparent_skeleton(skeleton: Skeleton, parents: Sequence[int], keep: Sequence[int] | None = None) -> Skeleton:
    """``skeleton`` with new ``parents`` (J,) (indices into its joints), reduced to ``keep`` and listed parents first.

    Only the hierarchy changes: rest positions, bind matrices and glTF nodes stay (a GLB export poses the
    joint nodes from their world transforms, so the file's own node tree is kept).
    """
    keep = list(range(len(skeleton.names))) if keep is None else list(keep)
    kept = set(keep)
    children: dict[int, list[int]] = {}
    for j in keep:
        children.setdefault(parents[j] if parents[j] in kept else -1, []).append(j)
    order: list[int] = []
    stack = list(reversed(children.get(-1, [])))
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j, [])))
    full = tuple(parents[j] if parents[j] in kept else -1 for j in range(len(skeleton.names)))
    return subset_skeleton(dataclasses.replace(skeleton, parents=full), order)


def deform_skeleton(skeleton: Skeleton) -> tuple[Skeleton, list[str]]:
    """A Blender Rigify control rig's deform bones (``DEF-``) as the skeleton, with a note; else ``skeleton``."""
    from shape_inversion.rig_mapper import deform_bones, kept_parents

    keep = deform_bones(skeleton.names)
    if keep is None:
        return skeleton, []
    parents = list(skeleton.parents)
    for j, p in zip(keep, kept_parents(skeleton.parents, keep), strict=True):
        parents[j] = p
    others = len(skeleton.names) - len(keep)
    return reparent_skeleton(skeleton, parents, keep), [
        f"a Blender Rigify rig: its {len(keep)} DEF- (deform) bones are the skeleton, its {others} other bones "
        "(ORG-, MCH-, controls, IK targets and poles) are ignored"]


def linked_skeleton(skeleton: Skeleton) -> tuple[Skeleton, list[str]] | None:
    """``skeleton`` with its separate chains linked into one hierarchy (``rig_mapper.virtual_parents``); None
    when it has one root."""
    from shape_inversion.rig_mapper import virtual_parents

    axes = None if skeleton.gltf is None else skeleton.gltf.T_world_joint_bind[:, :3, 1]
    made = virtual_parents(skeleton.names, skeleton.parents, skeleton.positions, axes)
    if made is None:
        return None
    return reparent_skeleton(skeleton, made[0]), made[1]


def _hierarchy(parents: tuple[int, ...], root: int) -> list[int]:
    keep = {root}
    for j, p in enumerate(parents):  # parents are listed before children
        if p in keep:
            keep.add(j)
    return sorted(keep)


def prepare_character(skeleton: Skeleton, *, rig: str | RigMap | None = None, map_file: str | Path | None = None,
                      units: str | float = "auto", up: str = "auto", root: str | None = None) -> Character:
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
    elif skeleton.humanoid and root is None:  # the file's own humanoid table wins
        from shape_inversion.rig_mapper import map_doubts

        index = {n: k for k, n in enumerate(skeleton.names)}
        doubts = map_doubts(skeleton.names, skeleton.parents, skeleton.positions,
                            {s: index[n] for s, n in skeleton.humanoid.items()})
        rig_map = RigMap("vrm", tuple(skeleton.humanoid.items()), "the file's humanoid bone table (VRM)",
                         warnings=tuple(doubts))
    else:
        skeleton, notes = deform_skeleton(skeleton)
        try:
            rig_map = detect_rig(skeleton.names, skeleton.parents, skeleton.positions, root=root)
        except RigError:
            linked = linked_skeleton(skeleton) if root is None else None
            if linked is None:
                raise
            skeleton, more = linked
            rig_map = detect_rig(skeleton.names, skeleton.parents, skeleton.positions)
            notes += more
        if notes:
            rig_map = dataclasses.replace(rig_map, warnings=tuple(notes) + tuple(rig_map.warnings))
    found, _ = match_joints(rig_map, skeleton.names)
    roots = [j for j, p in enumerate(skeleton.parents) if p < 0]
    if len(roots) > 1 and "pelvis" in found:  # several roots: keep the hierarchy holding the body
        top = found["pelvis"]
        while skeleton.parents[top] >= 0:
            top = skeleton.parents[top]
        if root is not None and root in skeleton.names:
            top = skeleton.names.index(root)
        skeleton = subset_skeleton(skeleton, _hierarchy(skeleton.parents, top))
        if rig_map.root != skeleton.names[0]:
            rig_map = dataclasses.replace(rig_map, root=skeleton.names[0])
        found, _ = match_joints(rig_map, skeleton.names)
    from shape_inversion.rigs import missing_required

    if missing_required(rig_map, found):
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
    if str(units).lower() == "auto" and skeleton.format == "fbx":  # the file states its unit (UnitScaleFactor)
        units_m, units_source = float(skeleton.units or 1.0), "file"
    elif str(units).lower() == "auto" and skeleton.format == "gltf" and not PLAUSIBLE_STATURE_M[0] <= \
            height / HEAD_ANKLE_PER_STATURE <= PLAUSIBLE_STATURE_M[1] and \
            OWN_SIZE_STATURE_M[0] <= height / HEAD_ANKLE_PER_STATURE <= OWN_SIZE_STATURE_M[1]:
        units_m, units_source = 1.0, "file: glTF is in metres"  # a figurine or a giant at its own size
    elif str(units).lower() == "auto":
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
    shift = np.array([centre[0], positions[:, 1].min(), centre[2]])
    positions = positions - shift
    features = named_joints_to_features({s: positions[i] for s, i in found.items()})
    return Character(skeleton, rig_map, positions, found, units_m, units_source, _axis_name(up_vec), features,
                     R_canon_file, shift)
