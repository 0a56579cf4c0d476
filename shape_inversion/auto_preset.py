"""``preset="auto"`` of BVH retargeting (:mod:`smplik.data.retarget`): the rig mapper picks the preset of a clip.

smplik, the lowest package, cannot import the mapper (:mod:`shape_inversion.rigs`), so the callers above it
pass :func:`auto_preset` explicitly (``retarget_bvh(..., rig_mapper=auto_preset)``, ``build_cache``'s and
``read_source``'s ``rig_mapper``): the ``smplik data`` commands, the edit benchmark, tracking from a motion
file. Importing this module installs nothing.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from shape_inversion.rigs import RigError
from shape_inversion.skeleton_io import Skeleton, SkeletonError, prepare_character
from smplik.data.bvh import BVHMotion
from smplik.data.retarget import (
    RetargetError,
    RetargetPreset,
    load_preset,
    preset_names,
    resolve_joint_names,
)

__all__ = ["auto_preset"]


def auto_preset(motion: BVHMotion) -> RetargetPreset:
    """The preset of a BVH clip found by the rig mapper (``preset="auto"``; no hand-written map).

    The clip's zero-rotation OFFSET pose is read by :func:`shape_inversion.skeleton_io.prepare_character`, the
    reader of ``invert-shape`` and ``--character`` (one rig reader for every command: Rigify deform bones,
    several roots, chains hanging apart, IK feet), so the map is the one ``invert-shape`` prints. A built-in
    preset found complete is used as is (its rest frame and units); a built-in preset whose optional joints
    (toes, a spine joint, the neck, collars, hands) the file lacks, or that names the file's spine otherwise,
    keeps its rest and units and takes the map ``invert-shape`` prints, each missing SMPL joint taking its
    parent's rotation (a Perception Neuron BVH without
    toes, a MediaPipe-to-BVH file without some spine joints). Otherwise units and up come from the mapped
    character (stature-based detection; an FBX clip is in metres, y up), the rest pose is chosen per clip
    (``rest="auto"``) and no frame is dropped. Raises :class:`RetargetError` naming the clip when it is not a
    humanoid.
    """
    _, positions = motion.rest_pose()
    if motion.num_frames and _offsets_one_way(motion):  # MediaPipe-to-BVH: the body is only in the rotations
        positions = motion.positions[0]
    fbx = motion.name.lower().endswith(".fbx")
    skeleton = Skeleton(motion.joint_names, motion.parents, positions, motion.name, "fbx" if fbx else "bvh",
                        units=1.0 if fbx else None, up="y" if fbx else None)
    try:
        char = prepare_character(skeleton)
    except (RigError, SkeletonError) as exc:
        raise RetargetError(f"{motion.name}: no rig map found ({exc})") from None
    if char.rig.name in preset_names() and not fbx:
        preset = load_preset(char.rig.name)
        if preset.units == 1.0 and char.units_m != 1.0:  # a preset saying no unit (Mixamo's: cm or m): the file's
            preset = dataclasses.replace(preset, units=char.units_m)
        resolved = resolve_joint_names(preset.joints, motion.joint_names)
        names = motion.joint_names
        if len(resolved) == len(preset.joints) and {k: names[i] for k, i in resolved.items()} == char.joint_map:
            return preset
        # the preset's rest and units, the map invert-shape reads (toes, spine joints, neck optional: an Axis
        # Neuron BVH's Spine..Spine3 maps spine3 to Spine3, where its arms branch, not the preset's Spine2)
        return dataclasses.replace(preset, name=f"{preset.name} (the joints {motion.name} has)",
                                   joints=dict(char.joint_map))
    if char.up not in ("y", "z"):
        raise RetargetError(f"{motion.name}: up axis {char.up} is not supported for training data (y or z)")
    return RetargetPreset(name=f"auto ({motion.name})", joints=char.joint_map, units=char.units_m,
                          up=char.up, rest="auto")  # type: ignore[arg-type]


def _offsets_one_way(motion: BVHMotion) -> bool:
    """Whether the clip's non-zero OFFSETs all point one way (its OFFSET pose is a line, not a body)."""
    off = np.asarray(motion.offsets, dtype=np.float64)[1:]
    lengths = np.linalg.norm(off, axis=-1)
    off = off[lengths > 1e-9] / lengths[lengths > 1e-9, None]
    return len(off) >= 5 and bool(np.all(off @ off[0] > 0.999))
