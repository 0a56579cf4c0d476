"""SMPL-X producers with the user's SMPL-X file: the exact rest pelvis J0_smplx(beta) and our closest betas."""

from __future__ import annotations

import numpy as np
import pytest

from smplik.conventions import Gender


@pytest.fixture
def smplx_file(tmp_path, monkeypatch):
    """A model file in SMPLX_NEUTRAL.npz's layout (v_template (V, 3), shapedirs (V, 3, 20), J_regressor (55, V)):
    the built-in neutral body with its third shape direction reversed and twice as strong, so that the same
    betas are another body, as SMPL-X's betas are for ours."""
    from smplik.body_model import load_body_model

    arrays = load_body_model(Gender.NEUTRAL).arrays
    dirs = np.array(arrays["shapedirs"], dtype=np.float64)
    dirs[:, :, 2] *= -2.0
    dirs = np.concatenate([dirs, np.zeros(dirs.shape[:2] + (10,))], axis=2)
    reg = np.array(arrays["J_regressor"], dtype=np.float64)[:22]
    reg = np.concatenate([reg, np.repeat(reg[15:16], 33, axis=0)])  # SMPL-X's 55 joints: face and hands extra
    path = tmp_path / "SMPLX_NEUTRAL.npz"
    np.savez(path, v_template=np.array(arrays["v_template"], dtype=np.float64), shapedirs=dirs, J_regressor=reg,
             f=np.array(arrays["f"]))
    monkeypatch.delenv("SMPLIK_MODEL_DIR", raising=False)
    monkeypatch.setenv("SMPLIK_SMPLX_MODEL", str(tmp_path))
    return path, reg, dirs, np.array(arrays["v_template"], dtype=np.float64)


BETAS = np.array([[0.7, -0.8, 1.3, -1.1, 0.0, -0.6, -0.2, -0.4, 0.05, 0.0]])


def test_rest_pelvis_and_betas_come_from_the_smplx_file(smplx_file):
    from smplik.body_model import load_body_model
    from workflows.estimators.base import SMPLX_NEUTRAL_REST_PELVIS, estimator_rest_pelvis
    from workflows.estimators.smplx_shape import fit_our_betas

    path, reg, dirs, v = smplx_file
    J0 = estimator_rest_pelvis(BETAS, Gender.NEUTRAL, "smplx")
    np.testing.assert_allclose(J0[0], reg[0] @ (v + dirs[:, :, :10] @ BETAS[0]), atol=1e-9)
    assert np.abs(J0[0] - SMPLX_NEUTRAL_REST_PELVIS).max() > 0.05  # not the published beta = 0 constant
    ours = fit_our_betas(BETAS, Gender.NEUTRAL, path)
    assert ours[0, 2] == pytest.approx(-2.0 * BETAS[0, 2], abs=1e-4)  # the reversed direction, undone
    import torch

    J_ours = load_body_model(Gender.NEUTRAL).rest_joints(torch.as_tensor(ours, dtype=torch.float32))[0, :22].numpy()
    J_smplx = reg[:22] @ (v + dirs[:, :, :10] @ BETAS[0])
    np.testing.assert_allclose(J_ours - J_ours[0], J_smplx - J_smplx[0], atol=1e-5)  # the same skeleton
    arrays = load_body_model(Gender.NEUTRAL).arrays

    def above_pelvis(betas_ours: np.ndarray) -> np.ndarray:
        """Head top and soles of our rest mesh relative to its pelvis (y, m)."""
        mesh = arrays["v_template"] + arrays["shapedirs"] @ betas_ours
        y = mesh[:, 1] - arrays["J_regressor"][0] @ mesh[:, 1]
        return np.array([y.max(), y.min()])

    mesh = v + dirs[:, :, :10] @ BETAS[0]
    y_smplx = mesh[:, 1] - reg[0] @ mesh[:, 1]
    np.testing.assert_allclose(above_pelvis(ours[0]), [y_smplx.max(), y_smplx.min()], atol=1e-4)  # fitted: same
    assert np.abs(above_pelvis(BETAS[0]) - [y_smplx.max(), y_smplx.min()]).max() > 0.03  # unfitted: 3+ cm off


def test_gvhmr_person_gets_the_fitted_body_at_the_exact_pelvis(smplx_file, tmp_path):
    from estimator_fixtures import people, write_gvhmr

    from workflows.estimators import read_estimate
    from workflows.estimators.base import M_WORLD_CAMERA, rest_pelvis

    path, reg, dirs, v = smplx_file
    aa, transl, _ = people(seed=3, n=1)
    w = write_gvhmr(tmp_path, aa, transl, BETAS)
    person = read_estimate(w.path, space="camera")[0]
    assert person.betas[2] == pytest.approx(-2.0 * BETAS[0, 2], abs=1e-4)
    pelvis_cam = reg[0] @ (v + dirs[:, :, :10] @ BETAS[0]) + transl[0]  # smplx: J0_smplx(beta) + transl
    ours = rest_pelvis(person.betas[None], Gender.NEUTRAL)[0] + person.transl
    np.testing.assert_allclose(ours, M_WORLD_CAMERA @ pelvis_cam, atol=1e-5)


def test_without_the_file_the_betas_are_kept(tmp_path, monkeypatch):
    from estimator_fixtures import people, write_gvhmr

    from workflows.estimators import read_estimate

    monkeypatch.delenv("SMPLIK_MODEL_DIR", raising=False)
    monkeypatch.delenv("SMPLIK_SMPLX_MODEL", raising=False)
    aa, transl, _ = people(seed=3, n=1)
    person = read_estimate(write_gvhmr(tmp_path, aa, transl, BETAS).path, space="camera")[0]
    np.testing.assert_allclose(person.betas, BETAS[0], atol=1e-6)


@pytest.mark.parametrize("content", ["missing", "nokey", "shape"])
def test_a_bad_smplx_file_is_one_clear_error(tmp_path, monkeypatch, content):
    from workflows.estimators.base import EstimateFormatError, estimator_rest_pelvis
    from workflows.estimators.smplx_shape import smplx_skeleton

    smplx_skeleton.cache_clear()
    path = tmp_path / "SMPLX_NEUTRAL.npz"
    if content == "nokey":
        np.savez(path, v_template=np.zeros((5, 3)))
    elif content == "shape":
        np.savez(path, v_template=np.zeros((5, 3)), shapedirs=np.zeros((5, 3, 10)), J_regressor=np.zeros((22, 4)))
    monkeypatch.setenv("SMPLIK_SMPLX_MODEL", str(path))
    with pytest.raises(EstimateFormatError) as err:
        estimator_rest_pelvis(BETAS, Gender.NEUTRAL, "smplx")
    assert "\n" not in str(err.value) and ("SMPLIK_SMPLX_MODEL" in str(err.value) or str(path) in str(err.value))
