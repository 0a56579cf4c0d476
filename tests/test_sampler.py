"""Training batches: mirroring, vertical rotation, body sampling, determinism, speed."""

from __future__ import annotations

import math

import pytest
import torch

from smplik.body_model import BodyModelSet
from smplik.conventions import LEFT_RIGHT, NUM_BETAS, NUM_JOINTS
from smplik.data.dataset import PoseDataset
from smplik.data.sampler import PoseBatch, PoseSampler, mirror_pose, rotate_about_vertical, rotation_about_y
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix

M = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
LR = list(LEFT_RIGHT)


def symmetric_body_models(seed: int = 0) -> BodyModelSet:
    """A mesh-less BodyModelSet whose rest joints are exactly mirror-symmetric for every beta."""
    g = torch.Generator().manual_seed(seed)
    J_t = torch.randn(3, NUM_JOINTS, 3, generator=g, dtype=torch.float64) * 0.3
    J_d = torch.randn(3, NUM_JOINTS, 3, NUM_BETAS, generator=g, dtype=torch.float64) * 0.01
    flip = torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)
    J_t = 0.5 * (J_t + J_t[:, LR] * flip)  # J[LR[j]] = M J[j]; centre joints get x = 0
    J_d = 0.5 * (J_d + J_d[:, LR] * flip[:, None])
    J_t[..., 1] += 0.9
    return BodyModelSet((), J_t.float(), J_d.float())


def random_dataset(N: int = 64, seed: int = 0, has_betas: bool | None = None, betas_value: float | None = None
                   ) -> PoseDataset:
    g = torch.Generator().manual_seed(seed)
    has = torch.rand(N, generator=g) < 0.5 if has_betas is None else torch.full((N,), has_betas)
    betas = torch.randn(N, NUM_BETAS, generator=g) if betas_value is None else torch.full((N, NUM_BETAS), betas_value)
    zeros = torch.zeros(N, dtype=torch.long)
    return PoseDataset(pose=torch.randn(N, NUM_JOINTS, 3, generator=g) * 0.5, transl=torch.randn(N, 3, generator=g),
                       betas=torch.where(has[:, None], betas, torch.zeros_like(betas)), has_betas=has,
                       gender=zeros - 1, clip_id=zeros, subject_id=zeros, frame=torch.arange(N), split=zeros,
                       clip_names=("clip",), subject_names=("subject",))


def test_mirror_twice_is_identity() -> None:
    g = torch.Generator().manual_seed(0)
    aa, t, J0 = torch.randn(5, 24, 3, generator=g), torch.randn(5, 3, generator=g), torch.randn(5, 3, generator=g)
    aa2, t2 = mirror_pose(*mirror_pose(aa, t, J0), J0)
    torch.testing.assert_close(aa2, aa)
    torch.testing.assert_close(t2, t)
    R = axis_angle_to_matrix(aa)
    R2, _ = mirror_pose(*mirror_pose(R, t), None)
    torch.testing.assert_close(R2, R)


def test_mirror_axis_angle_matches_matrices() -> None:
    """Axis-angle (x, y, z) -> (x, -y, -z) is M R M, on the swapped joint."""
    g = torch.Generator().manual_seed(1)
    aa, t = torch.randn(4, 24, 3, generator=g, dtype=torch.float64), torch.randn(4, 3, generator=g, dtype=torch.float64)
    aa_m, _ = mirror_pose(aa, t)
    R_m, _ = mirror_pose(axis_angle_to_matrix(aa), t)
    torch.testing.assert_close(axis_angle_to_matrix(aa_m), R_m)
    torch.testing.assert_close(R_m, M @ axis_angle_to_matrix(aa)[:, LR] @ M)


