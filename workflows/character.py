"""Custom characters: SMPL-SI approximation, SMPL <-> custom retargeting, BVH export.

A custom character is a skeleton file (BVH, glTF/GLB, joint JSON; read by
:mod:`shape_inversion.skeleton_io` with its zero-rotation rest pose, ``rest="offsets"`` for BVH)
whose joints are mapped to SMPL's by a rig preset (:mod:`shape_inversion.rigs`). SMPL-SI gives the
SMPL body ``(betas, scale)`` that approximates it; the character's pose is edited on that body.

Frames. ``canon`` is smplik's frame for the character (metres, y-up, left +x, facing +z, from
:func:`shape_inversion.skeleton_io.prepare_character`): ``p_canon = units * C @ p_file - shift``,
with the file-to-canon rotation ``C``. Rotations map as ``R_canon = C R_file C^T``. In the rest
pose every custom joint has the identity global rotation (the OFFSET pose), as every SMPL joint
has at rest; character space is the SMPL body scaled by ``scale`` about the world origin.

Retargeting (per mapped custom joint ``k`` <-> SMPL joint ``j``):

* Rest alignment ``A_k``: the minimal rotation taking the custom rest direction of ``k``'s aim bone
  (towards the custom joint mapped to ``j``'s aim child, e.g. spine3 -> neck, a pelvis without spine1-2
  -> spine3: :func:`shape_inversion.joint_fit.aim_children`) onto SMPL's rest direction of the same
  bone; identity for joints without a mapped child.
* SMPL -> custom: ``G_custom[k] = G_smpl[j] A_k``; an unmapped custom joint keeps its parent's
  global rotation (identity local rotation). Locals: ``R_parent_joint = G_parent^T G_joint``.
* Custom -> SMPL: ``G_smpl[j] = G_custom[k] A_k^T``; an unmapped SMPL joint keeps its parent's.
* Root position: ``p_custom_root = scale * p_smpl_pelvis + G_smpl_pelvis @ o`` with the rest
  offset ``o`` between the custom root and the scaled SMPL pelvis, both placed as
  ``prepare_character`` places skeletons (hips' midpoint above the origin, lowest joint at y = 0).

So SMPL -> custom -> SMPL returns every SMPL joint's rotation exactly when all 24 are mapped
(Mixamo-style rigs), and the mapped joints' global rotations in every case.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from shape_inversion.estimator import ShapeEstimate
from shape_inversion.joint_fit import AIM_CHILD, rest_alignments  # noqa: F401  (AIM_CHILD re-exported)
from shape_inversion.options import (  # noqa: F401  (re-exported: every command taking a character uses them)
    BindOption,
    CharacterOptions,
    CharacterOptionsError,
    MapOption,
    MaxJointsOption,
    PositionsOption,
    RestOption,
    RigOption,
    UnitsOption,
    UpOption,
    character_options_from_cli,
)
from shape_inversion.rigs import RigMap
from shape_inversion.skeleton_io import Character, Skeleton, prepare_character, read_character
from smplik.atomic import write_text_atomic
from smplik.conventions import JOINT_INDEX, NUM_JOINTS, PARENTS, Gender
from smplik.data.bvh import format_bvh
from smplik.data.retarget import swing_rotation
from smplik.kinematics import forward_kinematics, global_to_local
from smplik.metrics import rigid_align
from smplik.pose import Pose
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_euler_deg_np

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")


@dataclass(frozen=True, eq=False)
class CustomCharacter:
    """A custom skeleton with its SMPL approximation and retargeting data.

    Attributes:
        character: the mapped skeleton (metres, canon frame) from ``prepare_character``.
        estimate: the SMPL-SI estimate (betas, scale, gender).
        C_canon_file: (3, 3) rotation from file axes to the canon frame.
        shift: (3,) canon-frame shift (``p_canon = units * C p_file - shift``).
        smpl_of: (K,) SMPL joint index per custom joint, -1 if unmapped.
        align: (K, 3, 3) rest alignment ``A_k`` (identity when unmapped or without an aim bone).
        root_offset: (3,) custom root minus scaled SMPL pelvis at rest, canon frame.
        smpl_rest: (24, 3) ``J(betas)`` at unit scale (SMPL space).
        offsets: (K, 3) rest bone vectors ``p_rest[k] - p_rest[parent]`` in file units and axes (root:
            its rest position); the identity-rotation rest pose of :class:`CustomPose`.
        end_sites: custom joint index -> End Site offset (file units), when the source had them.
        options: how the character file was read.
    """

    character: Character
    estimate: ShapeEstimate
    C_canon_file: np.ndarray
    shift: np.ndarray
    smpl_of: np.ndarray
    align: np.ndarray
    root_offset: np.ndarray
    smpl_rest: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    options: CharacterOptions = CharacterOptions()

    @property
    def skeleton(self) -> Skeleton:
        return self.character.skeleton

    @property
    def names(self) -> tuple[str, ...]:
        return self.skeleton.names

    @property
    def parents(self) -> tuple[int, ...]:
        return self.skeleton.parents

    @property
    def betas(self) -> np.ndarray:
        return self.estimate.betas

    @property
    def scale(self) -> float:
        return float(self.estimate.scale)

    @property
    def gender(self) -> Gender:
        return self.estimate.gender

    @property
    def rig(self) -> RigMap:
        return self.character.rig

    @property
    def units_m(self) -> float:
        return float(self.character.units_m)

    def canon_to_file_points(self, p: np.ndarray) -> np.ndarray:
        """(..., 3) canon metres -> file units and axes."""
        return ((p + self.shift) @ self.C_canon_file) / self.units_m

    def file_to_canon_points(self, p: np.ndarray) -> np.ndarray:
        """(..., 3) file units and axes -> canon metres."""
        return (p * self.units_m) @ self.C_canon_file.T - self.shift

    def canon_to_file_rotations(self, R: np.ndarray) -> np.ndarray:
        """(..., 3, 3) canon -> file axes: ``C^T R C``."""
        return self.C_canon_file.T @ R @ self.C_canon_file

    def file_to_canon_rotations(self, R: np.ndarray) -> np.ndarray:
        return self.C_canon_file @ R @ self.C_canon_file.T


@dataclass(frozen=True)
class CustomPose:
    """A pose of a custom skeleton in its file's units and axes.

    Rotations are relative to the skeleton's rest pose (every joint's rest global rotation is the
    identity in this convention; the source file's own rest rotations are applied on export).

    Attributes:
        local_rotations: (K, 3, 3) ``R_parent_joint`` (root: its global rotation), file axes.
        root_position: (3,) root joint position, file units.
    """

    local_rotations: np.ndarray
    root_position: np.ndarray

    def positions(self, char: CustomCharacter) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics: ``(R_world (K, 3, 3), p_world (K, 3))`` in file units and axes."""
        K = len(char.parents)
        R = np.empty((K, 3, 3))
        p = np.empty((K, 3))
        for k, par in enumerate(char.parents):
            if par < 0:
                R[k], p[k] = self.local_rotations[k], self.root_position
            else:
                R[k] = R[par] @ self.local_rotations[k]
                p[k] = p[par] + R[par] @ char.offsets[k]
        return R, p


