"""The editor's Export: the posed scene as animation files.

:func:`export_posed_scene` calls the scene exporter ``workflows.export.export_scene`` when this
installation has it; otherwise it writes one single-frame BVH per character: the custom skeleton's
own BVH (:func:`workflows.character.export_bvh`) for characters with a custom skeleton, else the
SMPL skeleton (:func:`write_smpl_bvh`).

SMPL skeleton BVH: joints ``JOINT_NAMES`` in SMPL's tree, centimetres, y-up, character space
(the SMPL body scaled by the character's ``scale``); OFFSETs are the rest bones of the character's
body ``J(betas)``; the root has ``Xposition Yposition Zposition Zrotation Yrotation Xrotation``
(its position channels plus its OFFSET give the posed pelvis), the other joints ``Zrotation
Yrotation Xrotation`` (intrinsic, degrees, :func:`smplik.data.bvh.matrix_to_euler_channels`), with
each joint's local rotation ``R_parent_joint`` of the pose.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.atomic import write_text_atomic
from smplik.conventions import JOINT_NAMES, PARENTS
from smplik.data.bvh import format_bvh, matrix_to_euler_channels
from workflows.character import JOINT_CHANNELS, ROOT_CHANNELS
from workflows.scene import Scene, SceneCharacter

BVH_UNITS_PER_METRE = 100.0
"""The SMPL skeleton BVH is written in centimetres."""


def smpl_bvh_text(character: SceneCharacter) -> str:
    """One-frame BVH text of the character's posed SMPL skeleton (see the module docstring)."""
    import torch

    from smplik.body_model import load_body_model

    pose = character.pose
    if pose is None:
        raise ValueError(f"{character.name}: no pose to export.")
    s = BVH_UNITS_PER_METRE * character.scale
    rest = load_body_model(character.gender).rest_joints(torch.as_tensor(character.betas, dtype=torch.float64))
    J = rest.double().numpy() * s
    offsets = np.array([J[j] if p < 0 else J[j] - J[p] for j, p in enumerate(PARENTS)])
    local = Rotation.from_rotvec(np.concatenate([pose.global_orient[None], pose.body_pose])).as_matrix()
    euler = matrix_to_euler_channels(local, "ZYX")  # (24, 3), ZYX channel order
    pelvis = (np.asarray(rest[0].double().numpy()) + pose.transl) * s
    row = np.concatenate([pelvis - offsets[0], euler.reshape(-1)])
    channels = [ROOT_CHANNELS if p < 0 else JOINT_CHANNELS for p in PARENTS]
    return format_bvh(JOINT_NAMES, PARENTS, offsets, channels, row[None], 1 / 30)


def write_smpl_bvh(path: str | Path, character: SceneCharacter) -> Path:
    """Write :func:`smpl_bvh_text` atomically."""
    return write_text_atomic(path, smpl_bvh_text(character))


def _file_stem(name: str, taken: set[str]) -> str:
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "character"
    out, k = stem, 1
    while out in taken:
        k += 1
        out = f"{stem}_{k}"
    taken.add(out)
    return out


def export_posed_scene(scene: Scene, out_dir: Path, *, scene_dir: Path | None = None) -> list[Path]:
    """Export every character of ``scene`` (each with a pose) into ``out_dir``; returns the files written.

    ``scene_dir``: the folder relative skeleton paths are read from (default: the working directory).
    """
    try:
        from workflows.export import export_scene  # the scene exporter, where this installation has it
    except ModuleNotFoundError as exc:
        if exc.name != "workflows.export":
            raise
    else:
        return list(export_scene(scene, out_dir, formats=("bvh", "glb"), base_dir=scene_dir))
    from workflows.character import export_bvh, load_character, smpl_to_custom

    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    taken: set[str] = set()
    skeletons: dict[tuple[str, str | None, str], object] = {}
    for c in scene.characters:
        path = out_dir / f"{_file_stem(c.name, taken)}.bvh"
        if c.skeleton is not None:
            src = Path(c.skeleton.path)
            if not src.is_absolute() and scene_dir is not None:
                src = scene_dir / src
            key = (str(src), c.skeleton.rig, c.gender.value)
            if key not in skeletons:
                skeletons[key] = load_character(src, rig=c.skeleton.rig, gender=c.gender)
            char = skeletons[key]
            written.append(export_bvh(path, char, [smpl_to_custom(c.pose, char)]))  # type: ignore[arg-type]
        else:
            written.append(write_smpl_bvh(path, c))
    return written
