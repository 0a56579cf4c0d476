"""The pose editor's browser front end: :class:`~workflows.editor.state.EditorState` wired to viser.

Only wiring lives here: every edit goes through the state model, then :meth:`EditorApp.refresh`
pushes what changed to the browser. viser runs callbacks on a thread pool, so edits are serialised
by a lock, and gizmo updates that arrive while a solve is running are coalesced (only the newest
value of each gizmo is solved). Assignments made by this module also fire viser's GUI callbacks
(with ``client=None``); those are ignored, so only a person's input edits the scene.

Scene graph (names): ``/floor`` grid, ``/backdrop`` the source photo, ``/char{i}/mesh`` the SMPL
mesh of character ``i`` (click it to pick the nearest joint), ``/char{i}/skeleton`` a custom
character's bones, ``/gizmo/{k}`` the active character's effector handles (translate for position
and look-at targets, rotate for rotation effectors) and ``/rays/{k}`` look-at rays.
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser

from smplik.conventions import JOINT_NAMES, NUM_BETAS, EffectorType, Gender
from smplik.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from workflows.editor.access import TOKEN_PARAM, AccessGuard, guarded_serve
from workflows.editor.state import BETA_RANGE, EFFECTOR_TYPES, EditorError, EditorState

log = logging.getLogger(__name__)
PALETTE = ((158, 178, 219), (219, 178, 140), (158, 214, 163), (219, 158, 189), (204, 204, 148), (153, 204, 214))
GIZMO_SCALE = 0.18
NO_EFFECTOR = "(none)"
NO_VARIANT = "(none: press Variants)"
VARIANT_COUNT = 4
"""Variants the Variants button asks for (variant 0: the current pose)."""
MAX_IMAGE_SIDE = 1280
IMAGE_WXYZ = (0.0, 1.0, 0.0, 0.0)
"""viser draws an image in OpenCV camera axes (rows along -y down, seen from -z); a half turn about x
puts row 0 at the top, facing the camera at the origin (the estimator's OpenGL camera looks down -z)."""


class EditorApp:
    """A viser server showing and editing ``state``.

    Only a browser that opened :attr:`url` (which carries a random per-run token) can connect, and only
    from the editor's own origin (:mod:`workflows.editor.access`); viser's share-URL request (a public
    tunnel) is refused; Save and Export write only inside ``write_dirs``.

    Args:
        state: the editor model.
        host, port: where to listen (port 0: any free port; see :attr:`port`).
        export_dir: default folder of Export (default: ``export/`` next to the scene file).
        write_dirs: folders Save and Export may write in (default: the scene file's folder, or the
            working directory for a scene without a file), sub-folders included.
    """

    def __init__(self, state: EditorState, *, host: str = "127.0.0.1", port: int = 8080,
                 export_dir: str | Path | None = None, write_dirs: tuple[str | Path, ...] = ()) -> None:
        self.state = state
        self.access = AccessGuard()
        # viser prints its address without the token: drop that banner (smplik edit prints :attr:`url`)
        with guarded_serve(self.access) as guarded, contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if not guarded:  # a viser that starts its server another way: never run without the check
            self.server.stop()
            raise EditorError(f"viser {viser.__version__} does not start its server through "
                              "websockets.asyncio.server.serve; the editor cannot check who connects "
                              "(install viser>=1.1,<2).")
        self.server.request_share_url = self._refuse_share_url  # type: ignore[method-assign]
        self.server.gui.configure_theme(show_share_button=False)
        base = state.path.parent if state.path is not None else Path.cwd()
        self.write_dirs = tuple(Path(d).expanduser().resolve() for d in (write_dirs or (base,)))
        self._lock = threading.RLock()
        self._pending: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._pending_lock = threading.Lock()
        self._meshes: dict[int, Any] = {}
        self._drawn: dict[int, Any] = {}
        self._skeletons: dict[int, Any] = {}
        self._own_meshes: dict[int, Any] = {}
        self._gizmos: list[Any] = []
        self._rays: dict[int, Any] = {}
        self._gizmo_key: tuple | None = None
        self.status = ""
        self.last_exported: list[Path] = []
        default_export = (state.path.parent if state.path is not None else Path.cwd()) / "export"
        self.server.scene.set_up_direction("+y")
        self._build_static()
        self._build_gui(str(state.path or Path.cwd() / "scene.json"), str(export_dir or default_export))
        self.refresh()

    # ------------------------------------------------------------------------- server

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        """The address to open, with this run's token (the only way in)."""
        host = self.server.get_host()
        shown = "127.0.0.1" if host in ("0.0.0.0", "", "::") else f"[{host}]" if ":" in host else host
        return f"http://{shown}:{self.port}/?{TOKEN_PARAM}={self.access.token}"

    def _refuse_share_url(self, verbose: bool = True) -> None:
        """viser's share-URL request (a public tunnel to this editor through share.viser.studio): refused."""
        log.warning("smplik editor: refused a share-URL request (a public tunnel to the editor).")
        self._set_status("**error:** share URLs (a public tunnel to this editor) are disabled.")

    def _writable(self, path: Path, what: str) -> Path:
        """``path`` resolved, if it lies in one of :attr:`write_dirs`; else an :class:`EditorError`."""
        resolved = path.expanduser().resolve()
        if not any(resolved == d or resolved.is_relative_to(d) for d in self.write_dirs):
            allowed = ", ".join(str(d) for d in self.write_dirs)
            raise EditorError(f"{what}: {path} is outside the folders the editor may write in ({allowed}); "
                              "name another with smplik edit --output-dir.")
        return resolved

    def stop(self) -> None:
        self.server.stop()

    # ------------------------------------------------------------------------- static scene

    def _build_static(self) -> None:
        scene = self.state.scene
        views = [self.state.view(i) for i in range(len(scene.characters))]
        floor = min(float(v.vertices[:, 1].min()) for v in views)
        centre = np.mean([v.joints[0] for v in views], axis=0)
        self.server.scene.add_grid("/floor", width=20.0, height=20.0, plane="xz", cell_size=0.25,
                                   section_size=1.0, position=(float(centre[0]), floor, float(centre[2])))
        cam = self.server.initial_camera
        if self._add_backdrop(views):
            cam.position = (0.0, 0.0, 0.0)  # the estimator's camera: at the origin, looking down -z
            cam.look_at = (0.0, 0.0, float(min(centre[2], -0.5)))
        else:
            cam.position = (float(centre[0]) + 0.6, float(centre[1]) + 0.5, float(centre[2]) + 3.6)
            cam.look_at = (float(centre[0]), float(centre[1]) - 0.1, float(centre[2]))
            cam.fov = float(np.radians(50.0))

    def _add_backdrop(self, views: list[Any]) -> bool:
        """The source photo on a plane behind the characters, seen from the estimator's camera."""
        scene = self.state.scene
        if scene.image is None or scene.camera is None:
            return False
        src = Path(scene.image)
        if not src.is_absolute() and self.state.path is not None:
            src = self.state.path.parent / src
        if not src.is_file():
            return False
        from workflows.scene.previews import load_image

        try:
            image = load_image(src)[..., :3]
        except (OSError, ValueError) as exc:  # an unreadable photo: edit without the backdrop
            self.status = f"backdrop {src} not shown ({exc})"
            return False
        h, w = image.shape[:2]
        f = self.state.scene.camera.focal_for(w, h)
        step = int(np.ceil(max(h, w) / MAX_IMAGE_SIDE))
        depth = 1.5 * max(float(-v.joints[0, 2]) for v in views) + 1.0
        if depth <= 1.0:  # characters not in front of the camera: no backdrop
            return False
        self.server.scene.add_image("/backdrop", np.ascontiguousarray(image[::step, ::step]), w * depth / f,
                                    h * depth / f, position=(0.0, 0.0, -depth), wxyz=IMAGE_WXYZ, cast_shadow=False,
                                    receive_shadow=False)
        self.server.initial_camera.fov = float(2 * np.arctan(h / 2.0 / f))
        return True

    # ------------------------------------------------------------------------- GUI

    def _build_gui(self, save_path: str, export_dir: str) -> None:
        gui = self.server.gui
        s = self.state
        with gui.add_folder("Character"):
            self.character_dropdown = gui.add_dropdown("Character", self._character_labels(),
                                                       initial_value=self._character_labels()[s.active])
            self.gender_dropdown = gui.add_dropdown("Gender", [g.value for g in Gender],
                                                    initial_value=s.character().gender.value)
            self.beta_sliders = [gui.add_slider(f"β{k}", BETA_RANGE[0], BETA_RANGE[1], 0.05,
                                                float(s.character().betas[k])) for k in range(NUM_BETAS)]
        with gui.add_folder("Effectors"):
            self.joint_dropdown = gui.add_dropdown("Joint", list(JOINT_NAMES), initial_value="left_wrist",
                                                   hint="Pick from the list or click the body.")
            self.type_dropdown = gui.add_dropdown("Type", list(EFFECTOR_TYPES), initial_value="position")
            self.add_button = gui.add_button("Add effector", icon=viser.Icon.PLUS)
            self.effector_dropdown = gui.add_dropdown("Effector", [NO_EFFECTOR], initial_value=NO_EFFECTOR)
            self.tolerance_slider = gui.add_slider("Tolerance", 0.0, 1.0, 0.01, 0.0)
            self.delete_button = gui.add_button("Delete effector", icon=viser.Icon.TRASH, color="red")
            self.refine_checkbox = gui.add_checkbox("Refinement", s.refine,
                                                    hint="Levenberg-Marquardt steps after the network.")
        with gui.add_folder("Variants", expand_by_default=False):
            self.variants_button = gui.add_button("Variants", icon=viser.Icon.ARROWS_SHUFFLE,
                                                  hint="Alternative poses that meet the same effectors.")
            self.variant_dropdown = gui.add_dropdown("Variant", [NO_VARIANT], initial_value=NO_VARIANT)
            self.keep_variant_button = gui.add_button("Keep variant", icon=viser.Icon.CHECK,
                                                      hint="Add the shown variant's guide effectors (undoable).")
        with gui.add_folder("Recovery", expand_by_default=False):
            self.max_effectors_slider = gui.add_slider("Max effectors", 1, 16, 1, 8)
            self.recover_button = gui.add_button("Recover effectors",
                                                 hint="Greedy recovery of the scene's estimated pose.")
        with gui.add_folder("History and files"):
            self.undo_button = gui.add_button("Undo", icon=viser.Icon.ARROW_BACK_UP)
            self.redo_button = gui.add_button("Redo", icon=viser.Icon.ARROW_FORWARD_UP)
            self.path_text = gui.add_text("File", save_path)
            self.save_button = gui.add_button("Save", icon=viser.Icon.DEVICE_FLOPPY, color="green")
            self.export_text = gui.add_text("Export folder", export_dir)
            self.export_button = gui.add_button("Export", icon=viser.Icon.FILE_EXPORT)
        self.status_md = gui.add_markdown(self.status)
        user = self._user

        self.character_dropdown.on_update(user(lambda e: self.state.select_character(
            int(e.target.value.split(":")[0]))))
        self.gender_dropdown.on_update(user(lambda e: self.state.set_gender(e.target.value)))
        for k, slider in enumerate(self.beta_sliders):
            slider.on_update(user(lambda e, k=k: self.state.set_beta(k, float(e.target.value))))
        self.add_button.on_click(user(lambda e: self.state.add_effector(self.joint_dropdown.value,
                                                                        self.type_dropdown.value)))
        self.effector_dropdown.on_update(user(lambda e: self.state.select_effector(
            None if e.target.value == NO_EFFECTOR else int(e.target.value.split(":")[0]))))
        self.tolerance_slider.on_update(user(lambda e: self.state.set_tolerance(float(e.target.value))))
        self.delete_button.on_click(user(lambda e: self.state.delete_effector()))
        self.refine_checkbox.on_update(user(lambda e: self.state.set_refine(bool(e.target.value))))
        self.recover_button.on_click(user(lambda e: self._recover()))
        self.variants_button.on_click(user(lambda e: self._generate_variants()))
        self.variant_dropdown.on_update(user(lambda e: None if e.target.value == NO_VARIANT else
                                             self.state.preview_variant(int(e.target.value.split(":")[0]))))
        self.keep_variant_button.on_click(user(lambda e: self._keep_variant()))
        self.undo_button.on_click(user(lambda e: self.undo()))
        self.redo_button.on_click(user(lambda e: self.redo()))
        self.save_button.on_click(user(lambda e: self.save()))
        self.export_button.on_click(user(lambda e: self.export()))

    def _user(self, fn: Callable[[Any], None]) -> Callable[[Any], None]:
        """A GUI callback that runs ``fn(event)`` as an edit (:meth:`_run`) when a person made the change;
        assignments made by this module (``event.client is None``) are ignored."""
        def handler(event: Any) -> None:
            if event.client is None:
                return
            self._run(lambda: fn(event))
        return handler

    def _character_labels(self) -> list[str]:
        return [f"{i}: {c.name}" for i, c in enumerate(self.state.scene.characters)]

    def _run(self, fn: Callable[[], Any]) -> None:
        """Apply one edit under the lock, then refresh; a ValueError / OSError goes to the status line."""
        with self._lock:
            try:
                fn()
            except (ValueError, OSError) as exc:  # EditorError, SceneError, SkeletonError, ...: one line
                self._set_status(f"**error:** {exc}")
            self.refresh()

    def _set_status(self, text: str) -> None:
        self.status = text
        self.status_md.content = text

    def _recover(self) -> None:
        errors = self.state.recover(int(self.max_effectors_slider.value))
        self._set_status(f"Recovered {len(errors)} effectors; error {errors[-1] * 1000:.0f} mm.")

    def _generate_variants(self) -> None:
        n = self.state.generate_variants(VARIANT_COUNT)
        self._set_status(f"{n} variant(s) of {self.state.character().name}: pick one under Variant, then Keep "
                         "variant." if n > 1 else "The effectors leave no room for other plausible poses.")

    def _keep_variant(self) -> None:
        added = self.state.keep_variant()
        self._set_status(f"Kept the variant: {added} guide effector(s) added." if added else
                         "Variant 0 is the current pose: nothing added.")

    def undo(self) -> bool:
        """The Undo button."""
        return self.state.undo()

    def redo(self) -> bool:
        """The Redo button."""
        return self.state.redo()

    def save(self) -> Path:
        """Save to the File field's path (the Save button)."""
        path = self.state.save(self._writable(Path(self.path_text.value), "Save"))
        self._set_status(f"Saved {path} at {time.strftime('%H:%M:%S')}.")
        return path

    def export(self) -> list[Path]:
        """Export into the Export folder field's path (the Export button)."""
        self.last_exported = self.state.export(self._writable(Path(self.export_text.value), "Export"))
        self._set_status("Exported " + ", ".join(p.name for p in self.last_exported) + ".")
        return self.last_exported

    # ------------------------------------------------------------------------- gizmos

    def _on_gizmo(self, k: int, event: Any) -> None:
        """A handle's ``on_update``: drag start (select the effector, new undo step), update, end."""
        if event.client is None:
            return
        phase = getattr(event, "phase", "update")
        if phase == "start":
            self._drag_start(k)
            return
        if phase == "end":
            self._drag_end()
            return
        handle = event.target
        with self._pending_lock:
            self._pending[k] = (np.asarray(handle.position, np.float64), np.asarray(handle.wxyz, np.float64))
        self.process_pending()

    def process_pending(self) -> None:
        """Solve the newest pending gizmo values (a no-op when another thread is already solving)."""
        while True:
            if not self._lock.acquire(blocking=False):
                return  # the holder processes what is pending when it is done
            try:
                with self._pending_lock:
                    pending, self._pending = self._pending, {}
                for k, (position, wxyz) in pending.items():
                    self.drag(k, position, wxyz)
            finally:
                self._lock.release()
            with self._pending_lock:
                if not self._pending:
                    return

    def drag(self, k: int, position: np.ndarray, wxyz: np.ndarray) -> None:
        """A gizmo of effector ``k`` (active character) moved: re-solve and redraw that character."""
        with self._lock:
            e = self.state.character().effectors[k] if k < len(self.state.character().effectors) else None
            if e is None:
                return
            try:
                if e.type == EffectorType.ROTATION:
                    self.state.move_effector(k, rotation=quat_wxyz_to_matrix(wxyz))
                else:
                    self.state.move_effector(k, position=position)
            except EditorError as exc:
                self._set_status(f"**error:** {exc}")
                return
            self._draw_character(self.state.active)
            self._place_gizmos(skip=k)

    def _drag_start(self, k: int) -> None:
        with self._lock:
            self.state.end_gesture()
            if self.state.selected != k:
                self.state.select_effector(k)
                self._sync_gui()

    def _drag_end(self) -> None:
        self.process_pending()
        with self._lock:
            self.state.end_gesture()
            self.refresh()
            self._set_status(self.state.drag_summary())  # what the drag relaxed, which effectors conflict

    def _rebuild_gizmos(self) -> None:
        for g in self._gizmos:
            g.remove()
        for r in self._rays.values():
            r.remove()
        self._gizmos, self._rays = [], {}
        c = self.state.character()
        s = GIZMO_SCALE * c.scale
        for k, e in enumerate(c.effectors):
            rot = e.type == EffectorType.ROTATION
            g = self.server.scene.add_transform_controls(
                f"/gizmo/{k}", scale=s, disable_rotations=not rot, disable_axes=rot, disable_sliders=rot,
                depth_test=False)
            g.on_update(lambda event, k=k: self._on_gizmo(k, event))
            self._gizmos.append(g)
        self._gizmo_key = self._gizmo_signature()
        self._place_gizmos()

    def _gizmo_signature(self) -> tuple:
        c = self.state.character()
        return (self.state.active, tuple((e.joint, int(e.type)) for e in c.effectors))

    def _place_gizmos(self, skip: int | None = None) -> None:
        """Put each handle at its effector (rotation handles at the posed joint) and redraw look-at rays."""
        c = self.state.character()
        joints = self.state.view().joints
        for k, (e, g) in enumerate(zip(c.effectors, self._gizmos, strict=True)):
            if e.type == EffectorType.ROTATION:
                g.position = joints[e.joint]
                if k != skip:
                    g.wxyz = matrix_to_quat_wxyz(e.value)
            else:
                if k != skip:
                    g.position = np.asarray(e.value)
                if e.type == EffectorType.LOOK_AT:
                    pts = np.stack([joints[e.joint], np.asarray(e.value)])[None].astype(np.float32)
                    if k in self._rays:
                        self._rays[k].points = pts
                    else:
                        self._rays[k] = self.server.scene.add_line_segments(
                            f"/rays/{k}", pts, (200, 60, 200), thickness=0.008 * c.scale)

    # ------------------------------------------------------------------------- drawing

    def _draw_character(self, i: int) -> None:
        c, shown = self.state.view_key(i)
        drawn = self._drawn.get(i)
        if drawn is not None and drawn[0] is c and drawn[1] == shown:
            return
        view = self.state.view(i)
        if i in self._meshes:
            self._meshes[i].vertices = view.vertices
        else:
            mesh = self.server.scene.add_mesh_simple(f"/char{i}/mesh", view.vertices, view.faces,
                                                     color=PALETTE[i % len(PALETTE)],
                                                     opacity=None if c.skeleton is None else 0.55)
            mesh.on_click(lambda event, i=i: self._run(lambda: self._pick(i, event)))
            self._meshes[i] = mesh
        if c.skeleton is not None:
            try:
                bones = self.state.skeleton_bones(i)
            except ValueError as exc:  # SkeletonError, RigError, ...: draw without the skeleton
                self._set_status(f"{c.name}: skeleton not shown ({exc})")
                bones = None
            if bones is not None:
                pts = bones.astype(np.float32)
                if i in self._skeletons:
                    self._skeletons[i].points = pts
                else:
                    self._skeletons[i] = self.server.scene.add_line_segments(
                        f"/char{i}/skeleton", pts, (240, 130, 30), thickness=0.012 * c.scale)
                own = self.state.own_mesh(i)  # a glTF/GLB character's own skinned mesh, posed
                if own is not None:
                    if i in self._own_meshes:
                        self._own_meshes[i].vertices = own[0].astype(np.float32)
                    else:
                        self._own_meshes[i] = self.server.scene.add_mesh_simple(
                            f"/char{i}/own_mesh", own[0].astype(np.float32), own[1], color=(217, 184, 153))
        self._drawn[i] = (c, shown)

    def _pick(self, i: int, event: Any) -> None:
        self.state.select_character(i)
        self.joint_dropdown.value = self.state.pick_joint(event.ray_origin, event.ray_direction, i)

    def refresh(self) -> None:
        """Bring the browser up to date with the state (meshes, gizmos, GUI values)."""
        with self._lock:
            with self.server.atomic():
                for i in range(len(self.state.scene.characters)):
                    self._draw_character(i)
                if self._gizmo_signature() != self._gizmo_key:
                    self._rebuild_gizmos()
                else:
                    self._place_gizmos()
                self._sync_gui()

    def _sync_gui(self) -> None:
        s = self.state
        c = s.character()
        self.character_dropdown.value = self._character_labels()[s.active]
        self.gender_dropdown.value = c.gender.value
        for k, slider in enumerate(self.beta_sliders):
            slider.value = float(c.betas[k])
        labels = s.effector_labels()
        self.effector_dropdown.options = [NO_EFFECTOR] + labels
        self.effector_dropdown.value = NO_EFFECTOR if s.selected is None else labels[s.selected]
        self.tolerance_slider.disabled = self.delete_button.disabled = s.selected is None
        if s.selected is not None:
            self.tolerance_slider.value = float(c.effectors[s.selected].tolerance)
        self.refine_checkbox.value = s.refine
        variants = s.variants
        self.variant_dropdown.options = [f"{k}: " + ("current pose" if k == 0 else f"{100 * v.distance_m:.0f} cm away")
                                         for k, v in enumerate(variants)] or [NO_VARIANT]
        self.variant_dropdown.value = self.variant_dropdown.options[s.variant_index]
        self.variant_dropdown.disabled = self.keep_variant_button.disabled = len(variants) < 2
        self.undo_button.disabled = not s.can_undo
        self.redo_button.disabled = not s.can_redo
