"""SMPL-X producers on our body: the rest pelvis ``J0_smplx(beta)`` and the closest body, from the user's SMPL-X file.

GVHMR (and every reader with ``body_family="smplx"``) gives **SMPL-X** betas. SMPL-X's shape space is not
SMPL's, nor the built-in body's: the same beta is another body. Against GVHMR's own in-camera render
(``benchmarks/estimator_placement.py``, four real tracks) the pelvis-relative upper body of GVHMR's
mesh is 9-15 % longer than the built-in body given the same betas on three tracks (betas[2] = 0.6-1.3) and
2-4 % on the fourth (betas[2] = -0.6), while the legs agree within 5 %: the head sits 4-7 % of the body's
image height low. A constant rest pelvis cannot close that; the SMPL-X shape directions can, and they are
not shipped (the SMPL-X licence does not allow redistributing the model).

With the SMPL-X neutral model ``SMPLX_NEUTRAL.npz`` (smpl-x.is.tue.mpg.de) at ``$SMPLIK_SMPLX_MODEL`` (the file
or its folder; works with the built-in body) or in the model folder (``$SMPLIK_MODEL_DIR``, or its ``smplx/``
sub-folder, the layout ``smplx.create`` uses):

* ``J0_smplx(beta) = J_regressor[0] @ (v_template + shapedirs[..., :10] beta)``, exactly what smplx
  rotates the root about (the producer's ``transl`` is relative to it);
* the betas given to our body are the least-squares fit of our rest body to SMPL-X's for the producer's
  betas: the 22 body joints (pelvis..right_wrist, shared by both skeletons) and the top of the head and
  the soles (the highest and lowest rest vertices at beta = 0: what an overlay shows), relative to the
  pelvis, all linear in beta, so one (72 x 10) solve per person; directions that move none of them
  (girth) stay 0, and the fit is clipped to the +-5 that SMPL-SI spans.

The file is read with ``np.load(allow_pickle=False)`` (no code runs); only the arrays above are used. The
neutral file serves every gender (SMPL-X producers that name one, e.g. AMASS SMPL-X, are fitted with it).
Without the file, the readers keep the published beta = 0 rest pelvis
(:data:`workflows.estimators.base.SMPLX_NEUTRAL_REST_PELVIS`) and the producer's betas as they are.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from smplik.conventions import NUM_BETAS, Gender

SMPLX_FILE = "SMPLX_NEUTRAL.npz"
BODY_JOINTS = 22
"""SMPL-X's first 22 joints are SMPL's pelvis..right_wrist (same names, same tree)."""


SMPLX_ENV = "SMPLIK_SMPLX_MODEL"


def smplx_model_path() -> Path | None:
    """The user's SMPL-X neutral model file (``$SMPLIK_SMPLX_MODEL``, else the model folder), or None."""
    from smplik.body_model import resolve_model_dir
    from workflows.estimators.errors import EstimateFormatError

    given = os.environ.get(SMPLX_ENV, "")
    if given:
        path = Path(given)
        path = path / SMPLX_FILE if path.is_dir() else path
        if not path.is_file():
            raise EstimateFormatError(f"${SMPLX_ENV}={given}: no SMPL-X model file there (expected {SMPLX_FILE}).")
        return path
    folder = resolve_model_dir(None)
    if folder is None:
        return None
    for path in (folder / SMPLX_FILE, folder / "smplx" / SMPLX_FILE):
        if path.is_file():
            return path
    return None


@functools.lru_cache(maxsize=4)
def smplx_skeleton(path: str) -> tuple[np.ndarray, np.ndarray]:
    """SMPL-X's rest landmarks (:func:`_landmarks`), linear in beta: ``(24, 3)``, ``(24, 3, 10)`` (float64)."""
    from workflows.estimators.errors import EstimateFormatError

    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: np.asarray(npz[k], dtype=np.float64) for k in ("v_template", "shapedirs", "J_regressor")}
    except KeyError as exc:
        raise EstimateFormatError(f"{path}: SMPL-X model file lacks the key {exc}.") from None
    except (OSError, ValueError) as exc:
        raise EstimateFormatError(f"{path}: not a readable SMPL-X .npz model file ({exc}).") from None
    v, dirs, reg = arrays["v_template"], arrays["shapedirs"], arrays["J_regressor"]
    V = v.shape[0] if v.ndim == 2 else -1
    if v.ndim != 2 or v.shape[1] != 3 or dirs.shape[:2] != (V, 3) or dirs.ndim != 3 or dirs.shape[2] < NUM_BETAS \
            or reg.ndim != 2 or reg.shape[1] != V or reg.shape[0] < BODY_JOINTS:
        raise EstimateFormatError(f"{path}: SMPL-X arrays have shapes v_template {v.shape}, shapedirs {dirs.shape}, "
                                  f"J_regressor {reg.shape}; expected (V, 3), (V, 3, >=10), (>=22, V).")
    if not all(np.isfinite(a).all() for a in (v, dirs, reg)):
        raise EstimateFormatError(f"{path}: SMPL-X arrays contain NaN or inf.")
    return _landmarks(reg[:BODY_JOINTS], v, dirs[:, :, :NUM_BETAS])


def _landmarks(J_regressor: np.ndarray, v_template: np.ndarray, shapedirs: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """The 22 body joints, then the head-top and sole vertices (highest / lowest at beta = 0), linear in beta:
    ``(24, 3)`` at beta = 0 and ``(24, 3, 10)`` per unit beta."""
    ends = [int(np.argmax(v_template[:, 1])), int(np.argmin(v_template[:, 1]))]
    template = np.concatenate([J_regressor @ v_template, v_template[ends]])
    dirs = np.concatenate([np.einsum("jv,vcb->jcb", J_regressor, shapedirs), shapedirs[ends]])
    return template, dirs


def smplx_rest_joints(betas: np.ndarray, path: Path) -> np.ndarray:
    """SMPL-X rest body joints for betas (N, 10) -> (N, 22, 3)."""
    return _smplx_landmarks(betas, path)[:, :BODY_JOINTS]


def _smplx_landmarks(betas: np.ndarray, path: Path) -> np.ndarray:
    template, dirs = smplx_skeleton(str(path))
    return template + np.einsum("jcb,nb->njc", dirs, np.asarray(betas, dtype=np.float64))


def fit_our_betas(betas_smplx: np.ndarray, gender: Gender, path: Path) -> np.ndarray:
    """Our body's betas whose rest skeleton best matches SMPL-X's for ``betas_smplx`` (N, 10) -> (N, 10).

    Least squares over the pelvis-relative landmarks (module docstring).
    """
    from smplik.body_model import load_body_model

    arrays = load_body_model(gender).arrays
    J_t, J_d = _landmarks(np.asarray(arrays["J_regressor"], dtype=np.float64)[:BODY_JOINTS],
                          np.asarray(arrays["v_template"], dtype=np.float64),
                          np.asarray(arrays["shapedirs"], dtype=np.float64)[:, :, :NUM_BETAS])
    A = (J_d - J_d[:1]).reshape(-1, NUM_BETAS)  # (72, 10): pelvis-relative landmarks per unit beta
    target = _smplx_landmarks(betas_smplx, path)
    b = (target - target[:, :1]) - (J_t - J_t[:1])  # (N, 24, 3)
    fitted, *_ = np.linalg.lstsq(A, b.reshape(b.shape[0], -1).T, rcond=1e-3)
    return np.clip(fitted.T, -5.0, 5.0)
