"""Bare SMPL / SMPL-H / SMPL-X pose arrays: ``.npy`` (or a one-array ``.npz``) of shape (T, 72 | 156 | 165).

What ``np.save(path, poses)`` writes for the ``poses`` of an AMASS-style sequence, or the ``full_pose``
of smplx's models flattened: axis-angle, root first, then the body joints, then (SMPL-H) 30 hand joints
or (SMPL-X) jaw, two eyes and 30 hand joints. A file of 63 or 69 columns (smplx ``body_pose`` alone)
is refused: the root rotation is missing.

Nothing else is stored, so the reader assumes, and says so once (:class:`EstimateNote`): the width
names the model (72 SMPL, 156 SMPL-H, 165 SMPL-X; SMPL's hand joints get zero rotation for the latter
two), the root rotation is in smplik's y-up world, the pelvis at the origin (no translation), β = 0 and
a neutral body. ``--frame N`` is row N; the person id is ``"0"``.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from workflows.estimators.base import MAX_PEOPLE, EstimatedPerson, EstimateFormatError, finite, make_people

FORMAT = "pose_array"
WIDTHS = {72: "SMPL", 156: "SMPL-H", 165: "SMPL-X"}


class EstimateNote(UserWarning):
    """An assumption a reader made about a file (shown to the user as one line)."""


def _array(data: Any) -> Any:
    if isinstance(data, dict) and len(data) == 1:
        return next(iter(data.values()))
    return data


def matches(data: Any) -> bool:
    arr = _array(data)
    return isinstance(arr, np.ndarray) and arr.ndim in (1, 2) and arr.shape[-1] in WIDTHS and arr.dtype.kind == "f"


def from_data(data: Any, *, source: str = "<poses>", frame: int = 0,
              max_people: int = MAX_PEOPLE) -> list[EstimatedPerson]:
    arr = _array(data)
    if not isinstance(arr, np.ndarray) or arr.ndim not in (1, 2):
        raise EstimateFormatError(f"{source}: expected a (T, 72 | 156 | 165) pose array.")
    arr = finite(arr, "poses", source).reshape(-1, arr.shape[-1])
    width = arr.shape[1]
    if width not in WIDTHS:
        hint = " (the root rotation is missing)" if width in (63, 69) else ""
        raise EstimateFormatError(f"{source}: a pose array of {width} columns{hint}; expected 72 (SMPL), 156 "
                                  f"(SMPL-H) or 165 (SMPL-X).")
    if not 0 <= frame < arr.shape[0]:
        raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{arr.shape[0] - 1}).")
    model = WIDTHS[width]
    warnings.warn(f"{source}: a bare pose array of {width} columns, read as {model} axis-angle (root first) in a "
                  f"y-up world, pelvis at the origin, betas 0, neutral body; other conventions need a full "
                  f"estimator file.", EstimateNote, stacklevel=2)
    row = arr[frame]
    pose = row[:72] if width == 72 else np.concatenate([row[:66], np.zeros(6)])
    family = "smpl" if model != "SMPL-X" else "smplx"
    return make_people(pose[None], np.zeros((1, 3)), np.zeros((1, 10)), frame_of_reference="world",
                       translation_kind="pelvis", body_family=family, person_ids=["0"], frames=[str(frame)],
                       source=f"{source} (pose_array, {model})", max_people=max_people)
