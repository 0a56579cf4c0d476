"""ONNX export of the network + FK (smplik.onnx_runtime) and the solver's onnxruntime backend.

The exported graph is :class:`smplik.network_folded.FoldedProtoResIK`, tested here to be the network's
function (float64: to rounding; float32: within 1e-5). The round trip runs the shipped model
(smplik/checkpoints/smplik_cmu.pt) exported by the CLI (``smplik export-model --onnx``) and compares every
output with the torch network at several batch sizes and effector counts, which only works if both axes
of the graph are really dynamic.
"""

from __future__ import annotations

import copy
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import SHIPPED, needs_ort, needs_shipped, random_effectors
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from smplik.effectors import Effector, EffectorBatch
from smplik.network import NetworkConfig, ProtoResIK
from smplik.network_folded import FoldedProtoResIK
from smplik.onnx_runtime import (
    INPUT_NAMES,
    ONNX_OPSET,
    OUTPUT_NAMES,
    OnnxModelError,
    OnnxUnavailableError,
    export_onnx,
    model_fingerprint,
)
from smplik.solver import IKSolver


def _as(eff: EffectorBatch, dtype: torch.dtype) -> EffectorBatch:
    return EffectorBatch(eff.joint, eff.type, eff.data.to(dtype), eff.tolerance.to(dtype), eff.mask)


@needs_shipped
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_folded_network_is_the_network(torch_solver_plain, dtype):
    """Every fold is exact algebra: equal to rounding in float64, within 1e-5 in float32; all three genders
    (random_effectors draws them), padded rows, one to twelve effectors."""
    model = copy.deepcopy(torch_solver_plain.model).to(dtype)
    folded = FoldedProtoResIK(model)
    tol = 1e-10 if dtype == torch.float64 else 1e-5
    genders = set()
    for B, N in [(1, 1), (3, 8), (64, 12)]:
        eff, betas, gender = random_effectors(torch_solver_plain.bodies, B, N, seed=7 * B + N)
        genders |= set(gender.tolist())
        eff = _as(eff, dtype)
        with torch.inference_mode():
            ref = model(eff, betas.to(dtype), gender)
            out = folded(eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas.to(dtype), gender)
        for name, got in zip(OUTPUT_NAMES, out, strict=True):
            want = getattr(ref, name)
            assert got.shape == want.shape and got.dtype == dtype, name
            assert float((got - want).abs().max()) < tol, f"{name} (B={B}, N={N}): {float((got - want).abs().max())}"
    assert genders == {0, 1, 2}


def test_folded_slots_model_is_the_network(bodies):
    """The effector-slots extension and other block counts fold too (float64, to rounding)."""
    torch.manual_seed(0)
    model = ProtoResIK(NetworkConfig(width=32, encoder_blocks=2, decoder_blocks=4, layers_per_block=3,
                                     effector_slots=True), bodies.J_template, bodies.J_dirs).double().eval()
    folded = FoldedProtoResIK(model)
    eff, betas, gender = random_effectors(bodies, 9, 7, seed=1)
    eff = _as(eff, torch.float64)
    with torch.inference_mode():
        ref = model(eff, betas.double(), gender)
        out = folded(eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas.double(), gender)
    for name, got in zip(OUTPUT_NAMES, out, strict=True):
        torch.testing.assert_close(got, getattr(ref, name), rtol=0, atol=1e-10)


