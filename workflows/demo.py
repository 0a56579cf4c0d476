"""The end-to-end demo on built-in material only (smpl-ik.txt App. E): no downloads, no ../shared.

1. Generate the examples (:mod:`workflows.examples_gen`): a ROMP-style ``.npz`` of two people,
   the matching synthetic photo with those people rendered into it (their generating poses, so the
   overlay of the solved bodies is visibly right or wrong), and a Mixamo-named custom character (BVH).
2. ``smpl/``: estimator output -> SMPL scene: effector recovery per person, ``scene.json``, a
   preview over the photo plus 3D views, recovery plots.
3. ``character/``: the same people retargeted onto the custom character through SMPL-SI: scene,
   previews (custom skeleton beside its SMPL approximation), recovery plots, one BVH per person.
4. ``character/scene_edited.json``: a user edit (the first person's right wrist raised by 25 cm
   as a position effector), solved as the editor solves a drag (:mod:`workflows.scene.edits`), and its preview;
   :attr:`DemoOutputs.edit_lines` give its figures.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import JOINT_INDEX
from smplik.effectors import Effector
from smplik.rotations import geodesic_distance
from workflows.edit_benchmark.pairs import TORSO_JOINTS
from workflows.scene.pipeline import EstimateOutputs, from_estimate
from workflows.scene.recovery import RecoveryConfig

EDIT_JOINT = "right_wrist"
EDIT_RAISE_M = 0.25


@dataclass(frozen=True)
class DemoOutputs:
    """Everything the demo wrote."""

    examples: tuple[Path, ...]
    smpl: EstimateOutputs
    character: EstimateOutputs
    edited_scene: Path
    edited_preview: Path | None
    edit_lines: tuple[str, ...] = ()
    """The edit's figures: the wrist's distance to its target, what was relaxed, the torso's turn, the
    conflict report."""

    @property
    def all_files(self) -> tuple[Path, ...]:
        edited = (self.edited_scene,) + ((self.edited_preview,) if self.edited_preview else ())
        return self.examples + self.smpl.all_files + self.character.all_files + edited


def write_examples(folder: str | Path, *, people_in_photo: bool = True) -> tuple[Path, Path, Path]:
    """Write the generated example files; returns (ROMP npz, photo PNG, character BVH).

    ``people_in_photo``: render the generated people into the photo (needs OpenGL), else an empty scene.
    """
    from workflows.examples_gen import write_background, write_mixamo_character, write_photo, write_romp_example

    folder = Path(folder)
    photo = write_photo(folder / "photo.png") if people_in_photo else write_background(folder / "photo.png")
    return (write_romp_example(folder / "romp_two_people.npz"), photo,
            write_mixamo_character(folder / "mixamo_character.bvh"))


def edit_scene(scene_path: Path, out_path: Path, solver: Any) -> Path:
    """Raise the first character's right wrist by :data:`EDIT_RAISE_M` as the editor's drag does
    (:mod:`workflows.scene.edits`: the stale effectors of the arm relaxed, only the arm re-posed) and save the scene."""
    return _edit(scene_path, out_path, solver)[0]


def _edit(scene_path: Path, out_path: Path, solver: Any) -> tuple[Path, list[str]]:
    """:func:`edit_scene` plus the edit's figures (lines for the demo's printout)."""
    from workflows.scene import character_joints, load_scene, save_scene
    from workflows.scene.edits import conflict_report, relax_stale, solve_drag
    from workflows.scene.recovery import TargetPose

    scene = load_scene(scene_path)
    first = scene.characters[0]
    wrist = character_joints(first)[Effector.position(EDIT_JOINT, (0, 0, 0)).joint]
    target = Effector.position(EDIT_JOINT, wrist + np.array([0.0, EDIT_RAISE_M, 0.0]))
    kept = tuple(e for e in first.effectors if not (e.joint == target.joint and e.type == target.type))
    effectors, relaxed = relax_stale(kept + (target,), len(kept))
    edited = solve_drag(dataclasses.replace(first, effectors=effectors), solver, len(kept))
    path = save_scene(dataclasses.replace(scene, characters=(edited,) + scene.characters[1:]), out_path)
    R_before = TargetPose.from_pose(dataclasses.replace(first.pose, joints=None)).R_world.double()
    R_after = TargetPose.from_pose(dataclasses.replace(edited.pose, joints=None)).R_world.double()
    turn = {n: float(np.degrees(geodesic_distance(R_before[JOINT_INDEX[n]], R_after[JOINT_INDEX[n]])))
            for n in TORSO_JOINTS}
    off = 1000.0 * float(np.linalg.norm(character_joints(edited)[target.joint] - target.value))
    lines = [f"edit: {first.name}'s {EDIT_JOINT} raised {EDIT_RAISE_M * 100:.0f} cm; {EDIT_JOINT} {off:.1f} mm off "
             f"its target; relaxed (tolerance raised): "
             f"{', '.join(f'{effectors[i].joint_name} {effectors[i].type.name.lower()}' for i in relaxed) or 'none'}",
             "edit: torso turn (deg) " + ", ".join(f"{n} {v:.1f}" for n, v in turn.items())]
    return path, lines + conflict_report(edited, solver).lines()


def run_demo(out_dir: str | Path, solver: Any = None, *, config: RecoveryConfig | None = None,
             previews: bool = True) -> DemoOutputs:
    """Run the whole chain into ``out_dir`` (see the module docstring); ``solver`` defaults to the shipped model.

    Raises: FileNotFoundError when no solver is given and no model is shipped.
    """
    if solver is None:
        from smplik.solver import IKSolver

        solver = IKSolver.load()
    config = RecoveryConfig(max_effectors=6, threshold=0.02) if config is None else config
    out_dir = Path(out_dir)
    npz, photo, bvh = write_examples(out_dir / "examples", people_in_photo=previews)
    smpl = from_estimate(npz, out_dir / "smpl", solver, format="romp", config=config, image_path=photo,
                         previews=previews)
    character = from_estimate(npz, out_dir / "character", solver, format="romp", character_path=bvh,
                              rig="mixamo", config=config, image_path=photo, previews=previews)
    edited, edit_lines = _edit(character.scene, out_dir / "character" / "scene_edited.json", solver)
    edited_png = None
    if previews:
        from smplik.render import save_png
        from workflows.scene import load_scene
        from workflows.scene.previews import load_image, render_scene

        edited_png = save_png(render_scene(load_scene(edited), image=load_image(photo)),
                              out_dir / "character" / "scene_edited.png")
    return DemoOutputs((npz, photo, bvh), smpl, character, edited, edited_png, tuple(edit_lines))
