"""The pose editor's state: the scene being edited, the selection and the undo/redo history.

Plain Python (no viser): :mod:`workflows.editor.app` wires it to the browser, tests drive it
directly. Every edit builds a new immutable :class:`~workflows.scene.Scene` (re-solving the edited
character with :func:`workflows.scene.solve_character`, the code path of ``smplik scene solve``)
and pushes the previous :class:`Snapshot` on the undo stack. Consecutive edits with the same
*gesture key* (one gizmo drag, one slider being moved) merge into one undo step until
:meth:`EditorState.end_gesture`.

A drag of an effector relaxes the effectors on its chain that it makes stale and re-poses only that chain
(:mod:`workflows.scene.edits`); :meth:`EditorState.conflicts` reports which effectors are not met and which
others they contradict.

Spaces are those of :mod:`workflows.scene`: effectors and everything drawn are in character space
(the SMPL body scaled by ``scale`` about the world origin); poses are in SMPL space.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import JOINT_NAMES, NUM_BETAS, NUM_JOINTS, EffectorType, Gender, joint_index
from smplik.effectors import Effector
from smplik.pose import Pose
from smplik.refine import RefineConfig
from smplik.variants import Variant
from workflows.editor.skinning import ShapedBody, Skinner
from workflows.scene import Scene, SceneCharacter, load_scene, save_scene, solve_character
from workflows.scene.edits import ConflictReport, conflict_report, pulling_effectors, relax_stale, solve_drag
from workflows.scene.variants import with_variant

EFFECTOR_TYPES: tuple[str, ...] = tuple(t.name.lower() for t in EffectorType)
"""Effector type names, in :class:`~smplik.conventions.EffectorType` order."""
LOOK_AT_DIRECTION = (0.0, 0.0, 1.0)
"""A new look-at effector aims the joint's forward axis (+z in its frame: SMPL faces +z at rest)."""
LOOK_AT_DISTANCE = 0.5
"""Distance (metres, character space) of a new look-at effector's target from its joint."""
BETA_RANGE = (-3.0, 3.0)
"""Range of the shape sliders."""


class EditorError(ValueError):
    """An edit that cannot be applied (no such character or effector, bad value); the message says why."""


@dataclass(frozen=True)
class Snapshot:
    """Everything an undo step restores."""

    scene: Scene
    active: int
    selected: int | None
    refine: bool


@dataclass(frozen=True, eq=False)
class CharacterView:
    """What is drawn for one character, in character space.

    Attributes:
        vertices: (V, 3) float32 posed SMPL mesh; faces: (F, 3) int32.
        joints: (24, 3) posed joints; R_world: (24, 3, 3) their global rotations.
    """

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    R_world: np.ndarray


def fresh_scene() -> Scene:
    """A scene of one neutral body in the T-pose, without effectors."""
    return Scene((SceneCharacter("body", Gender.NEUTRAL, np.zeros(NUM_BETAS)),))


def rest_pose(character: SceneCharacter) -> Pose:
    """The character's T-pose (zero rotations and translation) in SMPL space."""
    return Pose(np.zeros(3), np.zeros((NUM_JOINTS - 1, 3)), np.zeros(3), np.asarray(character.betas, np.float64),
                character.gender)


def nearest_joint(joints: np.ndarray, ray_origin: Sequence[float], ray_direction: Sequence[float]) -> int:
    """The joint closest to a picking ray (a click). joints (24, 3); ties go to the joint nearer the origin."""
    o = np.asarray(ray_origin, np.float64)
    d = np.asarray(ray_direction, np.float64)
    d = d / max(np.linalg.norm(d), 1e-12)
    rel = np.asarray(joints, np.float64) - o
    along = np.clip(rel @ d, 0.0, None)
    dist = np.linalg.norm(rel - along[:, None] * d, axis=1)
    return int(np.lexsort((along, np.round(dist, 4)))[0])


def _rebase(name: str | None, old_dir: Path | None, new_dir: Path) -> str | None:
    """A path stored relative to the old scene folder, rewritten for a scene saved in ``new_dir``."""
    if name is None or old_dir is None or Path(name).is_absolute() or old_dir.resolve() == new_dir.resolve():
        return name
    return str((old_dir / name).resolve())