@pytest.fixture(scope="module")
def torch_solver_plain():
    return IKSolver.load(SHIPPED, runtime="torch")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The shipped model exported by ``smplik export-model --onnx`` (the CLI in process)."""
    pytest.importorskip("onnxruntime", reason="onnxruntime is not installed (pip install -e '.[fast]')")
    pytest.importorskip("onnx", reason="onnx is not installed (pip install -e '.[fast]')")
    if not SHIPPED.is_file():
        pytest.skip("shipped model smplik/checkpoints/smplik_cmu.pt absent")
    from smplik.cli.main import app

    folder = tmp_path_factory.mktemp("onnx")
    model_pt = folder / "model.pt"
    shutil.copyfile(str(SHIPPED), model_pt)
    result = CliRunner().invoke(app, ["export-model", str(model_pt), "--onnx", str(folder / "model.onnx")])
    assert result.exit_code == 0, result.output
    return model_pt, folder / "model.onnx"


@pytest.fixture(scope="module")
def torch_solver(exported):
    return IKSolver.load(exported[0], runtime="torch")


@pytest.fixture(scope="module")
def onnx_net(exported):
    from smplik.onnx_runtime import OnnxNetwork

    return OnnxNetwork(exported[1])


@needs_ort
@pytest.mark.parametrize(("B", "N"), [(1, 1), (1, 8), (5, 3), (64, 12), (200, 6), (300, 4)])
def test_round_trip_matches_torch(onnx_net, torch_solver, B, N):
    eff, betas, gender = random_effectors(torch_solver.bodies, B, N, seed=B * 100 + N)
    with torch.inference_mode():
        ref = torch_solver.model(eff, betas, gender)
        out = onnx_net(eff, betas, gender)
    for name in OUTPUT_NAMES:
        a, b = getattr(ref, name), getattr(out, name)
        assert a.shape == b.shape, name
        assert torch.allclose(a, b, atol=1e-4, rtol=0), f"{name}: max diff {float((a - b).abs().max()):.2e}"


@needs_ort
def test_graph_io_is_documented_and_dynamic(exported, onnx_net, torch_solver):
    import onnx

    proto = onnx.load(str(exported[1]))
    assert [o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")] == [ONNX_OPSET]
    sess = onnx_net.session
    inputs = {i.name: (i.shape, i.type) for i in sess.get_inputs()}
    assert tuple(inputs) == INPUT_NAMES
    assert inputs["data"] == (["batch", "effectors", 6], "tensor(float)")
    assert inputs["mask"] == (["batch", "effectors"], "tensor(bool)")
    assert inputs["joint"][1] == inputs["type"][1] == inputs["gender"][1] == "tensor(int64)"
    assert inputs["betas"] == (["batch", 10], "tensor(float)")
    outputs = {o.name: o.shape for o in sess.get_outputs()}
    assert tuple(outputs) == OUTPUT_NAMES
    assert outputs["R_world"] == ["batch", 24, 3, 3] and outputs["transl"] == ["batch", 3]
    meta = onnx_net.meta
    assert meta["format"] == "smplik-onnx" and meta["body_fingerprint"] == torch_solver.bodies.fingerprint
    assert meta["model_fingerprint"] == model_fingerprint(torch_solver.model)


def effector_lists(eff: EffectorBatch) -> list[list[Effector]]:
    """The Effector objects of each row of a packed batch (padding dropped)."""
    return [[Effector.position(int(j), d[:3].numpy()) if t == 0 else
             Effector.rotation(int(j), np.stack([d[:3], d[3:], np.cross(d[:3], d[3:])], 1)) if t == 1 else
             Effector.look_at(int(j), d[:3].numpy(), d[3:].numpy())
             for j, t, d, m in zip(eff.joint[b], eff.type[b], eff.data[b].double(), eff.mask[b], strict=True) if m]
            for b in range(eff.joint.shape[0])]


@needs_ort
def test_solver_onnx_runtime_gives_the_torch_poses(exported, torch_solver):
    solver = IKSolver.load(exported[0], runtime="onnx", onnx_file=exported[1])
    assert solver.network is not None and torch_solver.network is None
    eff, betas, gender = random_effectors(torch_solver.bodies, 6, 8, seed=3)
    lists = effector_lists(eff)
    names = ["neutral", "male", "female"]
    kwargs = {"betas": betas.double().numpy(), "gender": [names[int(g)] for g in gender]}
    ref, got = torch_solver.solve_batch(lists, **kwargs), solver.solve_batch(lists, **kwargs)
    single = solver.solve(lists[0], betas=kwargs["betas"][0], gender=kwargs["gender"][0])
    for a, b in [*zip(ref, got, strict=True), (ref[0], single)]:
        aa_a = np.concatenate([a.global_orient[None], a.body_pose])
        aa_b = np.concatenate([b.global_orient[None], b.body_pose])
        angle = (Rotation.from_rotvec(aa_a).inv() * Rotation.from_rotvec(aa_b)).magnitude()
        assert angle.max() < 1e-4
        assert np.abs(a.joints - b.joints).max() < 1e-4 and np.abs(a.transl - b.transl).max() < 1e-4


@needs_ort
def test_auto_uses_a_matching_sibling_file_only(exported, tmp_path, torch_solver):
    model_pt, model_onnx = exported
    assert IKSolver.load(model_pt, runtime="auto").network is not None  # model.onnx next to model.pt
    alone = tmp_path / "alone.pt"
    shutil.copyfile(model_pt, alone)
    assert IKSolver.load(alone, runtime="auto").network is None  # nothing derivable: torch
    # A file of other weights: auto warns and keeps torch, onnx refuses.
    other = ProtoResIK(torch_solver.model.cfg, torch_solver.bodies.J_template, torch_solver.bodies.J_dirs)
    export_onnx(other, tmp_path / "alone.onnx")
    with pytest.warns(UserWarning, match="other weights"):
        assert IKSolver.load(alone, runtime="auto").network is None
    with pytest.raises(OnnxModelError, match="exported from other weights"):
        IKSolver.load(alone, runtime="onnx")
    with pytest.raises(FileNotFoundError, match="ONNX file not found"):
        IKSolver.load(model_pt, runtime="onnx", onnx_file=tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(OnnxModelError, match="junk.onnx: not a readable ONNX model"):
        IKSolver.load(model_pt, runtime="onnx", onnx_file=tmp_path / "junk.onnx")
    with pytest.raises(ValueError, match="Unknown runtime 'gpu'"):
        IKSolver.load(model_pt, runtime="gpu")


@needs_ort
def test_onnx_without_file_exports_in_memory_and_threads_are_configurable(bodies):
    from smplik.onnx_runtime import OnnxNetwork, export_onnx_bytes

    torch.manual_seed(0)
    model = ProtoResIK(NetworkConfig(width=32, encoder_blocks=2, decoder_blocks=2, effector_slots=True),
                       bodies.J_template, bodies.J_dirs).eval()  # the slots extension exports too
    net = OnnxNetwork(export_onnx_bytes(model), threads=2)
    assert net.threads == 2 and net.with_threads(1).threads == 1
    assert net.session.get_session_options().intra_op_num_threads == 1  # threads spread chunks instead
    for B, N in ((1, 2), (9, 7)):
        eff, betas, gender = random_effectors(bodies, B, N, seed=N)
        with torch.inference_mode():
            ref, out = model(eff, betas, gender), net(eff, betas, gender)
        for name in OUTPUT_NAMES:
            assert torch.allclose(getattr(ref, name), getattr(out, name), atol=1e-4, rtol=0), name


@needs_shipped
def test_missing_onnxruntime_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import fails as if it were not installed
    with pytest.raises(OnnxUnavailableError, match=r'pip install -e "\.\[fast\]"'):
        IKSolver.load(runtime="onnx")
    assert IKSolver.load(runtime="auto").network is None  # auto falls back to torch


@needs_shipped
def test_cli_export_errors_are_one_line(tmp_path):
    from smplik.cli.main import app

    result = CliRunner().invoke(app, ["export-model", str(tmp_path / "missing.pt"), "--onnx", str(tmp_path / "m.onnx")])
    assert result.exit_code == 1 and "Model file not found" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(app, ["export-model", str(SHIPPED)])
    assert result.exit_code == 1 and "give --out FILE.pt and/or --onnx FILE.onnx" in result.output
    assert not (tmp_path / "m.onnx").exists()


@needs_ort
def test_calls_return_their_own_outputs_across_shapes_dtypes_and_threads(onnx_net, torch_solver):
    """The session's bound input buffers are reused per thread and shape: an earlier call's outputs must not
    change, other dtypes are cast, and threads do not share buffers."""
    import threading

    first = random_effectors(torch_solver.bodies, 1, 8, seed=11)
    with torch.inference_mode():
        ref = torch_solver.model(*first)
        out = onnx_net(*first)
        kept = {name: getattr(out, name).clone() for name in OUTPUT_NAMES}
        onnx_net(*random_effectors(torch_solver.bodies, 1, 8, seed=12))  # same shapes: same buffers
        onnx_net(*random_effectors(torch_solver.bodies, 4, 3, seed=13))  # other shapes: rebound
        eff, betas, gender = first
        cast = onnx_net(EffectorBatch(eff.joint.int(), eff.type, eff.data.double(), eff.tolerance.double(), eff.mask),
                        betas.double(), gender.int())
    for name in OUTPUT_NAMES:
        assert torch.equal(getattr(out, name), kept[name]), name
        assert torch.allclose(getattr(out, name), getattr(ref, name), atol=1e-4, rtol=0), name
        assert torch.allclose(getattr(cast, name), kept[name], atol=1e-6, rtol=0), name
    agree: dict[int, bool] = {}

    def work(i: int) -> None:
        inputs = random_effectors(torch_solver.bodies, 3, 5, seed=20 + i)
        with torch.inference_mode():
            want = torch_solver.model(*inputs).p_world
            agree[i] = all(torch.allclose(onnx_net(*inputs).p_world, want, atol=1e-4) for _ in range(30))

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert agree == {0: True, 1: True, 2: True, 3: True}


@needs_ort
def test_large_batches_run_in_chunks_over_threads_with_the_same_answer(onnx_net, torch_solver, monkeypatch):
    """A batch of 2 * CHUNK_ROWS rows or more is cut into CHUNK_ROWS-row session calls (the last one shorter),
    spread over the threads; the answer is the one-call answer bit for bit, whatever the thread count."""
    from smplik import onnx_runtime

    B = 2 * onnx_runtime.CHUNK_ROWS + 37
    eff, betas, gender = random_effectors(torch_solver.bodies, B, 7, seed=5)
    arrays = [t.numpy() for t in (eff.joint, eff.type, eff.data, eff.tolerance, eff.mask, betas, gender)]
    whole = onnx_net._run_chunk(arrays)  # one session call of all B rows
    two = onnx_net.with_threads(2)
    calls: list[tuple[int, str]] = []
    run_chunk = onnx_runtime.OnnxNetwork._run_chunk

    def spy(self, chunk, into=None):
        import threading

        calls.append((chunk[0].shape[0], threading.current_thread().name))
        return run_chunk(self, chunk, into)

    monkeypatch.setattr(onnx_runtime.OnnxNetwork, "_run_chunk", spy)
    for net in (onnx_net, two):
        calls.clear()
        outs = net.run_arrays(*arrays)
        assert sorted(n for n, _ in calls) == [37, onnx_runtime.CHUNK_ROWS, onnx_runtime.CHUNK_ROWS]
        assert len({name for _, name in calls}) == min(net.threads, 3)
        for name, got, want in zip(OUTPUT_NAMES, outs, whole, strict=True):
            assert got.shape == want.shape and np.array_equal(got, want), name
    with torch.inference_mode():
        ref = torch_solver.model(eff, betas, gender)
    assert np.allclose(outs[OUTPUT_NAMES.index("p_world")], ref.p_world.numpy(), atol=1e-4, rtol=0)


@needs_ort
def test_onnx_solves_take_the_numpy_path_and_equal_the_tensor_path(exported, torch_solver, monkeypatch):
    """With onnxruntime and the fast refinement, solve()/solve_batch() skip torch (IKSolver._solve_rows_numpy);
    the poses equal the tensor path's (solve_tensors with the reference refinement) within 1e-5."""
    from smplik.refine import numba_available, refine_backend

    if not numba_available():
        pytest.skip("the numpy path needs the fast refinement (numba)")
    solver = IKSolver.load(exported[0], runtime="onnx", onnx_file=exported[1])
    eff, betas, gender = random_effectors(torch_solver.bodies, 5, 7, seed=11)
    lists = effector_lists(eff)
    kwargs = {"betas": betas.double().numpy(), "gender": [["neutral", "male", "female"][int(g)] for g in gender]}
    calls = []
    original = IKSolver._solve_rows_numpy
    monkeypatch.setattr(IKSolver, "_solve_rows_numpy", lambda self, *a: calls.append(1) or original(self, *a))
    fast = solver.solve_batch(lists, **kwargs)
    assert calls == [1]
    with refine_backend("reference"):
        reference = solver.solve_batch(lists, **kwargs)
    assert calls == [1]  # the reference refinement goes through solve_tensors
    for a, b in zip(fast, reference, strict=True):
        angle = (Rotation.from_rotvec(np.concatenate([a.global_orient[None], a.body_pose])).inv()
                 * Rotation.from_rotvec(np.concatenate([b.global_orient[None], b.body_pose]))).magnitude()
        assert angle.max() < 1e-5
        assert np.abs(a.joints - b.joints).max() < 1e-5 and np.abs(a.transl - b.transl).max() < 1e-5


