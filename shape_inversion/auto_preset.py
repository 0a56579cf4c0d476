"""``preset="auto"`` of BVH retargeting (:mod:`smplik.data.retarget`): the rig mapper picks the preset of a clip.

Importing this module installs :func:`auto_preset` in :func:`smplik.data.retarget.register_rig_mapper`:
smplik, the lowest package, cannot import the mapper (:mod:`shape_inversion.rigs`), so the mapper registers
itself. The ``smplik data`` commands (:mod:`shape_inversion.data_cli`) and the edit benchmark import it.
"""

from __future__ import annotations

from shape_inversion.rigs import RigError, detect_rig
from shape_inversion.skeleton_io import Skeleton, SkeletonError, prepare_character
from smplik.data.bvh import BVHMotion
from smplik.data.retarget import RetargetError, RetargetPreset, load_preset, preset_names, register_rig_mapper

__all__ = ["auto_preset"]


def auto_preset(motion: BVHMotion) -> RetargetPreset:
    """The preset of a BVH clip found by the rig mapper (``preset="auto"``; no hand-written map).

    The skeleton is mapped by :func:`shape_inversion.rigs.detect_rig` (topology, geometry and names;
    a built-in preset when it is as complete) on the zero-rotation OFFSET pose; a built-in preset is
    used as is; otherwise units and up come from :func:`shape_inversion.skeleton_io.prepare_character`
    (stature-based detection), the rest pose is chosen per clip (``rest="auto"``) and no frame is
    dropped (``motion_start`` 0). Raises :class:`RetargetError` naming the clip when it is not a humanoid.
    """
    _, positions = motion.rest_pose()
    try:
        rig = detect_rig(motion.joint_names, motion.parents, positions)
        if rig.name in preset_names():
            return load_preset(rig.name)
        char = prepare_character(Skeleton(motion.joint_names, motion.parents, positions, motion.name, "bvh"), rig=rig)
    except (RigError, SkeletonError) as exc:
        raise RetargetError(f"{motion.name}: no rig map found ({exc})") from None
    if char.up not in ("y", "z"):
        raise RetargetError(f"{motion.name}: up axis {char.up} is not supported for training data (y or z)")
    return RetargetPreset(name=f"auto ({motion.name})", joints=char.joint_map, units=char.units_m,
                          up=char.up, rest="auto")  # type: ignore[arg-type]


register_rig_mapper(auto_preset)
