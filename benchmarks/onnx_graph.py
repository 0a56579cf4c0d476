"""The exported ONNX graph: node counts, one-pose latency, batch-1024 throughput and the GEMM roofline, in one run.

``python benchmarks/onnx_graph.py [--baseline OLD.onnx]`` exports the packaged model's network + FK (the graph
of :class:`smplik.network_folded.FoldedProtoResIK`) and, when given, measures a baseline file of the same weights
(e.g. exported by an earlier commit) side by side, interleaved so that both see the same machine load:

* nodes of the file and after onnxruntime's graph optimisation (``ORT_ENABLE_ALL``);
* one pose of 8 effectors, 1 thread: ``session.run`` and ``IKSolver.solve_tensors(refine=NO_REFINEMENT)``
  (the issue-15 "network alone" measurement), p50 of wall time and of the thread's CPU time (the CPU time
  is what another busy process on the machine disturbs least);
* batch 1024: poses/s at 1 thread (wall and CPU time) and 2 threads (wall);
* the roofline: multiply-adds per pose of the network's layers (8 effectors) and onnxruntime's measured
  GEMM rate on a token layer's shape (8192 x 128 x 128, 1 and 2 threads), i.e. the poses/s that the
  matrix products alone would allow.

Writes benchmarks/results/onnx_graph.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402
from speed import N_EFFECTORS, example_inputs  # noqa: E402

from smplik.network_folded import FoldedProtoResIK  # noqa: E402
from smplik.onnx_runtime import INPUT_NAMES, OUTPUT_NAMES, OnnxNetwork, export_onnx_bytes  # noqa: E402
from smplik.refine import NO_REFINEMENT  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402


def node_counts(model: bytes) -> dict[str, int]:
    import onnx
    import onnxruntime as ort

    with tempfile.TemporaryDirectory() as tmp:
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.optimized_model_filepath = str(Path(tmp) / "optimised.onnx")
        options.log_severity_level = 3
        ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
        optimised = len(onnx.load(options.optimized_model_filepath).graph.node)
    return {"nodes": len(onnx.load_from_string(model).graph.node), "nodes_optimised": optimised}


def timed(fn, calls: int) -> tuple[list[float], list[float]]:
    """Wall and thread-CPU seconds of ``calls`` calls."""
    wall, cpu = [], []
    for _ in range(calls):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    return wall, cpu


def interleaved(fns: dict, rounds: int, calls: int) -> dict[str, dict[str, list[float]]]:
    out = {k: {"wall": [], "cpu": []} for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            fn()
            wall, cpu = timed(fn, calls)
            out[k]["wall"] += wall
            out[k]["cpu"] += cpu
    return out


def gemm_rate(threads: int) -> float:
    """onnxruntime GFLOP/s of a token layer, (8192 x 128) @ (128 x 128) + bias, ReLU."""
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    M, K, N = 8192, 128, 128
    g = np.random.default_rng(0)
    nodes = [helper.make_node("Gemm", ["x", "W", "b"], ["y"]), helper.make_node("Relu", ["y"], ["z"])]
    graph = helper.make_graph(nodes, "gemm", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [M, K])],
                              [helper.make_tensor_value_info("z", TensorProto.FLOAT, [M, N])],
                              [numpy_helper.from_array(g.random((K, N), np.float32), "W"),
                               numpy_helper.from_array(np.zeros(N, np.float32), "b")])
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.log_severity_level = 3
    sess = ort.InferenceSession(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 15)])
                                .SerializeToString(), options, providers=["CPUExecutionProvider"])
    feed = {"x": g.random((M, K), np.float32)}
    wall, _ = timed(lambda: sess.run(None, feed), 3)
    wall, _ = timed(lambda: sess.run(None, feed), 40)
    return 2 * M * K * N / float(np.median(wall)) / 1e9


def macs_per_pose(folded: FoldedProtoResIK, tokens: int) -> dict[str, int]:
    """Multiply-adds of the folded network's matrix products for one pose of ``tokens`` effectors."""
    def layers(block):
        return [*block.layers, *([block.skip] if block.skip is not None else [])]

    encoder = tokens * (folded.W_token.numel() + sum(m.weight.numel() for b in folded.encoder for m in layers(b))) + \
        sum(b.forward_out.weight.numel() for b in folded.encoder)
    decoders = sum(p.numel() for p in [*folded.gpd_first, *folded.ikd_first]) + sum(
        m.weight.numel() for blocks in (folded.gpd, folded.ikd) for b in blocks for m in [*layers(b), b.forward_out])
    return {"encoder": encoder, "decoders": decoders, "total": encoder + decoders}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=None, help="An .onnx file of the same model to compare with.")
    parser.add_argument("--rounds", type=int, default=20, help="Interleaved rounds of the one-pose measurement.")
    parser.add_argument("--note", default="", help="Free text saved with the results.")
    args = parser.parse_args()
    load_at_start = os.getloadavg()
    torch.set_num_threads(1)
    solver = IKSolver.load()
    graphs = {"current": export_onnx_bytes(solver.model)}
    if args.baseline:
        graphs["baseline"] = Path(args.baseline).read_bytes()
    nets = {k: OnnxNetwork(b, threads=1) for k, b in graphs.items()}
    for net in nets.values():
        if net.fingerprint != nets["current"].fingerprint:
            raise SystemExit(f"--baseline {args.baseline}: exported from other weights than the packaged model.")
    solvers = {k: dataclasses.replace(solver, network=net) for k, net in nets.items()}
    result: dict = {k: node_counts(b) for k, b in graphs.items()}

    eff, betas, gender, _, _ = example_inputs(solver, 1)
    feed = {n: t.numpy() for n, t in zip(INPUT_NAMES, (eff.joint, eff.type, eff.data, eff.tolerance, eff.mask,
                                                       betas, gender), strict=True)}
    fns = {}
    for k, net in nets.items():
        fns[f"{k}/session.run"] = lambda s=net.session: s.run(OUTPUT_NAMES, feed)
        fns[f"{k}/network"] = lambda sv=solvers[k]: sv.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT)
    single = interleaved(fns, args.rounds, 100)
    eff, betas, gender, _, _ = example_inputs(solver, 1024, seed=1024)
    batch1 = interleaved({k: lambda sv=sv: sv.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT)
                          for k, sv in solvers.items()}, 4, 3)
    solvers2 = {k: dataclasses.replace(sv, network=sv.network.with_threads(2)) for k, sv in solvers.items()}
    batch2 = interleaved({k: lambda sv=sv: sv.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT)
                          for k, sv in solvers2.items()}, 4, 3)
    for k in graphs:
        result[k]["single_ms_1thread"] = {
            name: {"p50_wall": float(np.median(v["wall"])) * 1e3, "p50_cpu": float(np.median(v["cpu"])) * 1e3}
            for name, v in ((m, single[f"{k}/{m}"]) for m in ("session.run", "network"))}
        result[k]["b1024_poses_per_s"] = {
            "1thread_wall": 1024 / float(np.median(batch1[k]["wall"])),
            "1thread_cpu": 1024 / float(np.median(batch1[k]["cpu"])),
            "2threads_wall": 1024 / float(np.median(batch2[k]["wall"]))}
    macs = macs_per_pose(FoldedProtoResIK(solver.model), N_EFFECTORS)
    rates = {threads: gemm_rate(threads) for threads in (1, 2)}
    result["roofline"] = {"macs_per_pose": macs, "mflop_per_pose": 2 * macs["total"] / 1e6,
                          "gemm_gflops": {f"{t}thread{'s' if t > 1 else ''}": r for t, r in rates.items()},
                          "gemm_bound_poses_per_s": {f"{t}thread{'s' if t > 1 else ''}": r * 1e9 / (2 * macs["total"])
                                                     for t, r in rates.items()}}
    for k in graphs:
        r = result[k]
        one = r["single_ms_1thread"]
        print(f"{k:9s} nodes {r['nodes']:4d} (optimised {r['nodes_optimised']:3d})  one pose, 1 thread: session.run "
              f"{one['session.run']['p50_wall']:.3f} ms (cpu {one['session.run']['p50_cpu']:.3f}), network "
              f"{one['network']['p50_wall']:.3f} ms (cpu {one['network']['p50_cpu']:.3f});  b1024 poses/s: "
              + ", ".join(f"{n} {v:.0f}" for n, v in r["b1024_poses_per_s"].items()))
    print("roofline:", result["roofline"])
    print("wrote", save("onnx_graph", {**result, "baseline_file": args.baseline, "effectors_per_pose": N_EFFECTORS,
                                        "note": args.note, "load_average_at_start": load_at_start,
                                        "load_average_at_end": os.getloadavg()}))


if __name__ == "__main__":
    main()