class UndoStacks:
    """Undo and redo of an editable model keeping past and undone states in ``_undo`` / ``_redo``; the model
    says what its state is (:meth:`_history_state`) and how to go back to one (:meth:`_restore`)."""

    _undo: list[Any]
    _redo: list[Any]

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    def undo(self) -> bool:
        """Restore the state before the last edit; False when there is nothing to undo."""
        return self._step(self._undo, self._redo)

    def redo(self) -> bool:
        """Re-apply the last undone edit; False when there is nothing to redo."""
        return self._step(self._redo, self._undo)

    def _step(self, source: list[Any], target: list[Any]) -> bool:
        if not source:
            return False
        target.append(self._history_state())
        self._restore(source.pop())
        return True

    def _history_state(self) -> Any:
        raise NotImplementedError

    def _restore(self, state: Any) -> None:
        raise NotImplementedError


class EditorState(UndoStacks):
    """The editor's model (see the module docstring).

    Args:
        scene: the scene to edit (e.g. :func:`workflows.scene.load_scene`, or :func:`fresh_scene`).
        solver: an :class:`smplik.solver.IKSolver` (anything with ``solve`` and ``solve_tensors``
            that is a dataclass with a ``refine`` field).
        path: where :meth:`save` writes by default (the scene file).
        refine: solve with the solver's effector refinement (False: the network alone).
        max_history: undo steps kept.
        relax_on_drag: see :attr:`relax_on_drag`.
    """

    def __init__(self, scene: Scene, solver: Any, *, path: str | Path | None = None, refine: bool = True,
                 max_history: int = 500, relax_on_drag: bool = True) -> None:
        if not scene.characters:
            raise EditorError("The scene has no character to edit.")
        self._solver = solver
        self._solver_raw = dataclasses.replace(solver, refine=RefineConfig(iterations=0))
        self.path = None if path is None else Path(path)
        self._loaded_from = self.path.parent if self.path is not None else None
        self._now = Snapshot(scene, 0, None, refine)
        self._undo: list[Snapshot] = []
        self._redo: list[Snapshot] = []
        self._gesture: Hashable | None = None
        self._max_history = max_history
        self.version = 0
        """Increments on every change (edits, undo, redo, selection)."""
        self._reference = {i: c.pose for i, c in enumerate(scene.characters)}
        self._skinners: dict[Gender, Skinner] = {}
        self._shaped: dict[int, tuple[Gender, ShapedBody]] = {}
        self._views: dict[int, tuple[SceneCharacter, CharacterView]] = {}
        self._customs: dict[tuple[Any, ...], Any] = {}
        self.relax_on_drag = relax_on_drag
        """A drag relaxes the effectors it makes stale and moves only the dragged chain
        (:mod:`workflows.scene.edits`); False: every effector kept as it is and the whole body re-solved."""
        self.relaxed: tuple[str, ...] = ()
        """Labels of the effectors the last drag relaxed (tolerance raised to
        :data:`workflows.scene.edits.RELAXED_TOLERANCE`); shown by the editor."""
        self._drag_base: Pose | None = None
        self._pulling: tuple[SceneCharacter, int, tuple[int, ...]] | None = None
        self._reports: dict[int, tuple[SceneCharacter, ConflictReport]] = {}
        self._variants: tuple[int, SceneCharacter, tuple[Variant, ...]] | None = None
        self._variant_index = 0
        self._variant_views: dict[tuple[int, int], tuple[SceneCharacter, CharacterView]] = {}

    @classmethod
    def open(cls, path: str | Path, solver: Any, **kwargs: Any) -> EditorState:
        """Edit the scene file at ``path`` (SceneError naming the file and JSON path when invalid)."""
        return cls(load_scene(path), solver, path=path, **kwargs)

    def replace_scene(self, scene: Scene) -> None:
        """Edit another scene with the same characters (an animation's frame on the timeline): the undo
        history, selection and estimated poses start afresh; the active character, the refinement switch
        and the shaped bodies (skinning caches) are kept."""
        if len(scene.characters) != len(self.scene.characters):
            raise EditorError(f"The new scene has {len(scene.characters)} characters, not "
                              f"{len(self.scene.characters)}.")
        self._now = Snapshot(scene, self.active, None, self.refine)
        self._undo.clear()
        self._redo.clear()
        self._gesture = None
        self._reference = {i: c.pose for i, c in enumerate(scene.characters)}
        self._views.clear()
        self._reports.clear()
        self.relaxed = ()
        self._drag_base = None
        self.version += 1

    # ------------------------------------------------------------------------- read access

    @property
    def scene(self) -> Scene:
        return self._now.scene

    @property
    def active(self) -> int:
        """Index of the character being edited."""
        return self._now.active

    @property
    def selected(self) -> int | None:
        """Index of the selected effector of the active character (None: none)."""
        return self._now.selected

    @property
    def refine(self) -> bool:
        return self._now.refine

    def character(self, index: int | None = None) -> SceneCharacter:
        """The character at ``index`` (default: the active one)."""
        i = self.active if index is None else self._check_character(index)
        return self.scene.characters[i]

    def effector_labels(self, index: int | None = None) -> list[str]:
        """``"0: left_wrist position"``-style labels of a character's effectors."""
        return [f"{k}: {e.joint_name} {e.type.name.lower()}" for k, e in enumerate(self.character(index).effectors)]

    def view(self, index: int | None = None) -> CharacterView:
        """The posed mesh and joints of a character (cached until that character changes)."""
        i = self.active if index is None else self._check_character(index)
        c = self.scene.characters[i]
        if i == self.active and self.variant_index:  # previewing a variant of this character
            key = (i, self.variant_index)
            cached_variant = self._variant_views.get(key)
            if cached_variant is None or cached_variant[0] is not c:
                posed = with_variant(c, self.variants[self.variant_index])
                cached_variant = (c, self._compute_view(i, posed))
                self._variant_views[key] = cached_variant
            return cached_variant[1]
        cached = self._views.get(i)
        if cached is not None and cached[0] is c:
            return cached[1]
        view = self._compute_view(i, c)
        self._views[i] = (c, view)
        return view

    def view_key(self, index: int | None = None) -> tuple[SceneCharacter, int]:
        """What :meth:`view` of a character depends on: the character record and the previewed variant (0: none);
        the drawing is up to date while this is unchanged (compare records with ``is``)."""
        i = self.active if index is None else self._check_character(index)
        return self.scene.characters[i], self.variant_index if i == self.active else 0

    def conflicts(self, index: int | None = None) -> ConflictReport:
        """The conflict report of a character (:func:`workflows.scene.edits.conflict_report`: per effector its
        residual and the effectors it contradicts); cached until that character changes. Right after a drag it
        names only the effectors that pull against the dragged one
        (:func:`workflows.scene.edits.pulling_effectors`)."""
        i = self.active if index is None else self._check_character(index)
        c = self.scene.characters[i]
        cached = self._reports.get(i)
        if cached is not None and cached[0] is c:
            return cached[1]
        report = conflict_report(c, self._current_solver())
        pulling = self._pulling
        if pulling is not None and pulling[0] is c and i == self.active:  # after a drag: only what pulls
            k, names = pulling[1], set(pulling[2])
            entries = tuple(dataclasses.replace(
                e, drag_solved=True, conflicts_with=tuple(names) if e.index == k else
                tuple(j for j in e.conflicts_with if j == k and e.index in names)) for e in report.entries)
            report = dataclasses.replace(report, entries=entries)
        self._reports[i] = (c, report)
        return report

    def drag_summary(self) -> str:
        """Markdown for the editor's status line after a drag: what it relaxed and the effectors in conflict
        (residual, what is allowed, which effectors they contradict)."""
        parts = []
        if self.relaxed:
            parts.append("Relaxed (tolerance raised): " + ", ".join(self.relaxed) + ".")
        report = self.conflicts()
        if not report.conflicts:
            parts.append("No conflicting effectors.")
        for e in report.conflicts:
            others = ", ".join(report.entries[j].label() for j in e.conflicts_with) or "-"
            what = "not met" if not e.met else "forced"
            parts.append(f"**{e.label()}** {what}: {e.residual:.1f} {e.unit} (allowed {e.allowed:.1f}; network "
                         f"alone {e.network_residual:.1f}); contradicts {others}")
        return "  \n".join(parts)

    # ------------------------------------------------------------------------- selection

    def select_character(self, index: int) -> None:
        i = self._check_character(index)
        if i != self.active:
            self._now = dataclasses.replace(self._now, active=i, selected=None)
            self._gesture = None
            self.version += 1

    def select_effector(self, index: int | None) -> None:
        if index is not None:
            self._check_effector(index)
        if index != self.selected:
            self._now = dataclasses.replace(self._now, selected=index)
            self.version += 1

    def pick_joint(self, ray_origin: Sequence[float], ray_direction: Sequence[float],
                   index: int | None = None) -> str:
        """The name of the character's joint nearest a click ray (character space)."""
        return JOINT_NAMES[nearest_joint(self.view(index).joints, ray_origin, ray_direction)]

    # ------------------------------------------------------------------------- edits

    def add_effector(self, joint: str | int, kind: str | EffectorType = "position", *,
                     tolerance: float = 0.0) -> int:
        """Add an effector on ``joint`` holding the joint's current position / rotation / heading;
        select it and return its index."""
        try:
            j = joint_index(joint)
            t = EffectorType.parse(kind)
        except ValueError as exc:
            raise EditorError(str(exc)) from None
        view = self.view()
        if t == EffectorType.POSITION:
            eff = Effector.position(j, view.joints[j], tolerance)
        elif t == EffectorType.ROTATION:
            eff = Effector.rotation(j, view.R_world[j], tolerance)
        else:
            d = np.asarray(LOOK_AT_DIRECTION)
            target = view.joints[j] + LOOK_AT_DISTANCE * (view.R_world[j] @ d)
            eff = Effector.look_at(j, target, d, tolerance)
        c = self.character()
        self._edit(dataclasses.replace(c, effectors=c.effectors + (eff,)), selected=len(c.effectors), hold=True)
        return len(c.effectors)

    def delete_effector(self, index: int | None = None) -> None:
        """Delete an effector (default: the selected one)."""
        k = self._effector_or_selected(index)
        c = self.character()
        effs = c.effectors[:k] + c.effectors[k + 1:]
        self._edit(dataclasses.replace(c, effectors=effs), selected=None, hold=True)

    def move_effector(self, index: int, *, position: Sequence[float] | None = None,
                      rotation: np.ndarray | None = None) -> None:
        """Move an effector: ``position`` (3,) for position effectors and look-at targets,
        ``rotation`` (3, 3) ``R_world_joint`` for rotation effectors (character space).

        Consecutive moves of the same effector are one undo step until :meth:`end_gesture`. With
        :attr:`relax_on_drag` (the default) the first move of a drag raises the tolerance of the effectors it
        makes stale (:func:`workflows.scene.edits.relax_stale`, listed in :attr:`relaxed`) and every move re-solves
        the dragged chain on the pose the drag started from (:func:`workflows.scene.edits.solve_drag`).
        """
        k = self._check_effector(index)
        c = self.character()
        e = c.effectors[k]
        try:
            if e.type == EffectorType.ROTATION:
                if rotation is None:
                    raise EditorError(f"Effector {k} ({e.joint_name}) is a rotation effector: give rotation=.")
                new = Effector.rotation(e.joint, np.asarray(rotation, np.float64), e.tolerance)
            else:
                if position is None:
                    raise EditorError(f"Effector {k} ({e.joint_name}) is a {e.type.name.lower()} effector: "
                                      "give position=.")
                if e.type == EffectorType.POSITION:
                    new = Effector.position(e.joint, position, e.tolerance)
                else:
                    new = Effector.look_at(e.joint, position, e.direction, e.tolerance)
        except EditorError:
            raise
        except ValueError as exc:
            raise EditorError(str(exc)) from None
        gesture = ("move", self.active, k)
        moved = self._with_effector(c, k, new)
        if gesture != self._gesture or not self._undo:  # a new drag: relax what it makes stale, remember the pose
            effectors, relaxed = relax_stale(moved.effectors, k) if self.relax_on_drag else (moved.effectors, ())
            moved = dataclasses.replace(moved, effectors=effectors)
            self._drag_base = c.pose
            self.relaxed = tuple(f"{i}: {effectors[i].joint_name} {effectors[i].type.name.lower()}" for i in relaxed)
        self._edit(moved, selected=k, gesture=gesture, moved=k)
        self._pulling = None
        solved = self.character()
        if self.relax_on_drag and self._drag_base is not None and solved.pose is not None:
            base = dataclasses.replace(self._drag_base, betas=np.asarray(solved.betas, np.float64),
                                       gender=solved.gender, joints=None)
            self._pulling = (solved, k, pulling_effectors(self._current_solver(), solved.effectors, base,
                                                          solved.pose, k, scale=solved.scale))

    def set_tolerance(self, tolerance: float, index: int | None = None) -> None:
        """Set an effector's tolerance in [0, 1] (default: the selected effector)."""
        k = self._effector_or_selected(index)
        c = self.character()
        try:
            new = dataclasses.replace(c.effectors[k], tolerance=float(tolerance))
        except ValueError as exc:
            raise EditorError(str(exc)) from None
        self._edit(self._with_effector(c, k, new), selected=k, gesture=("tolerance", self.active, k), hold=True)

    def set_beta(self, component: int, value: float) -> None:
        """Set one shape component of the active character."""
        if not 0 <= int(component) < NUM_BETAS:
            raise EditorError(f"Shape component {component} is out of range [0, {NUM_BETAS - 1}].")
        if not np.isfinite(value):
            raise EditorError(f"beta {component}: {value} is not a finite number.")
        c = self.character()
        betas = np.array(c.betas, np.float64)
        betas[int(component)] = float(value)
        self._edit(dataclasses.replace(c, betas=betas), gesture=("beta", self.active, int(component)))

    def set_gender(self, gender: str | Gender) -> None:
        try:
            g = Gender.parse(gender)
        except ValueError as exc:
            raise EditorError(str(exc)) from None
        c = self.character()
        if g != c.gender:
            self._edit(dataclasses.replace(c, gender=g))

    def set_refine(self, refine: bool) -> None:
        """Switch the effector refinement on or off; re-solves every character (one undo step)."""
        if bool(refine) == self.refine:
            return
        self._push()
        self._now = dataclasses.replace(self._now, refine=bool(refine))
        chars = tuple(self._solve(c) for c in self.scene.characters)
        self._now = dataclasses.replace(self._now, scene=dataclasses.replace(self.scene, characters=chars))
        self.version += 1

    def recover(self, max_effectors: int = 8, *, threshold: float = 0.0) -> tuple[float, ...]:
        """Greedy effector recovery (:func:`workflows.scene.recovery.recover_effectors`) of the active character's
        estimated pose (the pose it had when the scene was opened; the current pose without one).
        Replaces its effectors; returns the error (metres) after each recovered effector."""
        from workflows.scene.recovery import RecoveryConfig, TargetPose, recover_effectors

        if int(max_effectors) < 1:
            raise EditorError(f"max effectors must be >= 1, got {max_effectors}.")
        c = self.character()
        target = self._reference.get(self.active) or c.pose or rest_pose(c)
        target = dataclasses.replace(target, betas=np.asarray(c.betas, np.float64), gender=c.gender, joints=None)
        cfg = RecoveryConfig(max_effectors=int(max_effectors), threshold=float(threshold))
        result = recover_effectors(self._current_solver(), TargetPose.from_pose(target), cfg, scale=c.scale)
        self._edit(dataclasses.replace(c, effectors=result.effectors), selected=None)
        return result.errors

    # ------------------------------------------------------------------------- variants

    @property
    def variants(self) -> tuple[Variant, ...]:
        """The variants (:mod:`smplik.variants`) last generated for the active character, while its effectors, shape
        and pose are unchanged (any edit, undo or a change of character drops them); SMPL space."""
        if self._variants is None:
            return ()
        i, c, variants = self._variants
        if i != self.active or self.scene.characters[i] is not c:
            self._variants, self._variant_index = None, 0
            self._variant_views.clear()
            return ()
        return variants

    @property
    def variant_index(self) -> int:
        """The variant shown in place of the active character's pose (0: its own pose, the plain solve)."""
        return self._variant_index if self.variants else 0

    def generate_variants(self, k: int = 4, *, seed: int = 0, candidates: int = 32) -> int:
        """Up to ``k`` alternative poses for the active character's effectors (variant 0: its current solve) with
        :func:`workflows.scene.variants.character_variants` (floor at y = 0 when the scene has a ground record);
        shows variant 0 and returns how many there are. Not an edit: nothing to undo."""
        from workflows.scene.variants import character_variants

        c = self.character()
        floor = 0.0 if self.scene.ground is not None else None
        try:
            variants = character_variants(c, self._current_solver(), k, seed=seed, candidates=candidates,
                                          floor=floor)
        except ValueError as exc:
            raise EditorError(str(exc)) from None
        self._variants = (self.active, c, tuple(variants))
        self._variant_index = 0
        self._variant_views.clear()
        self.version += 1
        return len(variants)

    def preview_variant(self, index: int) -> None:
        """Show variant ``index`` (0..len(variants) - 1) in place of the active character's pose."""
        n = len(self.variants)
        if n == 0:
            raise EditorError("No variants: generate them first.")
        if isinstance(index, bool) or not 0 <= int(index) < n:
            raise EditorError(f"No variant {index}: there are {n} (0..{n - 1}).")
        if int(index) != self._variant_index:
            self._variant_index = int(index)
            self.version += 1

    def keep_variant(self, index: int | None = None) -> int:
        """Make a variant (default: the one shown) the character's pose: its guide effectors are added to the
        character's (one undo step; :meth:`save` writes them) and the character re-solved. Returns the number of
        effectors added (0 for variant 0, the current pose: nothing changes)."""
        k = self.variant_index if index is None else index
        self.preview_variant(k)
        variant = self.variants[k]
        if not variant.guides:
            self._variant_index = 0
            self.version += 1
            return 0
        c = self.character()
        self._edit(with_variant(c, variant), selected=None)
        return len(variant.guides)

    def end_gesture(self) -> None:
        """End the current drag / slider gesture: the next edit starts a new undo step."""
        self._gesture = None

    def _history_state(self) -> Any:
        return self._now

    def _restore(self, state: Any) -> None:
        self._now = state
        self._gesture = None
        self.version += 1

    # ------------------------------------------------------------------------- files

    def save(self, path: str | Path | None = None) -> Path:
        """Write the scene (atomically, the ``smplik-scene`` format) to ``path`` (default: :attr:`path`).

        Relative ``image`` / skeleton paths are rewritten when saving into another folder.
        """
        target = Path(path) if path is not None else self.path
        if target is None:
            raise EditorError("No file to save to: give a path.")
        if target.suffix.lower() != ".json":
            raise EditorError(f"Save: {target} must end in .json.")
        scene = self.scene
        new_dir = target.parent
        chars = tuple(c if c.skeleton is None else dataclasses.replace(
            c, skeleton=dataclasses.replace(c.skeleton, path=_rebase(c.skeleton.path, self._loaded_from, new_dir)))
            for c in scene.characters)
        scene = dataclasses.replace(scene, image=_rebase(scene.image, self._loaded_from, new_dir), characters=chars)
        written = save_scene(scene, target)
        self.path = target
        return written

    def export(self, out_dir: str | Path) -> list[Path]:
        """Write the posed characters with the scene exporter (:func:`workflows.scene.export.export_scene`, as
        ``smplik scene export``): a BVH of each character's own skeleton and a posed GLB; all of them or none,
        and none over the scene's own files (its skeletons, image, the scene file)."""
        from smplik.output_files import staged_folder
        from workflows.scene.export import export_names, export_scene, scene_reads

        scene = self._posed_scene()
        reads = [self.path, *scene_reads(scene, self._loaded_from)]
        with staged_folder(Path(out_dir), reads=reads) as stage:
            stage.check(export_names(scene, ("bvh", "glb")))
            written = export_scene(scene, stage.dir, formats=("bvh", "glb"), base_dir=self._loaded_from)
        return [stage.final(p) for p in written]

    def _custom(self, index: int | None) -> tuple[Any, Any] | None:
        """(CustomCharacter, its posed CustomPose) of a character with a custom skeleton, else None.

        The skeleton is read once with the character options the scene stores, at the scene's shape
        (:func:`workflows.character.character_from_estimate`, as ``scene solve`` and ``scene export`` do).
        """
        from workflows.character import smpl_to_custom

        c = self.character(index)
        if c.skeleton is None:
            return None
        src = Path(c.skeleton.path)
        if not src.is_absolute() and self._loaded_from is not None:
            src = self._loaded_from / src
        key = (str(src), c.skeleton, c.gender, tuple(np.round(c.betas, 9)), c.scale)
        if key not in self._customs:
            from workflows.character import character_from_estimate

            self._customs[key] = character_from_estimate(src, c.skeleton.options, c.betas, c.scale, c.gender)
        char = self._customs[key]
        pose = c.pose if c.pose is not None else rest_pose(c)
        return char, smpl_to_custom(dataclasses.replace(pose, betas=c.betas), char)

    def skeleton_bones(self, index: int | None = None) -> np.ndarray | None:
        """Bones (B, 2, 3) of a character's posed custom skeleton (character space), or None without one."""
        from workflows.scene.previews import custom_skeleton_segments

        custom = self._custom(index)
        if custom is None:
            return None
        segments = custom_skeleton_segments(*custom)
        return np.array([[s.start, s.end] for s in segments], np.float64).reshape(-1, 2, 3)

    def own_mesh(self, index: int | None = None) -> tuple[np.ndarray, np.ndarray] | None:
        """The custom character's own skinned mesh, posed (glTF/GLB skins): (vertices (V, 3) character
        space, faces (F, 3)), or None for characters without one (:mod:`workflows.character_mesh`)."""
        from workflows.character_mesh import character_mesh_canon

        custom = self._custom(index)
        return None if custom is None else character_mesh_canon(*custom)

    # ------------------------------------------------------------------------- internals

    def _posed_scene(self) -> Scene:
        """The scene with a pose for every character (the T-pose where none was solved)."""
        chars = tuple(c if c.pose is not None else dataclasses.replace(c, pose=rest_pose(c))
                      for c in self.scene.characters)
        return dataclasses.replace(self.scene, characters=chars)

    def _check_character(self, index: int) -> int:
        n = len(self.scene.characters)
        if not 0 <= int(index) < n:
            raise EditorError(f"No character {index}: the scene has {n} (0..{n - 1}).")
        return int(index)

    def _check_effector(self, index: int) -> int:
        c = self.character()
        if not 0 <= int(index) < len(c.effectors):
            raise EditorError(f"No effector {index} on {c.name}: it has {len(c.effectors)}.")
        return int(index)

    def _effector_or_selected(self, index: int | None) -> int:
        if index is None:
            if self.selected is None:
                raise EditorError("No effector is selected.")
            index = self.selected
        return self._check_effector(index)

    @staticmethod
    def _with_effector(c: SceneCharacter, k: int, new: Effector) -> SceneCharacter:
        return dataclasses.replace(c, effectors=c.effectors[:k] + (new,) + c.effectors[k + 1:])

    def _current_solver(self) -> Any:
        return self._solver if self.refine else self._solver_raw

    def _solve(self, c: SceneCharacter, moved: int | None = None, hold: bool = False) -> SceneCharacter:
        """Re-solve from the effectors; without effectors keep the pose's rotations on the new body. ``moved``:
        the effector being dragged (:func:`workflows.scene.edits.solve_drag` from the pose at the drag's start);
        ``hold``: an edit of the effector list that moves nothing (:meth:`_hold`)."""
        if hold and c.effectors:
            try:
                return self._hold(c)
            except ValueError as exc:
                raise EditorError(f"{c.name}: {exc}") from None
        if c.effectors:
            try:
                if moved is not None and self.relax_on_drag:
                    return solve_drag(c, self._current_solver(), moved, self._drag_base)
                return solve_character(c, self._current_solver())
            except ValueError as exc:
                raise EditorError(f"{c.name}: {exc}") from None
        if c.pose is None:
            return c
        pose = dataclasses.replace(c.pose, betas=np.asarray(c.betas, np.float64), gender=c.gender, joints=None)
        return dataclasses.replace(c, pose=pose)

    def _hold(self, c: SceneCharacter) -> SceneCharacter:
        """After adding, deleting or re-tolerancing an effector: the current pose (the T-pose when none was
        solved) is kept when it meets every effector held more tightly than a relaxed hint
        (:func:`workflows.scene.edits.unmet_effectors`); the ones it misses (a tolerance lowered on an effector
        the pose was not meeting) are solved as drags from it (:func:`workflows.scene.edits.solve_edit`), so
        nothing else moves."""
        from workflows.scene.characters import scale_effector
        from workflows.scene.edits import drag_order, solve_edit, unmet_effectors

        solver = self._current_solver()
        pose = c.pose if c.pose is not None else rest_pose(c)
        pose = dataclasses.replace(pose, betas=np.asarray(c.betas, np.float64), gender=c.gender, joints=None)
        unmet = [i for i, _ in unmet_effectors(c.effectors, pose, c.scale, solver.bodies)]
        order = drag_order(c.effectors, unmet)
        for step, k in enumerate(order):
            pending = set(order[step + 1:])
            smpl = [scale_effector(e, 1.0 / c.scale) for i, e in enumerate(c.effectors) if i not in pending]
            pose = dataclasses.replace(solve_edit(solver, [smpl], [pose], [c.effectors[k].joint])[0], joints=None)
        return dataclasses.replace(c, pose=pose)

    def _push(self) -> None:
        self._undo.append(self._now)
        del self._undo[:-self._max_history]
        self._redo.clear()

    def _edit(self, character: SceneCharacter, *, selected: int | None | str = "keep",
              gesture: Hashable | None = None, moved: int | None = None, hold: bool = False) -> None:
        """Replace the active character (re-solved; ``moved``: the effector a drag moves; ``hold``: the pose is
        kept where the effectors allow, :meth:`_hold`) and record the undo step."""
        solved = self._solve(character, moved, hold)
        if gesture is None or gesture != self._gesture or not self._undo:
            self._push()
        self._gesture = gesture
        chars = list(self.scene.characters)
        chars[self.active] = solved
        sel = self.selected if selected == "keep" else selected
        self._now = dataclasses.replace(self._now, scene=dataclasses.replace(self.scene, characters=tuple(chars)),
                                        selected=sel)
        self.version += 1

    def _skinner(self, gender: Gender) -> Skinner:
        if gender not in self._skinners:
            from smplik.body_model import load_body_model

            self._skinners[gender] = Skinner.from_model(load_body_model(gender))
        return self._skinners[gender]

    def _compute_view(self, i: int, c: SceneCharacter) -> CharacterView:
        from workflows.scene.recovery import TargetPose

        skinner = self._skinner(c.gender)
        gender, body = self._shaped.get(i, (None, None))
        if body is None or gender != c.gender or not np.array_equal(body.betas, np.asarray(c.betas, np.float32)):
            body = skinner.shaped(c.betas)
            self._shaped[i] = (c.gender, body)
        pose = c.pose if c.pose is not None else rest_pose(c)
        pose = dataclasses.replace(pose, betas=np.asarray(c.betas, np.float64), gender=c.gender)
        fk = TargetPose.from_pose(pose)
        R_world, p_world = fk.R_world.numpy(), fk.p_world.numpy()
        R_local = None
        if skinner.posedirs is not None:
            from scipy.spatial.transform import Rotation

            R_local = Rotation.from_rotvec(np.concatenate([pose.global_orient[None], pose.body_pose])).as_matrix()
        verts = skinner.skin(body, R_world, p_world, R_local) * np.float32(c.scale)
        return CharacterView(verts, skinner.faces, p_world.astype(np.float64) * c.scale, R_world.astype(np.float64))
