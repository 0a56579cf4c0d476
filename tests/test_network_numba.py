"""The network as one numba kernel (smplik.network_numba) and the solver's small-batch path through it.

The kernel is the network's function in float32, like the ONNX graph: it must agree with the torch network
(the reference) within 1e-5 for every effector type, tolerance, padding, body and gender, for any batch (the
chunks of a large batch spread over threads give the same answer bit for bit), and the solver must use it
only for calls of at most SMALL_TOKENS effector tokens (rows x effectors).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from helpers import SHIPPED, needs_ort, needs_shipped, random_effectors

from smplik.network import NetworkConfig, ProtoResIK
from smplik.onnx_runtime import OUTPUT_NAMES

pytest.importorskip("numba", reason="numba not installed (pip install 'smplik[fast]')")

from smplik.network_numba import CHUNK_ROWS, NumbaNetwork  # noqa: E402


def _arrays(eff, betas, gender):
    return [t.numpy() for t in (eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas, gender)]


@pytest.fixture(scope="module", params=[NetworkConfig(width=48, encoder_blocks=3, decoder_blocks=2,
                                                      layers_per_block=2),
                                        NetworkConfig(width=32, encoder_blocks=1, decoder_blocks=1,
                                                      layers_per_block=3)],
                ids=["3-2-2", "1-1-3"])
def model(bodies, request):
    torch.manual_seed(0)
    return ProtoResIK(request.param, bodies.J_template, bodies.J_dirs).eval()


@pytest.mark.slow
@pytest.mark.parametrize(("B", "N"), [(1, 1), (1, 8), (4, 3), (8, 12), (2 * CHUNK_ROWS + 5, 6)])
def test_kernel_is_the_network(model, bodies, B, N):
    eff, betas, gender = random_effectors(bodies, B, N, seed=B * 7 + N)
    with torch.inference_mode():
        ref = model(eff, betas, gender)
    out = NumbaNetwork(model).run_arrays(*_arrays(eff, betas, gender))
    for name, got in zip(OUTPUT_NAMES, out, strict=True):
        want = getattr(ref, name).numpy()
        assert got.dtype == np.float32 and got.shape == want.shape, name
        assert np.abs(got - want).max() < 1e-5, f"{name}: max diff {np.abs(got - want).max():.2e}"


def test_threads_give_the_same_answer_and_calls_like_the_network(model, bodies):
    eff, betas, gender = random_effectors(bodies, 3 * CHUNK_ROWS + 1, 5, seed=3)
    one = NumbaNetwork(model)
    a = one.run_arrays(*_arrays(eff, betas, gender))
    b = one.with_threads(2).run_arrays(*_arrays(eff, betas, gender))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    out = one(eff, betas, gender)  # tensors in, IKOutput out
    assert all(torch.equal(getattr(out, name), torch.from_numpy(x)) for name, x in zip(OUTPUT_NAMES, a, strict=True))


def test_unsupported_networks_are_refused(bodies):
    slots = ProtoResIK(NetworkConfig(width=16, encoder_blocks=1, decoder_blocks=1, effector_slots=True),
                       bodies.J_template, bodies.J_dirs)
    with pytest.raises(ValueError, match="effector_slots"):
        NumbaNetwork(slots)
    with pytest.raises(ValueError, match="threads must be >= 1"):
        NumbaNetwork(ProtoResIK(dataclasses.replace(NetworkConfig(width=16)), bodies.J_template, bodies.J_dirs),
                     threads=0)


@pytest.mark.slow
@needs_ort
@needs_shipped
def test_solver_runs_small_calls_in_the_kernel_and_large_ones_in_onnxruntime(monkeypatch):
    from smplik import network_numba, onnx_runtime
    from smplik.solver import IKSolver

    solver = IKSolver.load(SHIPPED)  # runtime "auto": the shipped graph, and the kernel for small calls
    assert isinstance(solver.network, onnx_runtime.OnnxNetwork)
    assert isinstance(solver.network.small, NumbaNetwork)
    plain = IKSolver.load(SHIPPED, runtime="onnx", small_batches=False)
    assert plain.network.small is None
    seen: list[str] = []
    kernel, session = network_numba.NumbaNetwork.run_arrays, onnx_runtime.OnnxNetwork._run_chunk
    monkeypatch.setattr(network_numba.NumbaNetwork, "run_arrays",
                        lambda self, *a: seen.append("kernel") or kernel(self, *a))
    monkeypatch.setattr(onnx_runtime.OnnxNetwork, "_run_chunk",
                        lambda self, a, into=None: seen.append("onnx") or session(self, a, into))
    small = onnx_runtime.SMALL_TOKENS
    for B, N in ((1, 8), (1, small), (1, small + 1), (2, small // 2), (3, small // 2)):
        eff, betas, gender = random_effectors(solver.bodies, B, N, seed=B * 100 + N)
        seen.clear()
        fast = solver.solve_tensors(eff, betas, gender)
        assert seen == (["kernel"] if B * N <= small else ["onnx"]), (B, N, seen)
        seen.clear()
        ref = plain.solve_tensors(eff, betas, gender)
        assert seen == ["onnx"]
        for name in OUTPUT_NAMES:
            assert torch.allclose(getattr(fast, name), getattr(ref, name), atol=1e-4, rtol=0), name