def _check_mirrored_joints(J_rest: torch.Tensor, seed: int) -> None:
    """FK of the mirrored pose = reflection of the original joints, with left and right swapped."""
    g = torch.Generator().manual_seed(seed)
    B = J_rest.shape[0]
    aa = torch.randn(B, 24, 3, generator=g, dtype=torch.float64)
    t = torch.randn(B, 3, generator=g, dtype=torch.float64)
    R_w, p = forward_kinematics(axis_angle_to_matrix(aa), J_rest, t)
    aa_m, t_m = mirror_pose(aa, t, J_rest[:, 0])
    R_w_m, p_m = forward_kinematics(axis_angle_to_matrix(aa_m), J_rest, t_m)
    torch.testing.assert_close(p_m, p[:, LR] @ M, atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(R_w_m, M @ R_w[:, LR] @ M, atol=1e-9, rtol=1e-9)


def test_mirrored_joints_reflect_on_symmetric_skeleton() -> None:
    bm = symmetric_body_models()
    betas = torch.randn(6, NUM_BETAS, generator=torch.Generator().manual_seed(2))
    J_rest = bm.rest_joints(betas, torch.arange(6) % 3).double()
    torch.testing.assert_close(J_rest[:, LR] @ M, J_rest)  # the skeleton is symmetric
    _check_mirrored_joints(J_rest, seed=3)


def test_mirrored_joints_reflect_on_builtin_model() -> None:
    bm = BodyModelSet.load()
    betas = 2 * torch.randn(6, NUM_BETAS, generator=torch.Generator().manual_seed(4))
    J_rest = bm.rest_joints(betas.double(), torch.arange(6) % 3)
    torch.testing.assert_close(J_rest[:, LR] @ M, J_rest, atol=1e-6, rtol=0)
    J_rest = 0.5 * (J_rest + J_rest[:, LR] @ M)  # remove float32 rounding of the stored model
    _check_mirrored_joints(J_rest, seed=5)


def test_rotate_about_vertical() -> None:
    g = torch.Generator().manual_seed(6)
    B = 8
    J_rest = symmetric_body_models().rest_joints(torch.randn(B, NUM_BETAS, generator=g), torch.arange(B) % 3).double()
    R = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g, dtype=torch.float64))
    t = torch.randn(B, 3, generator=g, dtype=torch.float64)
    angle = torch.rand(B, generator=g, dtype=torch.float64) * 2 * math.pi
    _, p = forward_kinematics(R, J_rest, t)
    R2, t2 = rotate_about_vertical(R, t, angle, J_rest[:, 0])
    _, p2 = forward_kinematics(R2, J_rest, t2)
    torch.testing.assert_close(R2[:, 1:], R[:, 1:])  # only the root changes
    R_y = rotation_about_y(angle)
    torch.testing.assert_close(p2, p @ R_y.transpose(-1, -2))  # every joint rotates about the y axis
    torch.testing.assert_close(p2[..., 1], p[..., 1])  # heights (pelvis included) are kept
    torch.testing.assert_close(R_y @ R_y.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(B, 3, 3))
    quarter = rotation_about_y(torch.tensor(math.pi / 2, dtype=torch.float64))
    torch.testing.assert_close(quarter @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                               torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))  # right-handed about +y


def test_batch_shapes_and_consistency() -> None:
    sampler = PoseSampler(random_dataset(), symmetric_body_models(), batch_size=32,
                          generator=torch.Generator().manual_seed(0))
    b = sampler.sample()
    assert isinstance(b, PoseBatch) and len(b) == 32
    assert b.R_local.shape == (32, 24, 3, 3) and b.R_world.shape == (32, 24, 3, 3)
    assert b.transl.shape == (32, 3) and b.betas.shape == (32, 10) and b.J_rest.shape == (32, 24, 3)
    assert b.p_world.shape == (32, 24, 3) and b.gender.shape == (32,) and b.gender.dtype == torch.long
    assert all(x.dtype == torch.float32 for x in (b.R_local, b.transl, b.betas, b.J_rest, b.R_world, b.p_world))
    torch.testing.assert_close(b.J_rest, symmetric_body_models().rest_joints(b.betas, b.gender))
    R_w, p_w = forward_kinematics(b.R_local, b.J_rest, b.transl)
    torch.testing.assert_close(R_w, b.R_world)
    torch.testing.assert_close(p_w, b.p_world)
    eye = torch.eye(3).expand(32, 24, 3, 3)
    torch.testing.assert_close(b.R_local @ b.R_local.transpose(-1, -2), eye, atol=1e-5, rtol=0)


