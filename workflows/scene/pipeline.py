"""Estimator output -> (SMPL-SI character) -> effector recovery -> editable scene (smpl-ik.txt section 5, App. E).

The people of one frame (``frame``, default 0) are read by :func:`workflows.estimators.read_estimate`,
optionally put on a floor (``ground``), then per estimated person:

1. Body: the estimator's ``(betas, gender)`` at scale 1, or, with a custom character, the SMPL
   body SMPL-SI fitted to it (``character.betas``, ``scale``, ``gender``).
2. Retargeting onto that body: the estimated local rotations are kept; the pelvis stays where the
   estimator put it in the world (character space), so in SMPL space it is divided by ``scale``.
3. Effector recovery (:mod:`workflows.scene.recovery`, all people batched together) on that target gives
   a few effectors and the pose they solve to; both go into the scene.
4. With a custom character, the solved pose is retargeted onto the custom skeleton
   (:func:`workflows.character.smpl_to_custom`) for BVH export.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from smplik.pose import Pose
from smplik.solver import IKSolver
from workflows.character import CharacterOptions, CustomCharacter, CustomPose, smpl_to_custom
from workflows.estimators.base import EstimatedPerson
from workflows.scene.characters import GroundRecord, SceneCharacter, SkeletonSource
from workflows.scene.document import Scene
from workflows.scene.recovery import RecoveryConfig, RecoveryResult, TargetPose, TensorSolver, recover_many

Progress = Callable[[int, int, str], None]
"""``progress(done, total, what)``: called after each greedy recovery step (e.g. to drive a progress bar)."""


@dataclass(frozen=True)
class PersonResult:
    """What the pipeline did for one person."""

    name: str
    target: Pose
    recovery: RecoveryResult
    custom_pose: CustomPose | None


def retarget_to_body(person: EstimatedPerson, betas: np.ndarray, gender, scale: float) -> Pose:
    """The person's local rotations on another SMPL body, pelvis kept at its world position.

    Returns the pose in SMPL space of the new body (``transl = pelvis_world / scale - J0(betas)``).
    """
    from workflows.estimators.base import rest_pelvis

    pelvis_world = person.transl + rest_pelvis(person.betas[None], person.gender)[0]
    J0 = rest_pelvis(np.asarray(betas)[None], gender)[0]
    return Pose(person.global_orient.copy(), person.body_pose.copy(), pelvis_world / scale - J0,
                np.asarray(betas, dtype=np.float64).copy(), gender)


def lowest_point(people: Sequence[EstimatedPerson]) -> float:
    """The lowest y (world, metres) of the people's posed meshes (the feet, for standing people)."""
    from smplik.body_model import load_body_model

    lowest = np.inf
    for p in people:
        model = load_body_model(p.gender)

        def t(x: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=np.float32))[None]

        with torch.no_grad():
            verts, _ = model.vertices(t(p.global_orient), t(p.body_pose), t(p.transl), t(p.betas))
        lowest = min(lowest, float(verts[0, :, 1].min()))
    return lowest


def put_on_ground(people: Sequence[EstimatedPerson]) -> tuple[list[EstimatedPerson], GroundRecord]:
    """``--ground``: move every person up by the same amount so the lowest point of all is at y = 0.

    One shift for the whole scene keeps the people's relative placement and the camera (now at
    ``(0, shift, 0)``, recorded in the returned :class:`GroundRecord`), so overlays still fit.
    """
    shift = -lowest_point(people)
    moved = [dataclasses.replace(p, transl=p.transl + np.array([0.0, shift, 0.0])) for p in people]
    return moved, GroundRecord(shift)


def scene_from_people(
    people: Sequence[EstimatedPerson],
    solver: TensorSolver,
    *,
    config: RecoveryConfig | None = None,
    character: CustomCharacter | None = None,
    skeleton: SkeletonSource | None = None,
    source: str | None = None,
    image: str | None = None,
    ground: bool = False,
    progress: Progress | None = None,
) -> tuple[Scene, list[PersonResult]]:
    """Build an editable scene from estimated people (see the module docstring).

    ``ground``: first move the people onto a floor (:func:`put_on_ground`). Recovery runs for all
    people at once (:func:`workflows.scene.recovery.recover_many`); ``progress`` is called after each step.
    """
    config = RecoveryConfig() if config is None else config
    ground_record = None
    if ground:
        people, ground_record = put_on_ground(people)
    unique_ids = len({p.person_id for p in people}) == len(people)
    names, bodies, targets = [], [], []
    for i, person in enumerate(people):
        names.append(f"person_{person.person_id if unique_ids else i}")
        if character is None:
            bodies.append((person.betas, person.gender, 1.0))
        else:
            bodies.append((character.betas, character.gender, character.scale))
        targets.append(retarget_to_body(person, *bodies[-1]))
    # all people at once: one batched solve per greedy step (workflows.scene.recovery.recover_many)
    recs = recover_many(solver, [TargetPose.from_pose(t) for t in targets], config,
                        scales=[b[2] for b in bodies],
                        progress=None if progress is None else lambda k, n: progress(k, n, f"{len(people)} people"))
    characters = []
    results = []
    for name, (betas, gender, scale), target, rec in zip(names, bodies, targets, recs, strict=True):
        custom = smpl_to_custom(rec.pose, character) if character is not None else None
        characters.append(SceneCharacter(name, gender, np.asarray(betas, dtype=np.float64), float(scale),
                                         skeleton, rec.effectors, rec.pose))
        results.append(PersonResult(name, target, rec, custom))
    camera = next((p.camera for p in people if p.camera is not None), None)
    return Scene(tuple(characters), source, image, camera, ground_record), results