@needs_ort
def test_packaged_model_runs_its_shipped_onnx_file_by_default():
    """smplik/checkpoints/smplik_cmu.onnx is the packaged model's network (same fingerprint), so a default
    IKSolver.load() with onnxruntime installed runs it; runtime="torch" still gives the torch network."""
    onnx_file = SHIPPED.with_suffix(".onnx")
    if not (SHIPPED.is_file() and onnx_file.is_file()):
        pytest.skip("the packaged model or its .onnx file is absent")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a stale file would warn and fall back to torch
        solver = IKSolver.load()
    assert solver.network is not None and Path(solver.network.source) == onnx_file
    assert solver.network.fingerprint == model_fingerprint(solver.model)
    assert IKSolver.load(runtime="torch").network is None


def test_model_fingerprint_ignores_skeleton_noise_not_weights(torch_solver_plain):
    """A model file and its .onnx graph match on a machine whose built-in skeleton differs by
    floating-point noise (another CPU), but not once a weight or the skeleton really changes."""
    model = copy.deepcopy(torch_solver_plain.model)
    before = model_fingerprint(model)
    with torch.no_grad():
        model.J_template.add_(torch.randn_like(model.J_template) * 1e-12)
        model.J_dirs.add_(torch.randn_like(model.J_dirs) * 1e-12)
    assert model_fingerprint(model) == before
    with torch.no_grad():
        model.J_template[:, 15, 1] += 1e-3  # the head 1 mm higher
    assert model_fingerprint(model) != before
    other = copy.deepcopy(torch_solver_plain.model)
    with torch.no_grad():
        next(other.parameters()).view(-1)[0] += 1e-6
    assert model_fingerprint(other) != before
