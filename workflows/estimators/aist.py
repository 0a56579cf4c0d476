"""AIST++ motion ``.pkl`` files (a plain pickle dict, read by the restricted unpickler).

Written for the AIST++ dataset (google/aistplusplus_api; files ``motions/<seq>.pkl``, read by
``aist_plusplus/loader.py`` ``AISTDataset.load_motion``):

* ``smpl_poses (T, 72)`` axis-angle, root first; ``smpl_trans (T, 3)``; ``smpl_scaling (1,)``.
* The world is AIST++'s y-up frame in centimetres-like units: the API replays a frame as
  ``SMPL(global_orient, body_pose, transl=smpl_trans / smpl_scaling)`` and multiplies the output by
  ``smpl_scaling`` (``demos/run_vis.py``, ``gender='MALE'``). We keep the SMPL-unit body (transl
  ``smpl_trans / smpl_scaling``, metres of an SMPL body of scale 1) and the male model's facts.
* No camera: the people are in the world frame. ``--frame N`` is row N; the person id is ``"0"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smplik.conventions import Gender
from workflows.estimators import base

FORMAT = "aist"


def matches(data: Any) -> bool:
    return isinstance(data, dict) and "smpl_poses" in data and "smpl_trans" in data


def from_data(data: Any, *, source: str = "<aist>", frame: int = 0, max_people: int = base.MAX_PEOPLE
              ) -> list[base.EstimatedPerson]:
    poses = base.rows(base.require(data, "smpl_poses", source), "smpl_poses", 72, source)
    T = poses.shape[0]
    trans = base.rows(base.require(data, "smpl_trans", source), "smpl_trans", 3, source, T)
    scaling = base.scalar(data.get("smpl_scaling", 1.0), "smpl_scaling", source)
    if not scaling > 0:
        raise base.EstimateFormatError(f"{source}: 'smpl_scaling' must be positive, got {scaling}.")
    if not 0 <= frame < T:
        raise base.EstimateFormatError(f"{source}: frame {frame} out of range (0..{T - 1}).")
    return base.make_people(poses[frame:frame + 1], trans[frame:frame + 1] / scaling, np.zeros((1, 10)),
                            frame_of_reference="world", translation_kind="transl", genders=[Gender.MALE],
                            person_ids=["0"], frames=[str(frame)], source=f"{source} (aist)", max_people=max_people)