@dataclass(frozen=True)
class EstimateOutputs:
    """Files written by :func:`from_estimate`."""

    scene: Path
    previews: tuple[Path, ...]
    plots: tuple[Path, ...]
    bvh: tuple[Path, ...]
    results: tuple[PersonResult, ...]
    notes: tuple[str, ...] = ()
    """One-line remarks for the user (e.g. an ``--image`` that could not be overlaid)."""
    character: CustomCharacter | None = None

    @property
    def all_files(self) -> tuple[Path, ...]:
        return (self.scene, *self.previews, *self.plots, *self.bvh)


def from_estimate(
    results_path: str | Path,
    out_dir: str | Path,
    solver: TensorSolver,
    *,
    format: str = "auto",
    character_path: str | Path | None = None,
    rig: str | None = None,
    character_options: CharacterOptions | None = None,
    config: RecoveryConfig | None = None,
    trust_pickle: bool = False,
    image_path: str | Path | None = None,
    frame: int = 0,
    previews: bool = True,
    max_people: int | None = None,
    max_bytes: int | None = None,
    ground: bool = False,
    space: str | None = None,
    focal: float | None = None,
    progress: Progress | None = None,
) -> EstimateOutputs:
    """Estimator output -> ``out_dir/scene.json`` (+ previews, recovery plots, BVH with a character).

    ``character_options`` say how ``character_path`` is read (``rig`` overrides their rig); they are
    stored in the scene's skeleton source. Previews: ``scene.png`` (over the image with the estimator's
    camera when ``image_path`` is given,
    plus front and side views), ``<person>_character.png`` with a custom character; plots:
    ``<person>_recovery.png``; BVH: ``<person>.bvh`` (the posed custom character, its own skeleton).

    ``focal``: a focal length (pixels of ``image_path``) for the overlay camera: it replaces the file's
    (principal point kept), or gives a camera at the world origin to a file that holds none (AMASS-style
    files, GVHMR or WHAM in world space). Without one, such a file's ``image_path`` is recorded in the
    scene but no overlay is drawn, and ``notes`` says so.
    """
    from smplik.output_files import staged_folder

    reads = [results_path, character_path, image_path, getattr(character_options, "map", None)]
    with staged_folder(out_dir, reads=reads) as stage:  # every file or none (no empty folder); none an input
        stage.check(["scene.json", "scene.png"])  # before any work (the per-person names: after reading)
        outputs = _from_estimate_into(
            results_path, stage, solver, format=format, character_path=character_path, rig=rig,
            character_options=character_options, config=config, trust_pickle=trust_pickle, image_path=image_path,
            frame=frame, previews=previews, max_people=max_people, max_bytes=max_bytes, ground=ground, space=space,
            focal=focal, progress=progress)
    return dataclasses.replace(outputs, scene=stage.final(outputs.scene),
                               previews=tuple(stage.final(p) for p in outputs.previews),
                               plots=tuple(stage.final(p) for p in outputs.plots),
                               bvh=tuple(stage.final(p) for p in outputs.bvh))


