"""Effector refinement (smplik.refine): convergence, locality, tolerance, prior, config errors, solver use."""

from __future__ import annotations

from importlib import resources

import pytest
import torch

from smplik.conventions import JOINT_INDEX, EffectorType
from smplik.effectors import Effector, EffectorBatch, pack_effectors
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.refine import NO_REFINEMENT, RefineConfig, refine_output, tolerance_weight
from smplik.rotations import axis_angle_to_matrix, geodesic_distance, rot6d_to_matrix

LOOSE_PRIOR = RefineConfig(iterations=6, sigma_prior=10.0, damping=0.01)


def as_output(R_local: torch.Tensor, transl: torch.Tensor, J_rest: torch.Tensor) -> IKOutput:
    R_world, p_world = forward_kinematics(R_local, J_rest, transl)
    return IKOutput(R_local, R_world, p_world, p_world, transl)


@pytest.fixture(scope="module")
def scene(bodies):
    """A random ground-truth pose on a random body, its exact effectors, and a perturbed start."""
    g = torch.Generator().manual_seed(3)
    betas = torch.randn(1, 10, generator=g)
    gender = torch.tensor([2])
    J_rest = bodies.rest_joints(betas, gender)
    R_true = axis_angle_to_matrix(torch.randn(1, 24, 3, generator=g) * 0.3)
    transl = torch.tensor([[0.3, 0.1, -0.2]])
    truth = as_output(R_true, transl, J_rest)
    p, R = truth.p_world[0].double().numpy(), truth.R_world[0].double().numpy()
    effectors = [Effector.position(j, p[JOINT_INDEX[j]]) for j in ("left_wrist", "right_wrist", "left_ankle",
                                                                    "right_ankle")]
    effectors += [Effector.rotation("pelvis", R[0]), Effector.rotation("left_elbow", R[JOINT_INDEX["left_elbow"]])]
    head = JOINT_INDEX["head"]
    effectors.append(Effector.look_at("head", p[head] + 1.5 * R[head] @ [0.0, 0.0, 1.0], (0.0, 0.0, 1.0)))
    start = as_output(axis_angle_to_matrix(torch.randn(1, 24, 3, generator=g) * 0.1) @ R_true,
                      transl + torch.tensor([[0.05, -0.03, 0.04]]), J_rest)
    return truth, start, J_rest, pack_effectors(effectors)


def residuals(out: IKOutput, eff: EffectorBatch) -> dict[str, float]:
    """Worst position (m), rotation (rad) and look-at (rad) error of one pose's effectors."""
    k, kind = eff.joint[0], eff.type[0]
    p, R = out.p_world[0, k], out.R_world[0, k]
    pos = kind == int(EffectorType.POSITION)
    rot = kind == int(EffectorType.ROTATION)
    look = kind == int(EffectorType.LOOK_AT)
    data = eff.data[0]
    facing = (R[look] @ data[look, 3:, None])[..., 0]
    ray = data[look, :3] - p[look]
    return {"position": float((p[pos] - data[pos, :3]).norm(dim=-1).max()),
            "rotation": float(geodesic_distance(R[rot], rot6d_to_matrix(data[rot])).max()),
            "look_at": float(torch.acos(torch.nn.functional.cosine_similarity(facing, ray, dim=-1).clamp(-1, 1)).max())}


def test_exact_effectors_are_met_from_a_perturbed_start(scene):
    _, start, J_rest, eff = scene
    before = residuals(start, eff)
    assert before["position"] > 0.03 and before["rotation"] > 0.05 and before["look_at"] > 0.05
    after = residuals(refine_output(start, J_rest, eff, LOOSE_PRIOR), eff)
    assert after["position"] < 1e-4 and after["rotation"] < 1e-3 and after["look_at"] < 1e-3, after


def test_each_step_reduces_the_position_error_fast(scene):
    """Gauss-Newton with correct Jacobians: one step removes most of a small error."""
    _, start, J_rest, eff = scene
    errors = [residuals(refine_output(start, J_rest, eff, RefineConfig(iterations=i, sigma_prior=10.0,
                                                                       damping=0.01)), eff)["position"]
              for i in (0, 1, 2, 3)]
    assert errors[1] < 0.3 * errors[0] and errors[3] < errors[2] < errors[1] and errors[3] < 0.01 * errors[0], errors


def test_output_is_a_consistent_pose(scene):
    _, start, J_rest, eff = scene
    out = refine_output(start, J_rest, eff)
    R_world, p_world = forward_kinematics(out.R_local, J_rest, out.transl)
    torch.testing.assert_close(out.p_world, p_world)
    torch.testing.assert_close(out.R_world, R_world)
    eye = torch.eye(3).expand(24, 3, 3)
    torch.testing.assert_close(out.R_local[0] @ out.R_local[0].transpose(-1, -2), eye, atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.linalg.det(out.R_local[0]), torch.ones(24), atol=1e-5, rtol=0)
    assert out.R_local.dtype == start.R_local.dtype


def test_unconstrained_joints_keep_the_start_pose(scene):
    """Only a left-wrist target: the legs, right arm and head keep their local rotations exactly."""
    truth, start, J_rest, _ = scene
    eff = pack_effectors([Effector.position("left_wrist", truth.p_world[0, JOINT_INDEX["left_wrist"]].numpy())])
    out = refine_output(start, J_rest, eff)
    untouched = [JOINT_INDEX[j] for j in ("left_hip", "right_knee", "right_shoulder", "right_elbow", "head",
                                          "left_wrist", "left_hand")]
    torch.testing.assert_close(out.R_local[:, untouched], start.R_local[:, untouched], atol=1e-6, rtol=0)
    chain = [JOINT_INDEX[j] for j in ("left_shoulder", "left_elbow")]
    assert float(geodesic_distance(out.R_local[0, chain], start.R_local[0, chain]).max()) > 1e-3


