"""EasyMocap SMPL ``.json`` (one file per frame; the format of ZJU-MoCap and neuralbody's SMPL fits).

Written by EasyMocap (github.com/zju3dv/EasyMocap, ``easymocap/mytools/file_utils.py`` ``write_smpl``:
``output/smpl/000000.json``, a list of people) as read back by its body model
(``easymocap/smplmodel/body_model.py`` ``SMPLlayer.forward``):

* per person ``{"id": int, "Rh": [[3]], "Th": [[3]], "poses": [[72]] (SMPL; more columns for SMPL-H /
  SMPL-X), "shapes": [[10]]}``;
* the body is posed by LBS with ``poses`` (no translation; ``poses[:3]`` is usually zero), then rotated
  by ``Rh`` (axis-angle) **about the origin** and moved by ``Th``: a joint ``x`` is ``R(Rh) x + Th``. So
  the root rotation is ``R(Rh) R(poses[:3])`` and the pelvis is ``R(Rh) J0(shapes) + Th`` with ``J0`` the
  producer's rest pelvis (SMPL's for 72 columns, else SMPL-X's).
* The world is the calibrated capture world, **z-up** (EasyMocap's chessboard world: the ground is
  ``z = 0``); it is turned into smplik's y-up world (``(x, y, z) -> (x, z, -y)``). No camera.

SMPL-H / SMPL-X ``poses`` keep their 21 body joints (SMPL's two hand joints get zero rotation). The
file is one frame: ``--frame`` must be 0; people are keyed by ``id``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from workflows.estimators.base import (
    MAX_PEOPLE,
    EstimatedPerson,
    EstimateFormatError,
    estimator_rest_pelvis,
    finite,
    make_people,
    require,
)

FORMAT = "easymocap"
R_YUP_ZUP = Rotation.from_euler("x", -90, degrees=True)
"""EasyMocap's z-up world -> smplik's y-up world: (x, y, z) -> (x, z, -y)."""
KEYS = ("Rh", "Th", "poses")


def _people(data: Any) -> Any:
    return data.get("annots") if isinstance(data, dict) and isinstance(data.get("annots"), list) else data


def matches(data: Any) -> bool:
    people = _people(data)
    return (isinstance(people, list) and bool(people)
            and all(isinstance(p, dict) and all(k in p for k in KEYS) for p in people))


def _vector(value: Any, name: str, where: str, width: int | None = None) -> np.ndarray:
    arr = finite(value, name, where).reshape(-1)
    if width is not None and arr.shape[0] != width:
        raise EstimateFormatError(f"{where}: '{name}' has {arr.shape[0]} values; expected {width}.")
    return arr


def from_data(data: Any, *, source: str = "<easymocap>", frame: int = 0,
              max_people: int = MAX_PEOPLE) -> list[EstimatedPerson]:
    if frame != 0:
        raise EstimateFormatError(f"{source}: an EasyMocap SMPL file holds one frame; --frame must be 0.")
    people = _people(data)
    if not matches(data):
        raise EstimateFormatError(f"{source}: expected a list of people with keys {', '.join(KEYS)}.")
    poses, pelvis, betas, ids, genders, family = [], [], [], [], [], None
    for i, p in enumerate(people):
        where = f"{source}[{i}]"
        full = _vector(require(p, "poses", where), "poses", where)
        if full.shape[0] < 66:
            raise EstimateFormatError(f"{where}: 'poses' has {full.shape[0]} values; expected 72 (SMPL) or more.")
        fam = "smpl" if full.shape[0] == 72 else "smplx"
        if family not in (None, fam):
            raise EstimateFormatError(f"{source}: people mix SMPL and SMPL-X/H 'poses' widths.")
        family = fam
        body = full[:72] if fam == "smpl" else np.concatenate([full[:66], np.zeros(6)])
        b = _vector(p.get("shapes", np.zeros(10)), "shapes", where)[:10]
        b = np.pad(b, (0, 10 - b.shape[0]))
        R_h = Rotation.from_rotvec(_vector(require(p, "Rh", where), "Rh", where, 3))
        T_h = _vector(require(p, "Th", where), "Th", where, 3)
        genders.append(_gender(p))
        J0 = estimator_rest_pelvis(b[None], genders[-1], fam)[0]
        root = R_YUP_ZUP * R_h * Rotation.from_rotvec(body[:3])
        poses.append(np.concatenate([root.as_rotvec(), body[3:]]))
        pelvis.append(R_YUP_ZUP.apply(R_h.apply(J0) + T_h))
        betas.append(b)
        ids.append(str(p.get("id", i)))
    return make_people(np.stack(poses), np.stack(pelvis), np.stack(betas), frame_of_reference="world",
                       translation_kind="pelvis", body_family=family or "smpl", genders=genders, person_ids=ids,
                       frames=["0"] * len(ids), source=f"{source} (easymocap)", max_people=max_people)


def _gender(p: dict) -> Any:
    from smplik.conventions import Gender

    g = str(p.get("gender", "neutral")).lower()
    return {"male": Gender.MALE, "female": Gender.FEMALE}.get(g, Gender.NEUTRAL)