def test_augmentation_keeps_pose_up_to_mirror_and_turn() -> None:
    """One frame, many augmented samples: pelvis height kept; joint heights are those of the pose or its mirror."""
    ds = random_dataset(N=1)
    bm = symmetric_body_models()
    b = PoseSampler(ds, bm, batch_size=256, generator=torch.Generator().manual_seed(1)).sample()
    R = axis_angle_to_matrix(ds.pose.expand(256, 24, 3))
    _, p = forward_kinematics(R, b.J_rest, ds.transl.expand(256, 3))
    torch.testing.assert_close(b.p_world[:, 0, 1], p[:, 0, 1])
    same = (b.p_world[..., 1] - p[..., 1]).abs().amax(-1) < 1e-4
    mirrored = (b.p_world[..., 1] - p[:, LR, 1]).abs().amax(-1) < 1e-4
    assert bool((same | mirrored).all())
    assert 0.35 < same.float().mean() < 0.65  # mirrored about half of the time
    # Turned by angles spread over the circle: the pelvis-to-head direction covers all quadrants.
    d = b.p_world[:, 15] - b.p_world[:, 0]
    heading = torch.atan2(d[:, 0], d[:, 2])
    assert len(set(((heading + math.pi) // (math.pi / 2)).long().tolist())) == 4
    # Without augmentation the dataset pose is used as is.
    b0 = PoseSampler(ds, bm, batch_size=8, generator=torch.Generator().manual_seed(1), augment=False).sample()
    torch.testing.assert_close(b0.R_local, axis_angle_to_matrix(ds.pose.expand(8, 24, 3)))
    torch.testing.assert_close(b0.transl, ds.transl.expand(8, 3))


def test_beta_and_gender_statistics() -> None:
    bm = symmetric_body_models()
    gen = torch.Generator().manual_seed(2)
    b = PoseSampler(random_dataset(has_betas=True, betas_value=1.5), bm, batch_size=20000, generator=gen,
                    beta_noise=0.5).sample()
    assert abs(float(b.betas.mean()) - 1.5) < 0.02 and abs(float(b.betas.std()) - 0.5) < 0.02
    b = PoseSampler(random_dataset(has_betas=False), bm, batch_size=20000, generator=gen).sample()
    assert abs(float(b.betas.mean())) < 0.02 and abs(float(b.betas.std()) - 1.0) < 0.02
    counts = torch.bincount(b.gender, minlength=3).float() / 20000
    assert torch.all((counts - 1 / 3).abs() < 0.02)


def test_determinism() -> None:
    ds, bm = random_dataset(), symmetric_body_models()

    def batches(seed: int) -> list[PoseBatch]:
        s = PoseSampler(ds, bm, batch_size=16, generator=torch.Generator().manual_seed(seed))
        return [s.sample(), s.sample()]

    a, b, c = batches(7), batches(7), batches(8)
    for x, y in zip(a, b, strict=True):
        for name in ("R_local", "transl", "betas", "gender", "p_world"):
            assert torch.equal(getattr(x, name), getattr(y, name))
    assert not torch.equal(a[0].p_world, c[0].p_world)
    assert not torch.equal(a[0].p_world, a[1].p_world)
    # Per-batch rotations (no precomputed matrices) give the same batches.
    s = PoseSampler(ds, bm, batch_size=16, generator=torch.Generator().manual_seed(7), max_cached_bytes=0)
    torch.testing.assert_close(s.sample().p_world, a[0].p_world)


def test_invalid_arguments() -> None:
    with pytest.raises(ValueError, match="empty"):
        PoseSampler(random_dataset().select(torch.zeros(64, dtype=torch.bool)), symmetric_body_models(),
                    batch_size=4, generator=torch.Generator())
    with pytest.raises(ValueError, match="batch_size"):
        PoseSampler(random_dataset(), symmetric_body_models(), batch_size=0, generator=torch.Generator())
    with pytest.raises(ValueError, match="pose shape"):
        mirror_pose(torch.zeros(2, 23, 3), torch.zeros(2, 3))


def test_part_swap_takes_whole_limbs_from_other_frames() -> None:
    """part_swap = 1: every limb chain's local rotations are one other frame's; the torso keeps its
    frame's; part_swap = 0 gives the default batches bit for bit; a bad probability is an error."""
    from smplik.conventions import JOINT_INDEX, LIMB_CHAINS

    ds, bm = random_dataset(N=32), symmetric_body_models()
    table = axis_angle_to_matrix(ds.pose.float())  # (F, 24, 3, 3)
    b = PoseSampler(ds, bm, batch_size=64, generator=torch.Generator().manual_seed(3), augment=False,
                    part_swap=1.0).sample()

    def frames_of(cols: list[int]) -> list[set[int]]:
        """Per sample, the frames whose rotations on ``cols`` equal the sample's."""
        eq = (b.R_local[:, None, cols] == table[None, :, cols]).flatten(2).all(-1)  # (B, F)
        return [set(torch.nonzero(row)[:, 0].tolist()) for row in eq]

    torso = [j for j in range(NUM_JOINTS) if all(j not in [JOINT_INDEX[n] for n in c] for c in LIMB_CHAINS.values())]
    torso_frames = frames_of(torso)
    assert all(len(f) == 1 for f in torso_frames)
    moved = 0
    for chain in LIMB_CHAINS.values():
        limb_frames = frames_of([JOINT_INDEX[n] for n in chain])
        assert all(len(f) == 1 for f in limb_frames)  # the whole chain from one frame
        moved += sum(lf != tf for lf, tf in zip(limb_frames, torso_frames, strict=True))
    assert moved > 0.8 * 4 * 64  # donors are random frames: almost always another one
    _, p_world = forward_kinematics(b.R_local, b.J_rest, b.transl)
    torch.testing.assert_close(b.p_world, p_world)
    plain = PoseSampler(ds, bm, batch_size=16, generator=torch.Generator().manual_seed(4)).sample()
    zero = PoseSampler(ds, bm, batch_size=16, generator=torch.Generator().manual_seed(4), part_swap=0.0).sample()
    assert torch.equal(plain.R_local, zero.R_local) and torch.equal(plain.p_world, zero.p_world)
    with pytest.raises(ValueError, match="part_swap must be a probability"):
        PoseSampler(ds, bm, batch_size=4, generator=torch.Generator(), part_swap=1.5)