def test_tolerance_weakens_the_pull(scene):
    truth, start, J_rest, _ = scene
    target = truth.p_world[0, JOINT_INDEX["left_wrist"]].numpy()
    miss = {}
    for tol in (0.0, 0.6, 1.0):
        eff = pack_effectors([Effector.position("left_wrist", target, tolerance=tol)])
        out = refine_output(start, J_rest, eff)
        miss[tol] = float((out.p_world[0, JOINT_INDEX["left_wrist"]] - torch.as_tensor(target).float()).norm())
    assert miss[0.0] < 0.005 and miss[0.0] < miss[0.6] < miss[1.0], miss
    w = tolerance_weight(torch.tensor([0.0, 0.3, 0.6, 1.0]))
    assert w[0] == 1.0 and bool((w[1:] <= w[:-1]).all()) and float(w[-1]) == pytest.approx(0.01)


def test_zero_iterations_and_masked_padding(scene):
    _, start, J_rest, eff = scene
    assert refine_output(start, J_rest, eff, NO_REFINEMENT) is start
    # the same pose padded with masked (garbage) effectors refines identically
    padded = EffectorBatch(torch.cat([eff.joint, torch.tensor([[5, 7]])], 1),
                           torch.cat([eff.type, torch.tensor([[0, 1]])], 1),
                           torch.cat([eff.data, torch.full((1, 2, 6), 3.0)], 1),
                           torch.cat([eff.tolerance, torch.zeros(1, 2)], 1),
                           torch.cat([eff.mask, torch.zeros(1, 2, dtype=torch.bool)], 1))
    torch.testing.assert_close(refine_output(start, J_rest, padded).p_world, refine_output(start, J_rest, eff).p_world)


@pytest.mark.parametrize("kwargs, message", [
    ({"iterations": -1}, "iterations"), ({"sigma_pos": 0.0}, "sigma_pos"), ({"sigma_prior": -1.0}, "sigma_prior"),
    ({"damping": -0.5}, "damping"),
])
def test_config_errors_name_the_field(kwargs, message):
    with pytest.raises(ValueError, match=message):
        RefineConfig(**kwargs)


SHIPPED = resources.files("smplik") / "checkpoints" / "smplik_cmu.pt"


@pytest.mark.skipif(not SHIPPED.is_file(), reason="shipped model smplik/checkpoints/smplik_cmu.pt absent")
def test_shipped_solver_meets_effectors_the_network_misses(shipped_solver):
    """The default solve refines the network's pose onto exact targets; iterations=0 is the network alone.

    Targets: the joints of a plausible pose (the network's answer to targets near the rest pose),
    with the hands and feet pulled 4 cm in random directions."""
    from smplik.solver import IKSolver

    solver, network = shipped_solver, IKSolver.load(refine=NO_REFINEMENT)
    g = torch.Generator().manual_seed(5)
    names = ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle", "right_ankle")
    idx = [JOINT_INDEX[n] for n in names]
    kwargs = {"betas": torch.randn(10, generator=g).numpy(), "gender": "female"}
    rest = network.model.rest_joints(torch.as_tensor(kwargs["betas"]).float()[None], torch.tensor([2]))[0, idx]
    near_rest = rest + torch.randn(6, 3, generator=g) * 0.08
    truth = network.solve([Effector.position(n, t.numpy()) for n, t in zip(names, near_rest, strict=True)],
                          **kwargs).joints[idx]
    pull = torch.nn.functional.normalize(torch.randn(6, 3, generator=g), dim=-1).double().numpy() * 0.04
    pull[:2] = 0.0
    targets = truth + pull
    effectors = [Effector.position(n, t) for n, t in zip(names, targets, strict=True)]
    refined, raw = solver.solve(effectors, **kwargs), network.solve(effectors, **kwargs)

    def miss(pose):
        return float(torch.as_tensor(pose.joints[idx] - targets).norm(dim=-1).mean())

    assert miss(raw) > 0.01 and miss(refined) < 0.003, (miss(raw), miss(refined))
    with torch.inference_mode():
        model_out = network.model(pack_effectors(effectors), torch.as_tensor(kwargs["betas"]).float()[None],
                                  torch.tensor([2]))
    torch.testing.assert_close(torch.as_tensor(raw.joints).float(), model_out.p_world[0], atol=1e-5, rtol=0)


def test_without_numba_auto_runs_the_reference(scene, monkeypatch):
    """No numba installed: "auto" falls back to the torch reference; "fast" names the missing package."""
    import smplik.refine as refine

    _, start, J_rest, eff = scene
    monkeypatch.setattr(refine, "numba_available", lambda: False)
    assert refine.resolve_backend(start, J_rest) == "reference"
    torch.testing.assert_close(refine_output(start, J_rest, eff).R_local,
                               refine.refine_output_reference(start, J_rest, eff).R_local, atol=0, rtol=0)
    with pytest.raises(ValueError, match=r'numba is not installed \(pip install -e "\.\[fast\]" in the smplik'):
        refine_output(start, J_rest, eff, backend="fast")