def placed(joints: np.ndarray, left_hip: int, right_hip: int) -> np.ndarray:
    """Place a rest skeleton like ``prepare_character``: hips' midpoint above the origin, lowest joint at y = 0."""
    centre = (joints[left_hip] + joints[right_hip]) / 2
    return joints - np.array([centre[0], joints[:, 1].min(), centre[2]])


def build_character(skeleton: Skeleton, estimate: ShapeEstimate, options: CharacterOptions | None = None, *,
                    rig: str | RigMap | None = None) -> CustomCharacter:
    """Retargeting data for ``skeleton`` (rest = its positions with identity rotations) and an SMPL-SI estimate.

    ``options`` give the rig/map/units/up (``rig`` overrides the options' rig, e.g. the map already detected).
    """
    from smplik.body_model import load_body_model

    options = CharacterOptions() if options is None else options
    if sum(p < 0 for p in skeleton.parents) != 1 or skeleton.parents[0] >= 0:
        raise ValueError(f"{skeleton.source}: retargeting needs one root joint, listed first.")
    if rig is None and options.map is None:
        rig = options.rig
    char = prepare_character(skeleton, rig=rig, map_file=options.map if rig is None else None,
                             units=options.units, up=options.up)
    K = len(skeleton.names)
    P_file = skeleton.positions
    P = char.positions
    C, shift = char.R_canon_file, char.shift
    smpl_of = np.full(K, -1, dtype=np.int64)
    for name, k in char.smpl_joints.items():
        smpl_of[k] = JOINT_INDEX[name]
    custom_of = {int(j): k for k, j in enumerate(smpl_of) if j >= 0}
    model = load_body_model(estimate.gender)
    smpl_rest = model.rest_joints(torch.as_tensor(estimate.betas, dtype=torch.float32)).double().numpy()
    s = float(estimate.scale)
    J_placed = placed(s * smpl_rest, JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"])
    align = np.broadcast_to(np.eye(3), (K, 3, 3)).copy()
    mapped = np.array(sorted(custom_of.values()), dtype=np.int64)
    if len(mapped):
        align[mapped] = rest_alignments(P[mapped], smpl_of[mapped], smpl_rest)
    root_smpl = int(smpl_of[0]) if smpl_of[0] >= 0 else 0
    root_offset = P[0] - J_placed[root_smpl]
    offsets = np.zeros((K, 3))
    for k, par in enumerate(skeleton.parents):
        offsets[k] = P_file[k] if par < 0 else P_file[k] - P_file[par]
    end_sites: dict[int, np.ndarray] = {}
    if skeleton.bvh is not None and skeleton.rest_rotations is not None and skeleton.bvh.joint_names == skeleton.names:
        motion, R0 = skeleton.bvh, skeleton.rest_rotations  # End Sites indexed as the skeleton's joints
        end_sites = {int(j): R0[j] @ o for j, o in zip(motion.end_site_parents, motion.end_site_offsets, strict=True)}
    return CustomCharacter(char, estimate, C, shift, smpl_of, align, root_offset, smpl_rest, offsets, end_sites,
                           options)


def load_character(path: str | Path, options: CharacterOptions | None = None, *,
                   gender: Gender | str = Gender.NEUTRAL, rig: str | None = None) -> CustomCharacter:
    """Read a skeleton file as ``options`` say, estimate its SMPL body with SMPL-SI and prepare retargeting.

    ``rig`` is a shortcut for ``options.rig``. Raises: SkeletonError / RigError / ShapeInversionError
    (from SMPL-SI), naming the problem.
    """
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model

    options = CharacterOptions() if options is None else options
    if rig is not None:
        options = dataclasses.replace(options, rig=rig, map=None)
    char = read_character(path, options)
    estimate = ShapeEstimator.build(load_body_model(gender)).estimate(char.features, char.mapped_rest())
    return build_character(char.skeleton, estimate, options, rig=char.rig)


def character_from_estimate(path: str | Path, options: CharacterOptions, betas: np.ndarray, scale: float,
                            gender: Gender) -> CustomCharacter:
    """Re-read a character file with the ``(betas, scale)`` a scene stores (no SMPL-SI query)."""
    from shape_inversion.features import NUM_FEATURES

    char = read_character(path, options)
    zeros = np.zeros(NUM_FEATURES)
    estimate = ShapeEstimate(np.asarray(betas, dtype=np.float64), float(scale), Gender.parse(gender),
                             np.zeros(len(betas)), 0.0, 0.0, 0, 0.0, char.features, zeros, 0.0,
                             np.asarray(betas, dtype=np.float64), float(scale))
    return build_character(char.skeleton, estimate, options, rig=char.rig)


# ----------------------------------------------------------------------------- retargeting


def _smpl_globals(pose: Pose, char: CustomCharacter) -> tuple[np.ndarray, np.ndarray]:
    """SMPL global rotations (24, 3, 3) and positions (24, 3) of ``pose`` on the character's body (SMPL space)."""
    aa = torch.as_tensor(np.concatenate([pose.global_orient[None], pose.body_pose]), dtype=torch.float64)
    R, p = forward_kinematics(axis_angle_to_matrix(aa), torch.as_tensor(char.smpl_rest),
                              torch.as_tensor(pose.transl, dtype=torch.float64))
    return R.numpy(), p.numpy()


def _mapped_below(char: CustomCharacter, k: int) -> list[int]:
    """The nearest mapped custom joints below custom joint ``k`` (one per branch)."""
    out, stack = [], [c for c, p in enumerate(char.parents) if p == k]
    while stack:
        c = stack.pop()
        if char.smpl_of[c] >= 0:
            out.append(c)
        else:
            stack.extend(d for d, p in enumerate(char.parents) if p == c)
    return out


def _skipping_rotation(char: CustomCharacter, k: int, G_s: np.ndarray, p_s: np.ndarray) -> np.ndarray:
    """SMPL's global rotation for custom joint ``k``, turned so that bones skipping SMPL joints land right.

    Where the custom bone from ``k`` to its next mapped joint spans several SMPL bones (a spine of one joint
    mapped to spine3 above the pelvis: SMPL's spine1 and spine2 are skipped), SMPL's rotation of ``k``'s own
    joint does not say where that bone points: the rotation is the one taking SMPL's rest vectors from
    ``k``'s SMPL joint to the mapped joints below it onto their posed vectors (Kabsch; one vector: SMPL's
    rotation swung onto it). Chains without skipped joints keep SMPL's rotation exactly.
    """
    j = int(char.smpl_of[k])
    below = [int(char.smpl_of[c]) for c in _mapped_below(char, k)]
    if not below or all(PARENTS[m] == j for m in below):
        return G_s[j]
    rest = np.stack([char.smpl_rest[m] - char.smpl_rest[j] for m in below])
    posed = np.stack([p_s[m] - p_s[j] for m in below])
    if len(below) == 1:
        return swing_rotation(G_s[j] @ rest[0], posed[0]) @ G_s[j]
    rest = rest / np.maximum(np.linalg.norm(rest, axis=1, keepdims=True), 1e-12)
    posed = posed / np.maximum(np.linalg.norm(posed, axis=1, keepdims=True), 1e-12)
    # Kabsch on directions: with each vector's mirror image both sets are centred, so the fit is a pure rotation
    both_rest, both_posed = np.concatenate([rest, -rest]), np.concatenate([posed, -posed])
    return rigid_align(torch.as_tensor(both_rest), torch.as_tensor(both_posed), scale=False).R.numpy()


def smpl_to_custom(pose: Pose, char: CustomCharacter) -> CustomPose:
    """Retarget an SMPL pose (on the character's SMPL body, SMPL space) onto the custom skeleton."""
    G_s, p_s = _smpl_globals(pose, char)
    K = len(char.parents)
    G = np.empty((K, 3, 3))
    for k, par in enumerate(char.parents):
        j = int(char.smpl_of[k])
        if j >= 0:
            G[k] = _skipping_rotation(char, k, G_s, p_s) @ char.align[k]
        else:
            G[k] = G[par] if par >= 0 else G_s[0]
    root_smpl = int(char.smpl_of[0]) if char.smpl_of[0] >= 0 else 0
    p_root = char.scale * p_s[root_smpl] + G_s[root_smpl] @ char.root_offset
    G_file = char.canon_to_file_rotations(G)
    local = np.empty_like(G_file)
    for k, par in enumerate(char.parents):
        local[k] = G_file[k] if par < 0 else G_file[par].T @ G_file[k]
    return CustomPose(local, char.canon_to_file_points(p_root))


def retarget_error_m(pose: Pose, char: CustomCharacter) -> np.ndarray:
    """How far ``pose`` retargeted onto ``char`` lands from the SMPL pose: (M,) metres per mapped joint.

    The character's mapped joints (character space) against the SMPL joints they map to (the pose on the
    character's SMPL body, times its scale), after a rigid alignment (Kabsch, :func:`smplik.metrics.rigid_align`).
    """
    from smplik.metrics import rigid_align

    _, p_file = smpl_to_custom(pose, char).positions(char)
    _, p_s = _smpl_globals(pose, char)
    mapped = [k for k in range(len(char.names)) if char.smpl_of[k] >= 0]
    mine = torch.as_tensor(char.file_to_canon_points(p_file)[mapped])
    theirs = torch.as_tensor(char.scale * p_s[[int(char.smpl_of[k]) for k in mapped]])
    fit = rigid_align(mine, theirs, scale=False)
    return np.linalg.norm((fit.apply(mine) - theirs).numpy(), axis=1)


def custom_to_smpl(custom: CustomPose, char: CustomCharacter) -> Pose:
    """Retarget a custom-skeleton pose back to SMPL (the character's SMPL body, SMPL space)."""
    R_file, _ = custom.positions(char)
    G = char.file_to_canon_rotations(R_file)
    G_s = np.empty((NUM_JOINTS, 3, 3))
    have = np.zeros(NUM_JOINTS, dtype=bool)
    for k in range(len(char.parents)):
        j = int(char.smpl_of[k])
        if j >= 0:
            G_s[j] = G[k] @ char.align[k].T
            have[j] = True
    for j in range(NUM_JOINTS):
        if not have[j]:
            G_s[j] = G_s[PARENTS[j]] if j > 0 else G[0]
    local = global_to_local(torch.as_tensor(G_s)).numpy()
    aa = matrix_to_axis_angle(torch.as_tensor(local)).numpy()
    root_smpl = int(char.smpl_of[0]) if char.smpl_of[0] >= 0 else 0
    p_root = char.C_canon_file @ (custom.root_position * char.units_m) - char.shift
    p_root_smpl = (p_root - G_s[root_smpl] @ char.root_offset) / char.scale
    # a custom root mapped to another SMPL joint (a pelvis child): back to the pelvis by the rest bone
    p_pelvis = p_root_smpl - G_s[0] @ (char.smpl_rest[root_smpl] - char.smpl_rest[0])
    transl = p_pelvis - char.smpl_rest[0]
    return Pose(aa[0], aa[1:], transl, np.asarray(char.betas, dtype=np.float64), char.gender)


# ----------------------------------------------------------------------------- BVH export


BvhFrame = str
"""``"source"``: the source file's units and axes; ``"world"``: the scene's world frame (metres, y-up, its floor
and facing: ``p_world = units * C p_file - shift``)."""


def custom_bvh_text(char: CustomCharacter, poses: Sequence[CustomPose], frame_time: float = 1 / 30, *,
                    keep_source_frames: bool = False, frame: BvhFrame = "source") -> str:
    """BVH text of the custom hierarchy with one frame per pose.

    A BVH character keeps its source file's layout: the same joints, End Sites, channels and rotation
    order per joint; the source's own rest rotations (``rest="frame0"``) are put back
    (``R_src_world = R_world @ R_rest_world``), non-root position channels keep their rest values and
    the root's carry the root position. Joints with fewer than three rotation channels keep only
    those axes of their rotation. Other characters get ``Xposition Yposition Zposition Zrotation
    Yrotation Xrotation`` on the root and ``Zrotation Yrotation Xrotation`` elsewhere (intrinsic,
    degrees; see :mod:`smplik.data.bvh`). ``keep_source_frames``: a BVH source's own MOTION frames follow
    the pose frames (its clip is kept; the pose frames come first).

    ``frame="source"``: OFFSETs, positions and rotations in the file's own units and axes.
    ``frame="world"``: everything in the scene's world frame (metres, y-up, the scene's floor and facing),
    as the GLB export: OFFSETs ``units * C o``, global rotations ``C G C^T``, root ``units * C p - shift``
    (the source's own frames converted the same way), so that every character of a scene lines up.
    """
    if len(poses) == 0:
        raise ValueError("At least one pose is needed to write a BVH file.")
    if frame not in ("source", "world"):
        raise ValueError(f"Unknown BVH frame {frame!r}; expected 'source' or 'world'.")
    s, C, shift = (char.units_m, char.C_canon_file, char.shift) if frame == "world" else (1.0, np.eye(3), np.zeros(3))
    motion = char.skeleton.bvh
    if motion is not None and motion.joint_names == char.names:
        return _source_layout_bvh(char, motion, poses, frame_time, keep_source_frames, (s, C, shift))
    K = len(char.parents)
    channels = [ROOT_CHANNELS if par < 0 else JOINT_CHANNELS for par in char.parents]
    rows = []
    for pose in poses:
        R, p = pose.positions(char)
        G = C @ R @ C.T
        local = np.stack([G[k] if par < 0 else G[par].T @ G[k] for k, par in enumerate(char.parents)])
        euler = matrix_to_euler_deg_np(local, "ZYX")  # (K, 3)
        row = [s * C @ p[0] - shift, euler[0]] + [euler[k] for k in range(1, K)]
        rows.append(np.concatenate(row))
    offsets = s * char.offsets @ C.T
    offsets[0] = 0.0  # the root's position channels replace its OFFSET
    end_sites = {k: s * C @ o for k, o in char.end_sites.items()} or None
    return format_bvh(char.names, char.parents, offsets, channels, np.stack(rows), frame_time, end_sites)


def _channel_rows(parents: Sequence[int], channels, offsets: np.ndarray, add: bool, G: np.ndarray,
                  p_root: np.ndarray, t: np.ndarray) -> np.ndarray:
    """MOTION rows (T, C) of a BVH layout from global rotations G (T, J, 3, 3), root positions (T, 3) and local
    translations t (T, J, 3) (non-root position channels: ``t - offset`` when ``add``, else ``t``)."""
    T = len(G)
    local = np.stack([G[:, k] if par < 0 else np.swapaxes(G[:, par], -1, -2) @ G[:, k]
                      for k, par in enumerate(parents)], axis=1)
    cols = []
    for k, (par, chans) in enumerate(zip(parents, channels, strict=True)):
        order = "".join(c[0] for c in chans if c.endswith("rotation"))
        angles = {}
        if order:
            full = order + "".join(a for a in "XYZ" if a not in order)
            angles = dict(zip(full, np.moveaxis(matrix_to_euler_deg_np(local[:, k], full), -1, 0), strict=True))
        for c in chans:
            axis = "XYZ".index(c[0])
            if c.endswith("position"):
                cols.append(p_root[:, axis] if par < 0 else t[:, k, axis] - (offsets[k, axis] if add else 0.0))
            else:
                cols.append(angles[c[0]])
    return np.stack(cols, axis=1) if cols else np.zeros((T, 0))


def _source_layout_bvh(char: CustomCharacter, motion, poses: Sequence[CustomPose], frame_time: float,
                       keep_source_frames: bool, to_out: tuple[float, np.ndarray, np.ndarray]) -> str:
    s, C, shift = to_out
    R0 = char.skeleton.rest_rotations
    t_rest = char.skeleton.rest_translations
    add = motion.position_mode == "add"
    offsets = s * motion.offsets @ C.T
    Rp = np.stack([pose.positions(char)[0] for pose in poses])  # (T, J, 3, 3) file axes
    p_root = np.stack([pose.positions(char)[1][0] for pose in poses])
    G = C @ (Rp @ R0) @ C.T  # the source convention's world rotations, output axes
    values = _channel_rows(char.parents, motion.channels, offsets, add, G, s * p_root @ C.T - shift,
                           np.broadcast_to(s * t_rest @ C.T, (len(poses), *t_rest.shape)))
    end_sites = {j: s * C @ o for j, o in zip(motion.end_site_parents, motion.end_site_offsets, strict=True)}
    if keep_source_frames and motion.num_frames:
        if s == 1.0 and np.array_equal(C, np.eye(3)) and not shift.any():
            source = motion.values  # the source's own frames, unchanged
        else:
            source = _channel_rows(char.parents, motion.channels, offsets, add, C @ motion.global_rotations @ C.T,
                                   s * motion.positions[:, 0] @ C.T - shift, s * motion.local_translations @ C.T)
        values = np.concatenate([values, source], axis=0)
        frame_time = motion.frame_time  # one clock for the pose frames and the source's clip
    return format_bvh(motion.joint_names, motion.parents, offsets, motion.channels, values,
                      frame_time, end_sites or None)


def export_bvh(path: str | Path, char: CustomCharacter, poses: Sequence[CustomPose],
               frame_time: float = 1 / 30) -> Path:
    """Write :func:`custom_bvh_text` to ``path`` atomically."""
    return write_text_atomic(path, custom_bvh_text(char, poses, frame_time))
