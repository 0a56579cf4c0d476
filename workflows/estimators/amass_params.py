"""SMPL-H / SMPL-X / SMPL parameter sequences in AMASS's layout (``.npz``), one person over T frames.

Written by AMASS (amass.is.tue.mpg.de; the release ``.npz`` files, and SMPL-X exports such as
``smplx``'s fitting tools): ``poses (T, 156)`` (SMPL-H), ``(T, 165)`` (SMPL-X) or ``(T, 72)``
(SMPL), or split ``root_orient (T, 3)`` / ``pose_body (T, 63)``; ``trans (T, 3)``; ``betas``;
``gender``; ``mocap_frame(_)rate``. Read by :func:`smplik.data.amass.read_amass` (z-up world ->
y-up, first 10 betas, SMPL's hand joints zero for SMPL-H/X). ``transl`` is smplx's, relative to the
producer's rest pelvis: SMPL's (also SMPL-H's) or SMPL-X's facts (:mod:`workflows.estimators.base`).
No camera. ``--frame N`` is row N; the person id is ``"0"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import Gender
from workflows.estimators.base import (
    MAX_PEOPLE,
    BodyFamily,
    EstimatedPerson,
    EstimateFormatError,
    estimator_rest_pelvis,
    make_people,
)

FORMAT = "amass"


def matches(data: Any) -> bool:
    if not isinstance(data, dict) or "trans" not in data:
        return False
    return "poses" in data or ("root_orient" in data and "pose_body" in data)


def family_of(data: dict[str, Any]) -> BodyFamily:
    """SMPL-X when the poses have 165 columns or the file has SMPL-X-only keys, else SMPL (SMPL-H's body)."""
    poses = data.get("poses")
    width = np.shape(poses)[-1] if poses is not None and np.ndim(poses) >= 1 else 0
    if width == 165 or any(k in data for k in ("pose_jaw", "pose_eye", "surface_model_type")):
        return "smplx"
    return "smpl"


def read(path: str | Path, data: dict[str, Any], *, frame: int = 0, max_people: int = MAX_PEOPLE
         ) -> list[EstimatedPerson]:
    from smplik.data.amass import read_amass

    source = str(path)
    family = family_of(data)

    def J0_est(betas: np.ndarray | None, gender: Gender | None) -> np.ndarray:
        b = np.zeros((1, 10)) if betas is None else np.asarray(betas, dtype=np.float64).reshape(1, 10)
        return estimator_rest_pelvis(b, gender or Gender.NEUTRAL, family)[0]

    try:
        seq = read_amass(path, rest_pelvis=J0_est)
    except (ValueError, FileNotFoundError) as exc:
        raise EstimateFormatError(str(exc)) from None
    T = seq.global_orient.shape[0]
    if not 0 <= frame < T:
        raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{T - 1}).")
    betas = np.zeros(10) if seq.betas is None else np.asarray(seq.betas, dtype=np.float64)
    gender = seq.gender or Gender.NEUTRAL
    pose = np.concatenate([seq.global_orient[frame][None], seq.body_pose[frame]]).astype(np.float64)[None]
    return make_people(pose, seq.transl[frame][None].astype(np.float64), betas[None], frame_of_reference="world",
                       translation_kind="transl", body_family=family, genders=[gender], person_ids=["0"],
                       frames=[str(frame)], source=f"{source} (amass, {family})", max_people=max_people)
