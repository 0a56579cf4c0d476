"""Editing an animation's motion, not only a pose: a keyframe's new effectors, blended into its neighbours.

:func:`edit_keyframe` solves the keyframe's new effectors (character space, divided by the track's scale
as scenes do) on the track's body, giving the change ``D_j = R_old_j^T R_new_j`` of every local rotation
and ``dt`` of the root translation at that frame. Frames within ``window`` of it receive the change
scaled by a raised-cosine weight, ``w(d) = (1 + cos(pi d / (window + 1))) / 2`` at distance ``d``
(``w = 1`` at the keyframe, so it reaches the solved pose exactly): ``R_j <- R_j exp(w log D_j)``,
``t <- t + w dt``. Every frame outside the window keeps its values bit for bit. The keyframe stores the new
effectors (error 0: its pose is their solve); other keyframes inside the window keep their effectors.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from smplik.effectors import Effector
from workflows.animation import Animation, AnimationError, Keyframe, axis_angle_to_local


def blend_weights(num_rows: int, center: int, window: int) -> np.ndarray:
    """Raised-cosine weights (num_rows,): 1 at ``center``, 0 beyond ``window`` rows from it."""
    d = np.abs(np.arange(num_rows) - center)
    return np.where(d <= window, 0.5 * (1.0 + np.cos(np.pi * d / (window + 1))), 0.0)


def edit_keyframe(animation: Animation, track: str, frame: int, effectors: Sequence[Effector], solver: Any, *,
                  window: int) -> Animation:
    """The animation with track ``track`` (name or track id) re-posed at source frame ``frame`` by
    ``effectors`` (character space), the change blended over ``window`` frames on each side."""
    from workflows.scene import scale_effector

    matches = [i for i, t in enumerate(animation.tracks) if track in (t.name, t.track_id)]
    if not matches:
        names = ", ".join(t.name for t in animation.tracks)
        raise AnimationError(f"no track {track!r} in the animation (tracks: {names}).")
    n = matches[0]
    t = animation.tracks[n]
    if frame not in t.frames:
        raise AnimationError(f"frame {frame} is outside track {t.name}'s frames {t.first_frame}.."
                             f"{t.first_frame + t.num_frames - 1}.")
    if window < 0:
        raise AnimationError(f"--window must be >= 0 frames, got {window}.")
    if not effectors:
        raise AnimationError("a keyframe edit needs at least one effector.")
    row = frame - t.first_frame
    new = solver.solve([scale_effector(e, 1.0 / t.scale) for e in effectors], betas=t.betas, gender=t.gender)
    R_old = axis_angle_to_local(t.global_orient[row:row + 1], t.body_pose[row:row + 1])[0]
    R_new = axis_angle_to_local(np.asarray(new.global_orient)[None], np.asarray(new.body_pose)[None])[0]
    log_delta = Rotation.from_matrix(np.swapaxes(R_old, -1, -2) @ R_new).as_rotvec()  # (24, 3)
    dt = np.asarray(new.transl) - t.transl[row]
    weights = blend_weights(t.num_frames, row, window)
    rows = np.nonzero(weights > 0)[0]
    go, bp, transl = t.global_orient.copy(), t.body_pose.copy(), t.transl.copy()
    R_rows = axis_angle_to_local(go[rows], bp[rows])
    step = Rotation.from_rotvec((weights[rows, None, None] * log_delta[None]).reshape(-1, 3)).as_matrix()
    R_edit = R_rows @ step.reshape(len(rows), 24, 3, 3)
    aa = Rotation.from_matrix(R_edit.reshape(-1, 3, 3)).as_rotvec().reshape(len(rows), 24, 3)
    go[rows], bp[rows] = aa[:, 0], aa[:, 1:]
    transl[rows] += weights[rows, None] * dt
    keyframes = [k for k in t.keyframes if k.frame != frame] + [Keyframe(frame, tuple(effectors), 0.0)]
    edited = dataclasses.replace(t, global_orient=go, body_pose=bp, transl=transl,
                                 keyframes=tuple(sorted(keyframes, key=lambda k: k.frame)))
    tracks = list(animation.tracks)
    tracks[n] = edited
    return dataclasses.replace(animation, tracks=tuple(tracks))
