"""Metrics: the one Kabsch/Umeyama fit (rigid_align) on known transforms, PA-MPJPE, MPJPE, geodesic error."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.spatial.transform import Rotation

from smplik.metrics import local_geodesic, mpjpe, pa_mpjpe, procrustes_align, rigid_align


def _random_similarity(shape: tuple[int, ...], seed: int):
    """Rotations (*shape, 3, 3), scales (*shape,) in [0.5, 2] and translations (*shape, 3), float64."""
    n = math.prod(shape)
    R = torch.from_numpy(Rotation.random(n, random_state=seed).as_matrix()).reshape(*shape, 3, 3)
    g = torch.Generator().manual_seed(seed)
    s = 0.5 + 1.5 * torch.rand(shape, generator=g, dtype=torch.float64)
    t = torch.randn(*shape, 3, generator=g, dtype=torch.float64)
    return R, s, t


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_procrustes_recovers_a_rotated_scaled_translated_copy(batch):
    g = torch.Generator().manual_seed(1)
    src = torch.randn(*batch, 24, 3, generator=g, dtype=torch.float64)
    R, s, t = _random_similarity(batch, seed=2)
    dst = s[..., None, None] * (src @ R.transpose(-1, -2)) + t[..., None, :]
    fit = rigid_align(src, dst, scale=True)
    torch.testing.assert_close(fit.R, R, atol=1e-10, rtol=0)
    torch.testing.assert_close(fit.scale, s, atol=1e-10, rtol=0)
    torch.testing.assert_close(fit.t, t, atol=1e-10, rtol=0)
    torch.testing.assert_close(fit.apply(src), dst, atol=1e-10, rtol=0)
    assert pa_mpjpe(src, dst).abs().max() < 1e-10  # zero error after alignment...
    assert mpjpe(src, dst).min() > 0.1  # ...though the copy is far away before it
    torch.testing.assert_close(procrustes_align(src, dst), dst, atol=1e-10, rtol=0)


def test_kabsch_without_scale_keeps_unit_scale_and_finds_the_rotation():
    g = torch.Generator().manual_seed(3)
    src = torch.randn(5, 10, 3, generator=g, dtype=torch.float64)
    R, s, t = _random_similarity((5,), seed=4)
    dst = src @ R.transpose(-1, -2) + t[:, None]
    fit = rigid_align(src, dst, scale=False)
    torch.testing.assert_close(fit.scale, torch.ones(5, dtype=torch.float64))
    torch.testing.assert_close(fit.R, R, atol=1e-10, rtol=0)
    torch.testing.assert_close(fit.t, t, atol=1e-10, rtol=0)
    # a scaled copy: the rotation is still exact, the scale is not fitted
    scaled = rigid_align(src, 2.0 * src @ R.transpose(-1, -2), scale=False)
    torch.testing.assert_close(scaled.R, R, atol=1e-10, rtol=0)
    torch.testing.assert_close(scaled.scale, torch.ones(5, dtype=torch.float64))


def test_weights_ignore_outliers_and_mirror_images_give_rotations():
    g = torch.Generator().manual_seed(5)
    src = torch.randn(8, 3, generator=g, dtype=torch.float64)
    R, s, t = _random_similarity((), seed=6)
    dst = s * src @ R.T + t
    dst[:2] += 10.0  # two outliers, weight 0
    w = torch.ones(8, dtype=torch.float64)
    w[:2] = 0
    fit = rigid_align(src, dst, w, scale=True)
    torch.testing.assert_close(fit.R, R, atol=1e-10, rtol=0)
    torch.testing.assert_close(fit.scale, s, atol=1e-10, rtol=0)
    unweighted = rigid_align(src, dst, scale=True)
    assert (unweighted.R - R).abs().max() > 1e-3
    # a reflected copy has no exact proper rotation: the fit is still a rotation (det +1)
    mirrored = rigid_align(src, src * torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64), scale=False)
    assert torch.linalg.det(mirrored.R) == pytest.approx(1.0)


def test_rigid_align_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match=r"\(\.\.\., N, 3\)"):
        rigid_align(torch.zeros(4, 3), torch.zeros(5, 3), scale=True)


def test_local_geodesic_is_the_mean_angle():
    angles = torch.tensor([0.0, 0.5, 1.0, 2.5], dtype=torch.float64)
    R = torch.from_numpy(Rotation.from_rotvec(torch.stack([angles, 0 * angles, 0 * angles], -1).numpy()).as_matrix())
    eye = torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    assert float(local_geodesic(R, eye)) == pytest.approx(float(angles.mean()), abs=1e-6)
