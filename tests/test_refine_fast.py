"""The fast (numba) refinement backend (smplik.refine_fast) against the torch reference (smplik.refine)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from smplik.conventions import PARENTS
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.refine import (
    DEFAULT_REFINEMENT,
    RefineConfig,
    refine_backend,
    refine_output,
    refine_output_reference,
    resolve_backend,
)
from smplik.rotations import axis_angle_to_matrix, geodesic_distance, matrix_to_rot6d

pytest.importorskip("numba", reason="the fast refinement backend needs numba (pip install 'smplik[fast]')")

from smplik import refine_fast  # noqa: E402

CONFIGS = (DEFAULT_REFINEMENT, RefineConfig(iterations=6, sigma_prior=2.0, damping=0.01, tolerance_eta=2.0),
           RefineConfig(sigma_prior=1.5, joint_prior=tuple(np.random.default_rng(0).uniform(0.1, 10.0, 24).tolist())))


def random_problem(B: int, N: int, seed: int, dtype: torch.dtype = torch.float64, parents: tuple[int, ...] = PARENTS
                   ) -> tuple[IKOutput, torch.Tensor, EffectorBatch]:
    """B random start poses on random skeletons and N effectors per pose of all three types, from a different
    random pose: random tolerances (half of them 0), padded rows, and targets moved out of reach in half of
    the poses (so that Levenberg-Marquardt rejects steps)."""
    g = torch.Generator().manual_seed(seed)
    J = len(parents)
    J_rest = torch.randn(B, J, 3, generator=g, dtype=torch.float64) * 0.3
    R_true = axis_angle_to_matrix(torch.randn(B, J, 3, generator=g, dtype=torch.float64) * 0.3)
    R_world_true, p_world_true = forward_kinematics(R_true, J_rest, torch.randn(B, 3, generator=g,
                                                                                dtype=torch.float64), parents)
    R_start = axis_angle_to_matrix(torch.randn(B, J, 3, generator=g, dtype=torch.float64) * 0.2) @ R_true
    transl = torch.randn(B, 3, generator=g, dtype=torch.float64)
    R_world, p_world = forward_kinematics(R_start, J_rest, transl, parents)
    joint = torch.randint(0, J, (B, N), generator=g)
    kind = torch.randint(0, 3, (B, N), generator=g)
    kind[:, :3] = torch.tensor([0, 1, 2])
    rows = torch.arange(B)[:, None]
    data = torch.zeros(B, N, 6, dtype=torch.float64)
    far = (torch.arange(B) % 2 == 1).to(torch.float64)[:, None, None]
    data[..., :3] = p_world_true[rows, joint] + far * 2.0 * torch.randn(B, N, 3, generator=g, dtype=torch.float64)
    rot, look = kind == 1, kind == 2
    data[rot] = matrix_to_rot6d(R_world_true[rows, joint][rot])
    data[..., 3:][look] = torch.nn.functional.normalize(torch.randn(int(look.sum()), 3, generator=g,
                                                                    dtype=torch.float64), dim=-1)
    tolerance = torch.rand(B, N, generator=g, dtype=torch.float64) * (torch.rand(B, N, generator=g) > 0.5)
    mask = torch.rand(B, N, generator=g) > 0.25
    mask[:, :3] = True
    data = data * mask[..., None]  # padding: zeros, like pack_effectors
    out = IKOutput(R_start.to(dtype), R_world.to(dtype), p_world.to(dtype), p_world.to(dtype), transl.to(dtype))
    return out, J_rest.to(dtype), EffectorBatch(joint, kind, data.to(dtype), tolerance.to(dtype), mask)


def assert_same_refinement(a: IKOutput, b: IKOutput, rot_tol: float = 1e-5, m_tol: float = 1e-6) -> None:
    assert float(geodesic_distance(a.R_local.double(), b.R_local.double()).max()) <= rot_tol
    assert float(geodesic_distance(a.R_world.double(), b.R_world.double()).max()) <= rot_tol
    assert float((a.p_world.double() - b.p_world.double()).abs().max()) <= m_tol
    assert float((a.transl.double() - b.transl.double()).abs().max()) <= m_tol


@pytest.mark.parametrize("cfg", CONFIGS, ids=["default", "loose-prior", "per-joint-prior"])
@pytest.mark.parametrize("B", [1, 48])
def test_fast_equals_reference(cfg, B):
    out, J_rest, eff = random_problem(B, 9, seed=B)
    reference = refine_output(out, J_rest, eff, cfg, backend="reference")
    fast = refine_output(out, J_rest, eff, cfg, backend="fast")
    assert float((reference.p_world - out.p_world).abs().max()) > 0.01  # the refinement did move the poses
    assert_same_refinement(fast, reference)
    assert fast.draft is out.draft


def test_fast_equals_reference_where_steps_are_rejected():
    """Out-of-reach targets: the reference rejects some steps (an iterate repeats bit for bit); fast agrees."""
    out, J_rest, eff = random_problem(32, 8, seed=5)
    cfg = CONFIGS[1]
    one = refine_output_reference(out, J_rest, eff, RefineConfig(**{**cfg.to_dict(), "iterations": 1}))
    two = refine_output_reference(out, J_rest, eff, RefineConfig(**{**cfg.to_dict(), "iterations": 2}))
    kept = (one.R_local == two.R_local).flatten(1).all(1)
    moved = (one.R_local != out.R_local).flatten(1).any(1)
    assert bool((kept & moved).any()) and not bool(kept.all()), "the problem should mix accepted and rejected steps"
    for iterations in (1, 2, 4):
        c = RefineConfig(**{**cfg.to_dict(), "iterations": iterations})
        assert_same_refinement(refine_output(out, J_rest, eff, c, backend="fast"), refine_output_reference(
            out, J_rest, eff, c))


def test_another_skeleton():
    """The kernel takes any tree (its ancestor chains are built per parent tuple)."""
    parents = (-1, 0, 1, 2, 0, 4, 1, 6, 7, 7)
    out, J_rest, eff = random_problem(12, 6, seed=8, parents=parents)
    cfg = CONFIGS[1]
    assert_same_refinement(refine_output(out, J_rest, eff, cfg, parents, backend="fast"),
                           refine_output_reference(out, J_rest, eff, cfg, parents))


def test_float32_network_output_keeps_its_dtype_and_matches():
    out, J_rest, eff = random_problem(16, 8, seed=2, dtype=torch.float32)
    fast = refine_output(out, J_rest, eff, backend="fast")
    assert fast.R_local.dtype == fast.transl.dtype == torch.float32
    assert_same_refinement(fast, refine_output_reference(out, J_rest, eff), rot_tol=1e-5, m_tol=1e-5)


def test_padding_rows_change_nothing():
    """Appending masked rows (any content) gives the same refinement as without them."""
    out, J_rest, eff = random_problem(6, 5, seed=9)
    extra = 3
    padded = EffectorBatch(torch.cat([eff.joint, torch.randint(0, 24, (6, extra))], 1),
                           torch.cat([eff.type, torch.randint(0, 3, (6, extra))], 1),
                           torch.cat([eff.data, torch.randn(6, extra, 6, dtype=torch.float64)], 1),
                           torch.cat([eff.tolerance, torch.zeros(6, extra, dtype=torch.float64)], 1),
                           torch.cat([eff.mask, torch.zeros(6, extra, dtype=torch.bool)], 1))
    assert_same_refinement(refine_output(out, J_rest, padded, backend="fast"),
                           refine_output(out, J_rest, eff, backend="fast"), rot_tol=1e-9, m_tol=1e-10)


def test_threaded_chunks_equal_one_chunk_bit_for_bit():
    out, J_rest, eff = random_problem(4 * refine_fast.CHUNK_MIN + 7, 8, seed=11)
    arrays = [np.ascontiguousarray(t.numpy()) for t in (out.R_local, out.R_world, out.p_world, out.transl, J_rest,
                                                        eff.joint, eff.type, eff.data, eff.tolerance, eff.mask)]
    one = refine_fast.refine_arrays(*arrays, PARENTS, DEFAULT_REFINEMENT, threads=1)
    four = refine_fast.refine_arrays(*arrays, PARENTS, DEFAULT_REFINEMENT, threads=4)
    for a, b in zip(one, four, strict=True):
        assert np.array_equal(a, b)


def test_non_finite_poses_keep_their_iterate_without_raising():
    out, J_rest, eff = random_problem(4, 8, seed=4)
    R_local = out.R_local.clone()
    R_local[1, 5] = float("nan")
    transl = out.transl.clone()
    transl[2, 0] = float("inf")
    bad = IKOutput(R_local, out.R_world, out.p_world, out.p_world, transl)
    fast = refine_output(bad, J_rest, eff, backend="fast")
    reference = refine_output_reference(bad, J_rest, eff)
    for b in (1, 2):  # never a step from a non-finite state: the input pose comes back as it was
        assert torch.equal(fast.R_local[b].nan_to_num(7.0), bad.R_local[b].nan_to_num(7.0))
        assert torch.equal(fast.transl[b].nan_to_num(7.0), bad.transl[b].nan_to_num(7.0))
        assert torch.equal(reference.R_local[b].nan_to_num(7.0), bad.R_local[b].nan_to_num(7.0))
    finite = [0, 3]
    assert_same_refinement(IKOutput(*(t[finite] for t in (fast.R_local, fast.R_world, fast.p_world, fast.draft,
                                                           fast.transl))),
                           IKOutput(*(t[finite] for t in (reference.R_local, reference.R_world, reference.p_world,
                                                           reference.draft, reference.transl))))


def test_zero_iterations_return_the_input():
    out, J_rest, eff = random_problem(2, 4, seed=1)
    assert refine_output(out, J_rest, eff, RefineConfig(iterations=0), backend="fast") is out


def test_backend_selection():
    out, J_rest, eff = random_problem(2, 4, seed=1)
    assert resolve_backend(out, J_rest) == "fast"
    assert resolve_backend(out, J_rest, "reference") == "reference"
    with refine_backend("reference"):
        assert resolve_backend(out, J_rest) == "reference"
    assert resolve_backend(out, J_rest) == "fast"
    with pytest.raises(ValueError, match="Unknown refinement backend 'numpy'"):
        resolve_backend(out, J_rest, "numpy")  # type: ignore[arg-type]
    meta = IKOutput(*(torch.empty(t.shape, device="meta") for t in (out.R_local, out.R_world, out.p_world,
                                                                    out.draft, out.transl)))
    assert resolve_backend(meta, J_rest.to("meta")) == "reference"
    with pytest.raises(ValueError, match="fast refinement backend cannot run: its inputs are not on the CPU"):
        resolve_backend(meta, J_rest.to("meta"), "fast")
    # autograd: "auto" runs the differentiable reference, "fast" refuses in one line
    R_local = out.R_local.clone().requires_grad_(True)
    grad_out = IKOutput(R_local, out.R_world, out.p_world, out.draft, out.transl)
    assert resolve_backend(grad_out, J_rest) == "reference"
    refine_output(grad_out, J_rest, eff).p_world.sum().backward()
    assert R_local.grad is not None and bool(torch.isfinite(R_local.grad).all())
    with pytest.raises(ValueError, match="fast refinement backend cannot run: its inputs need gradients"):
        refine_output(grad_out, J_rest, eff, backend="fast")


def test_solver_runs_the_fast_backend(shipped_solver, monkeypatch):
    """``IKSolver.solve`` goes through refine_output's fast path when numba is installed."""
    calls = []
    original = refine_fast.refine_arrays

    def counting(*args, **kwargs):
        calls.append(args[0].shape[0])
        return original(*args, **kwargs)

    monkeypatch.setattr(refine_fast, "refine_arrays", counting)
    shipped_solver.solve([{"joint": "left_wrist", "type": "position", "value": [0.3, 0.9, 0.2]},
                          {"joint": "head", "type": "look_at", "target": [0.0, 1.5, 2.0]}])
    assert calls == [1]
    with refine_backend("reference"):
        shipped_solver.solve([{"joint": "left_wrist", "type": "position", "value": [0.3, 0.9, 0.2]}])
    assert calls == [1]


