"""Skeleton FK: against a naive per-joint recursion, and inverse relations; pointer-jumping composition."""

import pytest
import torch

from smplik.conventions import LEFT_RIGHT, PARENTS, tree_depth
from smplik.kinematics import _jumps, compose_to_root, forward_kinematics, global_to_local, local_to_global
from smplik.rotations import axis_angle_to_matrix


def naive_fk(R_local, J_rest, transl):
    R_world, p_world = [], []
    for j, p in enumerate(PARENTS):
        if p < 0:
            R_world.append(R_local[..., j, :, :])
            p_world.append(J_rest[..., j, :])
        else:
            R_world.append(R_world[p] @ R_local[..., j, :, :])
            offset = J_rest[..., j, :] - J_rest[..., p, :]
            p_world.append(p_world[p] + (R_world[p] @ offset[..., None])[..., 0])
    return torch.stack(R_world, -3), torch.stack(p_world, -2) + transl[..., None, :]


def test_fk_matches_naive_recursion_with_batch_broadcast():
    g = torch.Generator().manual_seed(0)
    R_local = axis_angle_to_matrix(torch.randn(3, 2, 24, 3, generator=g, dtype=torch.float64))
    J_rest = torch.randn(2, 24, 3, generator=g, dtype=torch.float64)
    transl = torch.randn(3, 2, 3, generator=g, dtype=torch.float64)
    R_w, p_w = forward_kinematics(R_local, J_rest, transl)
    R_ref, p_ref = naive_fk(R_local, J_rest.expand(3, 2, 24, 3), transl)
    torch.testing.assert_close(R_w, R_ref)
    torch.testing.assert_close(p_w, p_ref)


def test_identity_pose_gives_rest_joints():
    J_rest = torch.randn(24, 3, dtype=torch.float64)
    _, p = forward_kinematics(torch.eye(3, dtype=torch.float64).expand(24, 3, 3), J_rest)
    torch.testing.assert_close(p, J_rest)


def test_global_local_are_inverse():
    R_local = axis_angle_to_matrix(torch.randn(7, 24, 3, dtype=torch.float64))
    torch.testing.assert_close(global_to_local(local_to_global(R_local)), R_local)


def test_fk_gradients_flow():
    aa = torch.randn(2, 24, 3, dtype=torch.float64, requires_grad=True)
    _, p = forward_kinematics(axis_angle_to_matrix(aa), torch.randn(24, 3, dtype=torch.float64))
    p.square().sum().backward()
    assert torch.isfinite(aa.grad).all() and aa.grad.abs().sum() > 0


def test_tree_facts():
    assert max(tree_depth()) == 8
    assert all(LEFT_RIGHT[LEFT_RIGHT[j]] == j for j in range(24))


def _local_transforms(R_local, J_rest, transl, parents):
    """compose_to_root's input, (3, 4, J, B): [R_local | bone offset] (the root: J_rest[0] + transl)."""
    parent = torch.tensor([max(p, 0) for p in parents])
    offsets = J_rest - J_rest[..., parent, :]
    offsets[..., 0, :] = J_rest[..., 0, :] + transl
    return torch.cat([R_local, offsets[..., None]], -1).permute(2, 3, 1, 0)


def _world(T_world):
    """(3, 4, J, B) -> R_world (B, J, 3, 3), p_world (B, J, 3)."""
    T = T_world.permute(3, 2, 0, 1)
    return T[..., :3], T[..., 3]


@pytest.mark.parametrize("B", [1, 5])
def test_pointer_jumping_composition_is_fk(B):
    g = torch.Generator().manual_seed(B)
    R_local = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g, dtype=torch.float64))
    J_rest = torch.randn(B, 24, 3, generator=g, dtype=torch.float64)
    transl = torch.randn(B, 3, generator=g, dtype=torch.float64)
    T_world = compose_to_root(_local_transforms(R_local, J_rest, transl, PARENTS))
    assert T_world.shape == (3, 4, 24, B)
    R_ref, p_ref = naive_fk(R_local, J_rest, transl)
    R_world, p_world = _world(T_world)
    torch.testing.assert_close(R_world, R_ref)
    torch.testing.assert_close(p_world, p_ref)


def test_pointer_jumping_rounds_follow_depth():
    assert len(_jumps(PARENTS)) == 4  # SMPL: 9 levels, 2^4 >= 9
    chain = tuple(range(-1, 19))  # 20 joints in a line: 20 levels, 5 rounds
    assert len(_jumps(chain)) == 5
    g = torch.Generator().manual_seed(1)
    R_local = axis_angle_to_matrix(torch.randn(2, 20, 3, generator=g, dtype=torch.float64))
    J_rest = torch.randn(2, 20, 3, generator=g, dtype=torch.float64)
    zero = torch.zeros(2, 3, dtype=torch.float64)
    R_world, p_world = _world(compose_to_root(_local_transforms(R_local, J_rest, zero, chain), chain))
    R_ref, p_ref = forward_kinematics(R_local, J_rest, None, chain)
    torch.testing.assert_close(R_world, R_ref)
    torch.testing.assert_close(p_world, p_ref)
    with pytest.raises(ValueError, match=r"Invalid local transforms shape \(24, 3, 4, 2\)"):
        compose_to_root(torch.zeros(24, 3, 4, 2))
