"""GVHMR results: ``hmr4d_results.pt`` (a dict of tensors, read by :func:`smplik.model_io.read_torch_file`) or ``.npz``.

Written by GVHMR (github.com/zju3dv/GVHMR, ``tools/demo/demo.py``: ``pred = model.predict(data,
static_cam=...)``, ``torch.save(pred, paths.hmr4d_results)``). GVHMR poses **SMPL-X**
(``make_smplx("supermotion")``), one tracked person over L frames:

* ``smpl_params_incam``: ``body_pose (L, 63)`` (21 SMPL-X body joints), ``global_orient (L, 3)``,
  ``transl (L, 3)``, ``betas (L, 10)``, OpenCV camera frame; ``transl`` is smplx's (the demo renders
  ``smplx(**smpl_params_incam).vertices`` with ``K_fullimg``), so the pelvis is
  ``J0_smplx + transl``.
* ``smpl_params_global``: the same keys in GVHMR's gravity-aligned y-up world (``space="world"``).
* ``K_fullimg (L, 3, 3)``: the full-image intrinsics, used as they are. The image size is not stored, but
  the demo builds ``K_fullimg = estimate_K(width, height)`` (``hmr4d/utils/geo/hmr_cam.py``: focal = the
  image diagonal, principal point = the image centre), so the image is ``(2 cx, 2 cy)`` pixels; it is
  recorded so that an overlay on a resized frame rescales the intrinsics.

SMPL's two hand joints have no SMPL-X body counterpart and get zero rotation. ``--frame N`` is row N
(the video frame); the person id is ``"0"``. An ``.npz`` holds the same dicts (pickled object arrays
read by the restricted unpickler) or flattened keys ``smpl_params_incam.body_pose`` /
``smpl_params_incam/body_pose`` / ``smpl_params_incam_body_pose`` (the last as written by users'
AMASS-style conversions, e.g. github.com/wenconggan/video2smpl ``outputs/demo/tennis/hmr4d_results.npz``:
``poses, trans, betas, gender, mocap_framerate`` plus ``K_fullimg`` and ``smpl_params_incam_*``).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from workflows.estimators.base import (
    MAX_PEOPLE,
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    make_people,
    require,
    rows,
)

FORMAT = "gvhmr"
_KEYS = ("smpl_params_incam", "smpl_params_global")


def _nest(data: Any) -> Any:
    """Flattened ``a.b`` / ``a/b`` keys regrouped into nested dicts."""
    if not isinstance(data, dict):
        return data
    out: dict[str, Any] = {}
    for k, v in data.items():
        key = str(k)
        for head in _KEYS:
            if len(key) > len(head) + 1 and key.startswith(head) and key[len(head)] in "/._":
                inner = out.setdefault(head, {})
                if isinstance(inner, dict):
                    inner[key[len(head) + 1:]] = v
                break
        else:
            out[key] = v
    return out


def matches(data: Any) -> bool:
    data = _nest(data)
    return isinstance(data, dict) and any(k in data for k in _KEYS)


def from_data(data: Any, *, source: str = "<gvhmr>", frame: int = 0,
              space: Literal["camera", "world"] = "camera", max_people: int = MAX_PEOPLE) -> list[EstimatedPerson]:
    data = _nest(data)
    key = "smpl_params_global" if space == "world" else "smpl_params_incam"
    params = require(data, key, source)
    where = f"{source}.{key}"
    if not isinstance(params, dict):
        raise EstimateFormatError(f"{where}: expected a dict of arrays, got {type(params).__name__}.")
    body = rows(require(params, "body_pose", where), "body_pose", (63, 69), where)
    L = body.shape[0]
    go = rows(require(params, "global_orient", where), "global_orient", 3, where, L)
    transl = rows(require(params, "transl", where), "transl", 3, where, L)
    betas = rows(require(params, "betas", where), "betas", tuple(range(1, 301)), where)
    if not 0 <= frame < L:
        raise EstimateFormatError(f"{source}: frame {frame} out of range (0..{L - 1}).")
    b = body[frame]
    if b.shape[0] == 63:
        b = np.concatenate([b, np.zeros(6)])
    pose = np.concatenate([go[frame], b])[None]
    camera = None
    if space != "world":
        camera = CameraInfo()
        if "K_fullimg" in data:
            K = np.asarray(data["K_fullimg"], dtype=object if isinstance(data["K_fullimg"], list) else None)
            K = rows(K, "K_fullimg", 9, source)
            K = K[min(frame, K.shape[0] - 1)].reshape(3, 3)
            cx, cy = float(K[0, 2]), float(K[1, 2])
            size = (round(2 * cx), round(2 * cy)) if 0 < cx < 50_000 and 0 < cy < 50_000 else None
            camera = CameraInfo.from_K(K, size, f"{source}.K_fullimg")
    return make_people(pose, transl[frame:frame + 1], betas[min(frame, betas.shape[0] - 1)][None],
                       frame_of_reference="world" if space == "world" else "camera", translation_kind="transl",
                       body_family="smplx", camera=camera, person_ids=["0"], frames=[str(frame)],
                       source=f"{source} (gvhmr)", max_people=max_people)