def test_read_only_install_compiles_without_a_cache(monkeypatch):
    """No writable cache directory anywhere (numba: "no locator available"): kernels still compile and run."""
    import numba.core.caching as caching

    def unwritable(self):
        raise OSError("read-only file system")

    monkeypatch.setattr(caching._CacheLocator, "ensure_cache_path", unwritable)

    def add_one(x):
        return x + 1

    kernel = refine_fast._jit(add_one)
    assert kernel(1) == 2
    assert type(kernel._cache).__name__ == "NullCache"


def test_joint_prior_config_round_trip_and_validation():
    cfg = RefineConfig(sigma_prior=1.5, joint_prior=[1.0, 2] + [0.5] * 22)
    assert cfg.joint_prior == (1.0, 2.0, *([0.5] * 22))
    assert RefineConfig.from_dict(cfg.to_dict()) == cfg
    np.testing.assert_array_equal(DEFAULT_REFINEMENT.joint_prior_array(24), np.ones(24))
    with pytest.raises(ValueError, match="joint_prior must be a list of finite numbers > 0"):
        RefineConfig(joint_prior=[1.0] * 23 + [0.0])
    with pytest.raises(ValueError, match="joint_prior has 3 values for a skeleton of 24 joints"):
        RefineConfig(joint_prior=[1.0, 1.0, 1.0]).joint_prior_array(24)
    with pytest.raises(ValueError, match=r"model.pt: refine: unknown key\(s\) \['sigma'\]"):
        RefineConfig.from_dict({"sigma": 1.0}, "model.pt: refine")


def test_joint_prior_weights_hold_joints_differently():
    """A joint whose prior weight is 100x the others' moves far less from the network's answer (both backends)."""
    out, J_rest, eff = random_problem(8, 8, seed=5)
    heavy = [1.0] * 24
    heavy[3] = 100.0
    for backend in ("reference", "fast"):
        moved = {}
        for name, cfg in (("uniform", DEFAULT_REFINEMENT), ("heavy", RefineConfig(joint_prior=heavy))):
            res = refine_output(out, J_rest, eff, cfg, backend=backend)
            moved[name] = float(geodesic_distance(res.R_local[:, 3], out.R_local[:, 3]).mean())
        assert moved["heavy"] < 0.2 * moved["uniform"], (backend, moved)
