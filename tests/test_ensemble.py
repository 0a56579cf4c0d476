"""Test-time ensemble (smplik/ensemble.py): the copies' effectors, the way back, and the equivariance
it gives the shipped solver."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from smplik.conventions import LEFT_RIGHT
from smplik.effectors import EffectorBatch
from smplik.ensemble import NO_ENSEMBLE, EnsembleConfig, augment_effectors, combine_outputs
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.refine import NO_REFINEMENT
from smplik.rotations import axis_angle_to_matrix, matrix_to_rot6d
from smplik.symmetry import mirror_pose, rotate_about_vertical

JOINTS = torch.tensor([20, 21, 7, 8, 0, 15, 12, 4, 16])
TYPES = torch.tensor([0, 0, 0, 0, 1, 2, 0, 1, 2])


DIRECTION = (0.3, -0.2, 0.9)


def _effectors_of(R_local, transl, J_rest, joints=JOINTS, types=TYPES, direction=DIRECTION) -> EffectorBatch:
    """Exact effectors of a pose: positions, world rotations (6D) and look-ats 1.5 m along a local axis."""
    R_world, p_world = forward_kinematics(R_local, J_rest, transl)
    B = R_local.shape[0]
    rows = torch.arange(B)[:, None]
    j = joints.expand(B, -1)
    p, R = p_world[rows, j], R_world[rows, j]
    direction = torch.tensor(direction, dtype=p.dtype)
    direction = direction / direction.norm()
    pos = torch.cat([p, torch.zeros_like(p)], -1)
    rot = matrix_to_rot6d(R)
    look = torch.cat([p + 1.5 * (R @ direction), direction.expand_as(p)], -1)
    t = types.expand(B, -1)[..., None]
    data = torch.where(t == 0, pos, torch.where(t == 1, rot, look))
    N = joints.shape[0]
    return EffectorBatch(j.clone(), types.expand(B, -1).clone(), data, torch.zeros(B, N, dtype=p.dtype),
                         torch.ones(B, N, dtype=torch.bool))


def _random_pose(B: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    R_local = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g, dtype=torch.float64) * 0.4)
    transl = torch.randn(B, 3, generator=g, dtype=torch.float64)
    return R_local, transl


@pytest.mark.parametrize("cfg", [EnsembleConfig(mirror=True), EnsembleConfig(yaw=3),
                                 EnsembleConfig(yaw=4, mirror=True)])
def test_copies_are_the_effectors_of_the_transformed_pose_and_combine_undoes_them(bodies, cfg):
    """Each copy's effectors equal the exact effectors of the mirrored/turned pose; a network that answers
    every copy exactly is mapped back to the original pose by combine_outputs."""
    B = 3
    R_local, transl = _random_pose(B)
    J_rest = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    eff = _effectors_of(R_local, transl, J_rest)
    copies = augment_effectors(eff, cfg)
    assert copies.joint.shape == (cfg.size * B, JOINTS.shape[0])
    answers = []
    for k in range(cfg.size):
        mirrored, turn = k >= cfg.yaw, 2 * np.pi * (k % cfg.yaw) / cfg.yaw
        R_k, t_k = (mirror_pose(R_local, transl, J_rest[:, 0]) if mirrored else (R_local, transl))
        R_k, t_k = rotate_about_vertical(R_k, t_k, torch.full((B,), turn, dtype=torch.float64), J_rest[:, 0])
        joints = torch.tensor(LEFT_RIGHT)[JOINTS] if mirrored else JOINTS
        sl = slice(k * B, (k + 1) * B)
        # the joint's frame is mirrored too, so a mirrored look-at direction is M d
        direction = (-DIRECTION[0], *DIRECTION[1:]) if mirrored else DIRECTION
        expected = _effectors_of(R_k, t_k, J_rest, joints, direction=direction)
        torch.testing.assert_close(copies.joint[sl], expected.joint)
        torch.testing.assert_close(copies.data[sl], expected.data, atol=1e-9, rtol=0)
        R_world_k, p_world_k = forward_kinematics(R_k, J_rest, t_k)
        answers.append(IKOutput(R_k, R_world_k, p_world_k, p_world_k, t_k))
    stacked = IKOutput(*(torch.cat([getattr(a, f.name) for a in answers]) for f in dataclasses.fields(IKOutput)))
    back = combine_outputs(stacked, J_rest, cfg)
    torch.testing.assert_close(back.R_local, R_local, atol=1e-9, rtol=0)
    torch.testing.assert_close(back.transl, transl, atol=1e-9, rtol=0)
    _, p_world = forward_kinematics(R_local, J_rest, transl)
    torch.testing.assert_close(back.p_world, p_world, atol=1e-9, rtol=0)
    torch.testing.assert_close(back.draft, p_world, atol=1e-9, rtol=0)


def test_mirror_ensemble_makes_the_shipped_network_exactly_mirror_equivariant(shipped_solver, bodies):
    """Alone, the network answers a mirrored problem only roughly with the mirrored pose; with the mirror
    ensemble (whose copies are closed under mirroring) the answers agree to float precision."""
    B = 4
    R_local, transl = _random_pose(B, seed=1)
    J_rest = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    R_m, t_m = mirror_pose(R_local, transl, J_rest[:, 0])
    eff = _effectors_of(R_local.float(), transl.float(), J_rest.float())
    eff_m = augment_effectors(eff, EnsembleConfig(mirror=True))
    eff_m = EffectorBatch(*(getattr(eff_m, f)[B:] for f in ("joint", "type", "data", "tolerance", "mask")))
    betas, gender = torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)

    def gap(ens):
        a = shipped_solver.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT, ensemble=ens)
        b = shipped_solver.solve_tensors(eff_m, betas, gender, refine=NO_REFINEMENT, ensemble=ens)
        R_back, _ = mirror_pose(b.R_local, b.transl, J_rest[:, 0].float())
        return float((R_back - a.R_local).abs().max())

    assert gap(NO_ENSEMBLE) > 1e-2
    assert gap(EnsembleConfig(mirror=True)) < 1e-4


def test_ensemble_parse_and_bad_values():
    assert EnsembleConfig.parse("none") == NO_ENSEMBLE
    assert EnsembleConfig.parse("mirror+yaw4") == EnsembleConfig(yaw=4, mirror=True)
    assert EnsembleConfig.parse("yaw2").size == 2 and EnsembleConfig.parse("mirror").size == 2
    with pytest.raises(ValueError, match="Unknown ensemble 'flip'"):
        EnsembleConfig.parse("flip")
    with pytest.raises(ValueError, match=r"yaw must be an integer in \[1, 64\]"):
        EnsembleConfig(yaw=0)


def test_solver_ensemble_lowers_error_on_its_own_problems(shipped_solver, bodies):
    """On exact effectors of random plausible poses, the mirror ensemble is at least as close to the truth
    as the network alone (geodesic error of the local rotations, 64 poses)."""
    B = 64
    R_local, transl = _random_pose(B, seed=2)
    R_local = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=torch.Generator().manual_seed(3),
                                               dtype=torch.float64) * 0.2)
    J_rest = bodies.rest_joints(torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)).double()
    eff = _effectors_of(R_local.float(), transl.float(), J_rest.float())
    betas, gender = torch.zeros(B, 10), torch.zeros(B, dtype=torch.long)

    def geodesic(ens):
        out = shipped_solver.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT, ensemble=ens)
        M = out.R_local.double() @ R_local.transpose(-1, -2)
        return float(torch.arccos(((M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)).mean())

    assert geodesic(EnsembleConfig(mirror=True)) < geodesic(NO_ENSEMBLE)


def test_cli_solve_ensemble_option(tmp_path, shipped_solver):
    import json

    from typer.testing import CliRunner

    from smplik.cli.main import app as cli

    eff = tmp_path / "e.json"
    eff.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "left_wrist", "type": "position", "value": [0.5, 1.2, 0.1]},
        {"joint": "head", "type": "look_at", "target": [0, 1.6, 2.0], "direction": [0, 0, 1]}]}))
    res = CliRunner().invoke(cli, ["solve", str(eff), "--out", str(tmp_path / "p.json"), "--ensemble", "flip"])
    assert res.exit_code != 0 and "Unknown ensemble 'flip'" in res.output
    poses = {}
    for ens in ("none", "mirror+yaw2"):
        res = CliRunner().invoke(cli, ["solve", str(eff), "--out", str(tmp_path / f"{ens}.json"), "--ensemble", ens])
        assert res.exit_code == 0, res.output
        poses[ens] = np.asarray(json.loads((tmp_path / f"{ens}.json").read_text())["body_pose"])
    assert np.abs(poses["none"] - poses["mirror+yaw2"]).max() > 1e-3  # the ensemble changed the answer


def test_benchmark_ensemble_methods(shipped_solver, bodies):
    from smplik.benchmark import build_methods

    methods, settings = build_methods(["smplik_ens", "smplik_net_ens"], bodies, solver=shipped_solver,
                                      ensemble=EnsembleConfig(yaw=2, mirror=True))
    assert settings["ensemble"] == {"yaw": 2, "mirror": True}
    assert methods["smplik_ens"].ensemble == EnsembleConfig(yaw=2, mirror=True)
    assert methods["smplik_net_ens"].refine == NO_REFINEMENT and methods["smplik_ens"].refine is None