def _from_estimate_into(results_path: str | Path, stage: Any, solver: TensorSolver, *, format: str,
                        character_path: str | Path | None, rig: str | None,
                        character_options: CharacterOptions | None, config: RecoveryConfig | None,
                        trust_pickle: bool, image_path: str | Path | None, frame: int, previews: bool,
                        max_people: int | None, max_bytes: int | None, ground: bool, space: str | None,
                        focal: float | None, progress: Progress | None) -> EstimateOutputs:
    """:func:`from_estimate`'s work, its files written into ``stage.dir`` (a :class:`smplik.output_files.Stage`)."""
    from workflows.character import export_bvh, load_character
    from workflows.estimators import read_estimate
    from workflows.scene.document import save_scene

    out_dir = stage.dir
    config = RecoveryConfig() if config is None else config
    from workflows.estimators import MAX_BYTES, MAX_PEOPLE
    from workflows.estimators.pose_array import EstimateNote

    with warnings.catch_warnings(record=True) as caught:  # readers' assumptions become notes for the user
        warnings.simplefilter("always", EstimateNote)
        people = read_estimate(results_path, format=format, trust_pickle=trust_pickle, frame=frame,  # type: ignore[arg-type]
                               max_people=MAX_PEOPLE if max_people is None else max_people,
                               max_bytes=MAX_BYTES if max_bytes is None else max_bytes, space=space,  # type: ignore[arg-type]
                               solver=solver if isinstance(solver, IKSolver) else None)  # fits SAM-3D-Body's MHR joints
    for w in caught:
        if not issubclass(w.category, EstimateNote):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    people, notes = _overlay_camera(people, results_path, image_path, focal)
    notes = tuple(str(w.message) for w in caught if issubclass(w.category, EstimateNote)) + notes
    character = skeleton = None
    if character_path is not None:
        options = CharacterOptions() if character_options is None else character_options
        if rig is not None:
            options = dataclasses.replace(options, rig=rig, map=None)
        character = load_character(character_path, options)
        from shape_inversion.rigs import available_presets

        if options.map is not None:
            options = dataclasses.replace(options, map=str(Path(options.map).resolve()))
        elif character.rig.name in available_presets():  # a re-read skips detection
            options = dataclasses.replace(options, rig=character.rig.name)
        # else: mapped by the rig mapper (rig None), which maps a re-read identically
        joint_map = {s: character.names[k] for s, k in character.character.smpl_joints.items()}
        skeleton = SkeletonSource.from_options(str(Path(character_path).resolve()), options, joint_map)
    image_ref = str(Path(image_path).resolve()) if image_path is not None else None
    scene, person_results = scene_from_people(people, solver, config=config, character=character, skeleton=skeleton,
                                              source=str(Path(results_path).resolve()), image=image_ref,
                                              ground=ground, progress=progress)
    names = [f"{r.name}{tail}" for r in person_results
             for tail in (".bvh", *(("_recovery.png", "_character.png") if previews else ()))]
    stage.check(names)  # before the files are made: none of them an input
    scene_path = save_scene(scene, out_dir / "scene.json")
    preview_paths: list[Path] = []
    plot_paths: list[Path] = []
    bvh_paths: list[Path] = []
    for r in person_results:
        if character is not None and r.custom_pose is not None:
            bvh_paths.append(export_bvh(out_dir / f"{r.name}.bvh", character, [r.custom_pose]))
    if previews:
        from smplik.render import save_png
        from workflows.scene.previews import load_image, plot_recovery_errors, render_custom_character, render_scene

        image = load_image(image_path) if image_path is not None and scene.camera is not None else None
        ghosts = [r.target for r in person_results]
        errors = [r.recovery.final_error for r in person_results]
        preview_paths.append(save_png(render_scene(scene, image=image, ghosts=ghosts, errors_m=errors),
                                      out_dir / "scene.png"))
        for r, c in zip(person_results, scene.characters, strict=True):
            plot_paths.append(plot_recovery_errors(r.recovery.errors, out_dir / f"{r.name}_recovery.png",
                                                   title=f"{r.name}: effector recovery",
                                                   threshold_m=config.threshold))
            if character is not None and r.custom_pose is not None:
                img = render_custom_character(character, r.custom_pose, c)
                preview_paths.append(save_png(img, out_dir / f"{r.name}_character.png"))
    return EstimateOutputs(scene_path, tuple(preview_paths), tuple(plot_paths), tuple(bvh_paths),
                           tuple(person_results), notes, character)


def _overlay_camera(people: list[EstimatedPerson], results_path: str | Path, image_path: str | Path | None,
                    focal: float | None) -> tuple[list[EstimatedPerson], tuple[str, ...]]:
    """Apply ``--focal`` to the people's camera; a note when ``--image`` cannot be overlaid (no camera)."""
    from workflows.estimators.base import CameraInfo, EstimateFormatError

    if focal is not None:
        if not (np.isfinite(focal) and focal > 0):
            raise EstimateFormatError(f"--focal must be a positive number of pixels, got {focal}.")
        people = [dataclasses.replace(p, camera=dataclasses.replace(
            p.camera or CameraInfo(), focal_px=float(focal), image_size=None, focal_rule="given")) for p in people]
    if image_path is None or any(p.camera is not None for p in people):
        return people, ()
    return people, (f"{results_path}: this file holds no camera (its people are in a world frame), so --image "
                    f"{image_path} is recorded but not overlaid; GVHMR/WHAM: --space camera; else --focal PX "
                    f"overlays through a camera at the world origin.",)
