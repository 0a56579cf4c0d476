"""Editing an animation's motion, not only a pose: a keyframe's new effectors, blended into its neighbours.

:func:`keyframe_edit` merges the given effectors (character space) into the keyframe's recovered effectors
(:func:`merge_effectors`: an effector of the same joint and type is replaced, the others are kept; at a frame
that is no keyframe there are none to keep) and solves the frame as the editor solves drags
(:func:`workflows.scene.edits.solve_scripted`): the given effectors the frame's pose does not meet are the moved
ones; each relaxes the stale effectors of its chain (tolerance raised to 1) and is solved from the frame's
pose, its limb re-posed and the rest of the body kept. That gives the change ``D_j = R_old_j^T R_new_j`` of
every local rotation and ``dt`` of the root translation at that frame. Frames within ``window`` of it receive
the change scaled by a raised-cosine weight, ``w(d) = (1 + cos(pi d / (window + 1))) / 2`` at distance ``d``
(``w = 1`` at the keyframe, so it reaches the solved pose exactly): ``R_j <- R_j exp(w log D_j)``,
``t <- t + w dt``. Every frame outside the window keeps its values bit for bit (every frame, when the frame's
pose already meets the given effectors). The keyframe stores the merged
effectors (error 0); other keyframes inside the window keep their effectors. ``exact=True`` re-solves the
frame from the merged effectors alone (every one exact as given, nothing relaxed).

The editor's timeline *Apply* (:meth:`workflows.editor.timeline.AnimationTimeline.apply`) and
``smplik scene edit-keyframe`` both run :func:`edit_keyframe`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.effectors import Effector
from workflows.animation.clips import Animation, AnimationError, Keyframe, axis_angle_to_local
from workflows.scene.edits import ScriptedEdit


def blend_weights(num_rows: int, center: int, window: int) -> np.ndarray:
    """Raised-cosine weights (num_rows,): 1 at ``center``, 0 beyond ``window`` rows from it."""
    d = np.abs(np.arange(num_rows) - center)
    return np.where(d <= window, 0.5 * (1.0 + np.cos(np.pi * d / (window + 1))), 0.0)


def merge_effectors(keyframe: Sequence[Effector], given: Sequence[Effector]
                    ) -> tuple[tuple[Effector, ...], tuple[int, ...], int]:
    """The keyframe's effectors with ``given`` merged in: every keyframe effector whose joint and type no given
    effector names is kept (in order), then the given ones (in order).

    Returns: (merged effectors, indices of the given ones in it, how many of the keyframe's were replaced)."""
    named = {(e.joint, e.type) for e in given}
    kept = tuple(e for e in keyframe if (e.joint, e.type) not in named)
    return kept + tuple(given), tuple(range(len(kept), len(kept) + len(given))), len(keyframe) - len(kept)


@dataclass(frozen=True)
class KeyframeEdit:
    """The result of :func:`keyframe_edit`: the edited animation and what the edit did, for one printed line.

    Attributes:
        animation: the edited animation.
        track: the track's name; frame: the source frame.
        given: how many effectors were given; kept: how many of the keyframe's were kept as they were;
        replaced: how many of the keyframe's the given ones replaced.
        solve: what the frame's solve did (:class:`workflows.scene.edits.ScriptedEdit`: moved, relaxed).
        window: the blend window (frames on each side).
    """

    animation: Animation
    track: str
    frame: int
    given: int
    kept: int
    replaced: int
    solve: ScriptedEdit
    window: int
    merged: bool = True
    """False: the effectors given were the keyframe's whole list (``merge=False``)."""

    def line(self) -> str:
        """``person_0: frame 40: 1 effector given (replacing 0 of the keyframe's 6, 6 kept); moved ...``"""
        what = self.solve.line().split(": ", 1)[1]
        merged = ("the keyframe's whole list" if not self.merged else
                  f"replacing {self.replaced} of the keyframe's, {self.kept} kept" if self.kept or self.replaced
                  else "a new keyframe")
        return (f"{self.track}: frame {self.frame}: {self.given} effector{'s' * (self.given != 1)} given "
                f"({merged}); {what}; blended over +-{self.window} frames")


def edit_keyframe(animation: Animation, track: str, frame: int, effectors: Sequence[Effector], solver: Any, *,
                  window: int, exact: bool = False, merge: bool = True) -> Animation:
    """The animation with track ``track`` (name or track id) re-posed at source frame ``frame`` by
    ``effectors`` (character space) merged into the keyframe's, the change blended over ``window`` frames on
    each side (:func:`keyframe_edit`, which also says what it did)."""
    return keyframe_edit(animation, track, frame, effectors, solver, window=window, exact=exact,
                         merge=merge).animation


def check_keyframe_edit(animation: Animation, track: str, frame: int, effectors: Sequence[Effector], *,
                        window: int) -> int:
    """The index of ``track`` in ``animation``, after refusing (one :class:`AnimationError` line) an unknown track,
    a frame outside it, a negative window or no effector: what :func:`keyframe_edit` checks, callable before the
    model loads."""
    matches = [i for i, t in enumerate(animation.tracks) if track in (t.name, t.track_id)]
    if not matches:
        names = ", ".join(t.name for t in animation.tracks)
        raise AnimationError(f"no track {track!r} in the animation (tracks: {names}).")
    t = animation.tracks[matches[0]]
    if frame not in t.frames:
        raise AnimationError(f"frame {frame} is outside track {t.name}'s frames {t.first_frame}.."
                             f"{t.first_frame + t.num_frames - 1}.")
    if window < 0:
        raise AnimationError(f"--window must be >= 0 frames, got {window}.")
    if not effectors:
        raise AnimationError("a keyframe edit needs at least one effector.")
    return matches[0]


def keyframe_edit(animation: Animation, track: str, frame: int, effectors: Sequence[Effector], solver: Any, *,
                  window: int, exact: bool = False, merge: bool = True) -> KeyframeEdit:
    """:func:`edit_keyframe` and what it did (module docstring: merge, drags, blend).

    ``merge=False``: ``effectors`` are the keyframe's whole new list (the editor's *Apply*, whose frame shows
    every effector of the keyframe: one deleted there stays deleted); the moved ones are still solved as drags.
    """
    from workflows.scene.edits import solve_scripted

    n = check_keyframe_edit(animation, track, frame, effectors, window=window)
    t = animation.tracks[n]
    row = frame - t.first_frame
    old = next((k.effectors for k in t.keyframes if k.frame == frame), ()) if merge else ()
    merged, given, replaced = merge_effectors(old, effectors)
    new, report = solve_scripted(solver, t.name, merged, t.pose(row), scale=t.scale, betas=t.betas, gender=t.gender,
                                 among=given, exact=exact)
    R_old = axis_angle_to_local(t.global_orient[row:row + 1], t.body_pose[row:row + 1])[0]
    R_new = axis_angle_to_local(np.asarray(new.global_orient)[None], np.asarray(new.body_pose)[None])[0]
    log_delta = Rotation.from_matrix(np.swapaxes(R_old, -1, -2) @ R_new).as_rotvec()  # (24, 3)
    dt = np.asarray(new.transl) - t.transl[row]
    weights = blend_weights(t.num_frames, row, window)
    if report.mode == "kept":  # every given effector already met: the motion stays bit for bit
        weights = np.zeros_like(weights)
    rows = np.nonzero(weights > 0)[0]
    go, bp, transl = t.global_orient.copy(), t.body_pose.copy(), t.transl.copy()
    R_rows = axis_angle_to_local(go[rows], bp[rows])
    step = Rotation.from_rotvec((weights[rows, None, None] * log_delta[None]).reshape(-1, 3)).as_matrix()
    R_edit = R_rows @ step.reshape(len(rows), 24, 3, 3)
    aa = Rotation.from_matrix(R_edit.reshape(-1, 3, 3)).as_rotvec().reshape(len(rows), 24, 3)
    go[rows], bp[rows] = aa[:, 0], aa[:, 1:]
    transl[rows] += weights[rows, None] * dt
    keyframes = [k for k in t.keyframes if k.frame != frame] + [Keyframe(frame, report.effectors, 0.0)]
    edited = dataclasses.replace(t, global_orient=go, body_pose=bp, transl=transl,
                                 keyframes=tuple(sorted(keyframes, key=lambda k: k.frame)))
    tracks = list(animation.tracks)
    tracks[n] = edited
    return KeyframeEdit(dataclasses.replace(animation, tracks=tuple(tracks)), t.name, frame, len(effectors),
                        len(old) - replaced, replaced, report, window, merge)
