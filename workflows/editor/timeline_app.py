"""The editor on an animation: :class:`~workflows.editor.timeline.AnimationTimeline` wired to the browser.

:class:`AnimationEditorApp` is the pose editor (:class:`~workflows.editor.app.EditorApp`, same token and
Origin checks, same gizmos and panels) whose scene is the animation's current frame
(:func:`workflows.animation.files.scene_of`: every track posed at that frame, its effectors when the frame is
a keyframe), plus a *Timeline* panel: play/pause at the source frame rate, a frame slider, previous/next
keyframe and a keyframe list, the blend window and *Apply*.

Edits on a frame (dragging its effectors, adding or deleting some, recovery) change only the shown pose
until they are applied: *Apply* -- and also *Save*, or moving to another frame, so no edit is lost -- runs
:meth:`AnimationTimeline.apply_scene`, i.e. :func:`workflows.animation.keyframe_edit.edit_keyframe`, the code of
``smplik scene edit-keyframe``: the frame is re-solved from its effectors (the solver with refinement, as
the command) and the change blended over the window; frames outside it keep their values bit for bit.
*Undo* takes back the frame's unapplied edits first, then applies, one at a time; *Save* writes the
animation (``smplik-animation``); *Export* writes the animated BVH and GLB of every track
(:func:`workflows.animation.run.export_animation`, as ``scene animate --export``).

Playback runs on its own thread (:meth:`play`): each tick advances as many frames as the source frame
rate says have passed (frames are skipped when drawing is slower) under the editor's lock, so GUI events
keep being served between frames. :meth:`play_step` is one tick (tests call it directly).
Shape, gender and the refinement switch are fixed on an animation (a track has one body; applies use the
refinement) and shown disabled.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser

from workflows.editor.app import EditorApp
from workflows.editor.state import EditorState
from workflows.editor.timeline import AnimationTimeline

NOT_A_KEYFRAME = "(not a keyframe)"
MAX_WINDOW = 120
"""Largest blend window the slider offers (frames on each side; ``scene edit-keyframe --window`` has no cap)."""


class AnimationEditorApp(EditorApp):
    """The editor on an animation's timeline (see the module docstring).

    Args:
        timeline: the animation being edited (its solver applies the edits).
        solver: the solver the frame's drags use (the timeline's, normally).
        host, port, export_dir, write_dirs: as :class:`~workflows.editor.app.EditorApp`.
    """

    def __init__(self, timeline: AnimationTimeline, solver: Any, *, host: str = "127.0.0.1", port: int = 8080,
                 export_dir: str | Path | None = None, write_dirs: tuple[str | Path, ...] = ()) -> None:
        self.timeline = timeline
        self.playing = False
        self._play_stop = threading.Event()
        self._play_thread: threading.Thread | None = None
        state = EditorState(timeline.scene(), solver, path=timeline.path)
        super().__init__(state, host=host, port=port, export_dir=export_dir, write_dirs=write_dirs)

    # ------------------------------------------------------------------------- GUI

    def _build_static(self) -> None:
        """The floor, and the first view facing the active character at the first frame (an animation has no
        backdrop photo)."""
        super()._build_static()
        view = self.state.view()
        forward = view.R_world[0] @ np.array([0.0, 0.0, 1.0])  # SMPL faces +z at rest
        forward[1] = 0.0
        if np.linalg.norm(forward) < 1e-6:
            return
        forward /= np.linalg.norm(forward)
        centre = view.joints[0]
        cam = self.server.initial_camera
        cam.position = tuple(float(v) for v in centre + 3.6 * forward + [0.0, 0.5, 0.0])
        cam.look_at = (float(centre[0]), float(centre[1]) - 0.1, float(centre[2]))

    def _frame_marks(self) -> tuple[Any, ...]:
        """Frame slider marks: the first and last frame labelled, a tick at every keyframe."""
        frames = self.timeline.frames
        ends = {frames.start: str(frames.start), frames.stop - 1: str(frames.stop - 1)}
        return tuple((float(f), ends[f]) for f in ends) + tuple(
            float(k) for k in self.timeline.keyframes() if k not in ends)

    def _build_gui(self, save_path: str, export_dir: str) -> None:
        gui = self.server.gui
        tl = self.timeline
        frames = tl.frames
        with gui.add_folder("Timeline"):
            self.frame_md = gui.add_markdown(self._frame_text())
            self.play_button = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY,
                                              hint=f"Play at the source frame rate ({tl.animation.fps:g} frames/s).")
            self.frame_slider = gui.add_slider("Frame", frames.start, frames.stop - 1, 1, tl.frame,
                                               marks=self._frame_marks(), hint="Ticks: keyframes.")
            self._marked = tuple(tl.keyframes())
            self.prev_key_button = gui.add_button("Previous keyframe", icon=viser.Icon.PLAYER_TRACK_PREV)
            self.next_key_button = gui.add_button("Next keyframe", icon=viser.Icon.PLAYER_TRACK_NEXT)
            self.keyframe_dropdown = gui.add_dropdown("Keyframe", self._keyframe_options(),
                                                      initial_value=self._keyframe_value())
            self.window_slider = gui.add_slider("Blend window", 0, max(1, min(MAX_WINDOW, len(frames))), 1,
                                                min(tl.window, MAX_WINDOW),
                                                hint="An applied edit blends into this many frames on each side.")
            self.apply_button = gui.add_button("Apply", icon=viser.Icon.CHECK, color="green",
                                               hint="Re-solve this frame from its effectors and blend the change "
                                                    "over the window (as smplik scene edit-keyframe).")
        super()._build_gui(save_path, export_dir)
        for handle in (self.gender_dropdown, *self.beta_sliders, self.refine_checkbox):
            handle.disabled = True
        user = self._user
        self.play_button.on_click(user(lambda e: self.toggle_play()))
        self.frame_slider.on_update(user(lambda e: self.goto(int(e.target.value))))
        self.prev_key_button.on_click(user(lambda e: self.jump_keyframe(-1)))
        self.next_key_button.on_click(user(lambda e: self.jump_keyframe(1)))
        self.keyframe_dropdown.on_update(user(lambda e: self._pick_keyframe(e.target.value)))
        self.window_slider.on_update(user(lambda e: setattr(self.timeline, "window", int(e.target.value))))
        self.apply_button.on_click(user(lambda e: self.apply()))

    def _pick_keyframe(self, value: str) -> None:
        """The Keyframe dropdown: go to the keyframe picked; "(not a keyframe)" is a label, not a choice (picked
        on a keyframe it would contradict the header), so the dropdown goes back to what the frame is."""
        if value == NOT_A_KEYFRAME:
            self.keyframe_dropdown.value = self._keyframe_value()
        else:
            self.goto(int(value))

    def _keyframe_options(self) -> list[str]:
        return [NOT_A_KEYFRAME] + [str(k) for k in self.timeline.keyframes()]

    def _keyframe_value(self) -> str:
        return str(self.timeline.frame) if self.timeline.frame in self.timeline.keyframes() else NOT_A_KEYFRAME

    def _frame_text(self) -> str:
        tl = self.timeline
        shown = [c for c in self.state.scene.characters if c.pose is not None]
        effectors = sum(len(c.effectors) for c in shown)
        plural = "" if effectors == 1 else "s"
        kind = f"keyframe, {effectors} effector{plural}" if tl.frame in tl.keyframes() else "not a keyframe"
        return (f"**Frame {tl.frame}** of {tl.frames.start}..{tl.frames.stop - 1} at {tl.animation.fps:g} "
                f"frames/s ({kind})")

    def _sync_gui(self) -> None:
        super()._sync_gui()
        tl = self.timeline
        self.frame_slider.value = tl.frame
        if tuple(tl.keyframes()) != self._marked:  # an apply made a keyframe: tick it (viser has no public
            from viser._gui_api import _build_slider_marks  # setter for slider marks)

            self.frame_slider._marks = _build_slider_marks(self._frame_marks())
            self._marked = tuple(tl.keyframes())
        self.keyframe_dropdown.options = self._keyframe_options()
        self.keyframe_dropdown.value = self._keyframe_value()
        self.window_slider.value = min(tl.window, MAX_WINDOW)
        self.frame_md.content = self._frame_text()
        self.undo_button.disabled = not (self.state.can_undo or tl.can_undo)
        self.redo_button.disabled = not (self.state.can_redo or (not self.state.can_undo and tl.can_redo))

    def _draw_character(self, i: int) -> None:
        super()._draw_character(i)
        present = self.state.scene.characters[i].pose is not None  # a track that does not cover this frame
        for handles in (self._meshes, self._skeletons, self._own_meshes):
            if i in handles:
                handles[i].visible = present

    # ------------------------------------------------------------------------- the timeline

    def pending(self) -> list[str]:
        """Names of the tracks whose effectors on this frame were edited and not applied yet."""
        before = {c.name: [e.to_dict() for e in c.effectors] for c in self.timeline.scene().characters}
        return [c.name for c in self.state.scene.characters
                if c.effectors and [e.to_dict() for e in c.effectors] != before.get(c.name)]

    def apply(self) -> list[str]:
        """Apply this frame's edited effectors to the motion (the Apply button); returns the tracks edited."""
        with self._lock:
            changed = self.timeline.apply_scene(self.state.scene)
            if changed:
                self._show_frame()
                self._set_status(f"Applied frame {self.timeline.frame} of {', '.join(changed)}, blended over "
                                 f"±{self.timeline.window} frames.")
            return changed

    def goto(self, frame: int) -> None:
        """Show source frame ``frame`` (edits on the frame shown are applied first)."""
        with self._lock:
            if frame == self.timeline.frame:
                return
            if frame not in self.timeline.frames:
                self.timeline.set_frame(frame)  # the one-line error, before anything is applied
            self._move(lambda: self.timeline.set_frame(frame))

    def jump_keyframe(self, direction: int) -> int:
        """Go to the next (1) or previous (-1) keyframe; returns the frame shown."""
        return self._move(lambda: self.timeline.next_keyframe(direction))

    def _move(self, move: Callable[[], int]) -> int:
        """Apply the frame's edits, move the timeline (``move`` returns the new frame) and show that frame."""
        with self._lock:
            self.apply()
            frame = move()
            self._show_frame()
            return frame

    def _show_frame(self) -> None:
        self.state.replace_scene(self.timeline.scene())
        self.refresh()

    def undo(self) -> bool:
        """The frame's unapplied edits first, then the last apply."""
        if self.state.can_undo:
            return self.state.undo()
        if self.timeline.undo():
            self._show_frame()
            self._set_status(f"Undid an apply; showing frame {self.timeline.frame}.")
            return True
        return False

    def redo(self) -> bool:
        """The frame's undone edits first; an undone apply only when the frame has no edits of its own."""
        if self.state.can_redo:
            return self.state.redo()
        if not self.state.can_undo and self.timeline.redo():
            self._show_frame()
            return True
        return False

    def save(self) -> Path:
        """Apply the frame's edits, then write the animation to the File field's path (the Save button)."""
        with self._lock:
            self.apply()
            path = self.timeline.save(self._writable(Path(self.path_text.value), "Save"))
            self._set_status(f"Saved {path} at {time.strftime('%H:%M:%S')}.")
            return path

    def export(self) -> list[Path]:
        """Apply the frame's edits, then write every track's animated BVH and GLB into the Export folder."""
        from workflows.animation.run import export_animation

        with self._lock:
            self.apply()
            base = self.timeline.path.parent if self.timeline.path is not None else None
            self.last_exported = export_animation(self.timeline.animation,
                                                  self._writable(Path(self.export_text.value), "Export"),
                                                  ("bvh", "glb"), base_dir=base)
            self._set_status("Exported " + ", ".join(p.name for p in self.last_exported) + ".")
            return self.last_exported

    # ------------------------------------------------------------------------- playback

    def play_step(self, count: int = 1) -> int:
        """Advance ``count`` frames (wrapping at the end) and show the frame; one playback tick."""
        return self._move(lambda: self.timeline.step(count))

    def toggle_play(self) -> None:
        """The Play/Pause button."""
        if self.playing:
            self.pause()
        else:
            self.play()

    def play(self) -> None:
        """Start playing at the source frame rate on a background thread."""
        with self._lock:
            if self.playing:
                return
            self.playing = True
            self._play_stop = threading.Event()
            self.play_button.label, self.play_button.icon = "Pause", viser.Icon.PLAYER_PAUSE
            self._play_thread = threading.Thread(target=self._play_loop, args=(self._play_stop,), daemon=True,
                                                 name="smplik-editor-playback")
            self._play_thread.start()

    def pause(self) -> None:
        """Stop playing (the frame shown stays). The playback thread shows no frame after this returns."""
        with self._lock:
            self._play_stop.set()
            self.playing = False
            self.play_button.label, self.play_button.icon = "Play", viser.Icon.PLAYER_PLAY

    def _tick(self, stop: threading.Event, count: int) -> bool:
        """One playback tick unless ``stop`` was set meanwhile; False when playback is over."""
        with self._lock:
            if stop.is_set():
                return False
            try:
                self.play_step(count)
            except (ValueError, OSError) as exc:  # an edit that cannot be applied: stop and say why
                self._set_status(f"**error:** {exc}")
                self.pause()
                return False
            return True

    def _play_loop(self, stop: threading.Event) -> None:
        """Show the frame the source frame rate says is due, until ``stop`` is set."""
        frame_time = self.timeline.frame_time
        start, shown = time.monotonic(), 0
        while not stop.is_set():
            due = int((time.monotonic() - start) / frame_time)
            if due > shown:
                if not self._tick(stop, due - shown):
                    return
                shown = due
            stop.wait(max(0.0, start + (shown + 1) * frame_time - time.monotonic()))

    def _drag_start(self, k: int) -> None:
        if self.playing:
            self.pause()
        super()._drag_start(k)

    def stop(self) -> None:
        self.pause()
        if self._play_thread is not None and self._play_thread is not threading.current_thread():
            self._play_thread.join(timeout=10.0)
        super().stop()
