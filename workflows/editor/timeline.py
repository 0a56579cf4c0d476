"""The editor's timeline model for animations (plain Python; :mod:`workflows.editor.timeline_app` wires it to
the browser).

:class:`AnimationTimeline` holds an :class:`~workflows.animation.clips.Animation` and what a timeline shows and
does: the current source frame (scrub, step for playback at the source frame rate, jump between
keyframes), the scene of the current frame (:func:`workflows.animation.files.scene_of`, effectors on
keyframes: what :class:`~workflows.editor.state.EditorState` edits), the blend window, and applying a
frame's edited effectors to the motion (:func:`workflows.animation.keyframe_edit.edit_keyframe`: only the
window changes), with undo and redo, and saving through the animation writer.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from smplik.effectors import Effector
from workflows.animation.clips import Animation, AnimationError
from workflows.editor.state import UndoStacks
from workflows.scene import Scene


class AnimationTimeline(UndoStacks):
    """An animation being edited on a timeline (see the module docstring)."""

    def __init__(self, animation: Animation, solver: Any, *, window: int = 10, path: str | Path | None = None
                 ) -> None:
        if not animation.tracks:
            raise AnimationError("the animation has no tracks to edit.")
        self._animation = animation
        self._solver = solver
        self._path = None if path is None else Path(path)
        self._undo: list[Animation] = []
        self._redo: list[Animation] = []
        self.window = window
        self._frame = self.frames.start

    @classmethod
    def open(cls, path: str | Path, solver: Any, **kwargs: Any) -> AnimationTimeline:
        from workflows.animation.files import load_animation

        return cls(load_animation(path), solver, path=path, **kwargs)

    @classmethod
    def open_if_animation(cls, path: str | Path, solver: Any, **kwargs: Any) -> AnimationTimeline | None:
        """The timeline of ``path`` when it is a ``smplik-animation`` file; None for anything else (a scene,
        or a file the scene reader should report on). An invalid animation file: one-line
        :class:`~workflows.animation.files.AnimationFileError` naming the file and JSON path."""
        from smplik.validation import read_json
        from workflows.animation.files import ANIMATION_FORMAT, AnimationFileError, animation_from_dict

        try:
            data = read_json(path, AnimationFileError, what="animation file")
        except AnimationFileError:
            return None
        if not isinstance(data, dict) or data.get("format") != ANIMATION_FORMAT:
            return None
        return cls(animation_from_dict(data, source=str(path)), solver, path=path, **kwargs)

    @property
    def path(self) -> Path | None:
        """The file :meth:`save` writes by default (the file opened, then the last one saved)."""
        return self._path

    @property
    def animation(self) -> Animation:
        return self._animation

    @property
    def frames(self) -> range:
        """Every source frame some track covers (first..last)."""
        first = min(t.first_frame for t in self._animation.tracks)
        last = max(t.first_frame + t.num_frames - 1 for t in self._animation.tracks)
        return range(first, last + 1)

    @property
    def frame(self) -> int:
        return self._frame

    @property
    def window(self) -> int:
        return self._window

    @window.setter
    def window(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise AnimationError(f"the blend window must be a whole number of frames >= 0, got {value!r}.")
        self._window = value

    @property
    def frame_time(self) -> float:
        """Seconds per frame when playing (the source frame rate)."""
        return 1.0 / self._animation.fps

    def set_frame(self, frame: int) -> int:
        """Scrub to a source frame (an error outside :attr:`frames`); returns it."""
        if frame not in self.frames:
            raise AnimationError(f"frame {frame} is outside the animation's frames {self.frames.start}.."
                                 f"{self.frames.stop - 1}.")
        self._frame = int(frame)
        return self._frame

    def step(self, count: int = 1) -> int:
        """Advance by ``count`` frames, wrapping around (playback); returns the new frame."""
        span = len(self.frames)
        self._frame = self.frames.start + (self._frame - self.frames.start + count) % span
        return self._frame

    def keyframes(self) -> list[int]:
        """Every track's keyframe frames, sorted, without repeats."""
        return sorted({k.frame for t in self._animation.tracks for k in t.keyframes})

    def next_keyframe(self, direction: int = 1) -> int:
        """Jump to the next (``direction`` 1) or previous (-1) keyframe; stays put when there is none."""
        keys = self.keyframes()
        ahead = [k for k in keys if (k - self._frame) * direction > 0]
        if ahead:
            self._frame = min(ahead) if direction > 0 else max(ahead)
        return self._frame

    def scene(self) -> Scene:
        """The current frame as a scene (each track present, its effectors when the frame is a keyframe)."""
        from workflows.animation.files import scene_of

        return scene_of(self._animation, self._frame)

    def apply(self, track: str, effectors: Sequence[Effector]) -> None:
        """Set the current frame's effectors of ``track`` and blend the re-solved pose over the window."""
        from workflows.animation.keyframe_edit import edit_keyframe

        edited = edit_keyframe(self._animation, track, self._frame, effectors, self._solver, window=self._window,
                               merge=False)  # the frame shows the keyframe's whole list
        self._undo.append(self._animation)
        self._redo.clear()
        self._animation = edited

    def apply_scene(self, scene: Scene) -> list[str]:
        """Apply every character of an edited scene of the current frame whose effectors changed; returns
        the names of the tracks edited."""
        before = {c.name: [e.to_dict() for e in c.effectors] for c in self.scene().characters}
        changed = []
        for c in scene.characters:
            if c.name in before and c.effectors and [e.to_dict() for e in c.effectors] != before[c.name]:
                self.apply(c.name, c.effectors)
                changed.append(c.name)
        return changed

    def _history_state(self) -> Animation:
        return self._animation

    def _restore(self, state: Animation) -> None:
        self._animation = state

    def save(self, path: str | Path | None = None) -> Path:
        """Write the animation (atomically) to ``path`` or the file it was opened from."""
        from workflows.animation.files import save_animation

        target = Path(path) if path is not None else self._path
        if target is None:
            raise AnimationError("no file to save to; give a path.")
        self._path = save_animation(self._animation, target)
        return self._path
