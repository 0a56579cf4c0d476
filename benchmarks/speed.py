"""Solver speed: single-solve latency, batched throughput, and the optimization baseline, in one run.

``python benchmarks/speed.py [--checkpoint FILE] [--data CACHE]`` prints a table and writes
benchmarks/results/speed.json. Measured for the packaged model (or ``--checkpoint``):

* ``solve_tensors`` (no validation) twice: ``network`` (network + FK, ``refine=NO_REFINEMENT``) and
  ``refined`` (the solver's default: network, then 3 Levenberg-Marquardt refinement steps), and the full
  ``solve()`` (validation, packing, refinement, axis-angle conversion) for one pose of 8 effectors
  given as Effector objects and as dicts, and ``solve_network`` (``solve()`` with ``refine=NO_REFINEMENT``:
  validation, packing, the network alone, conversion): p50 / p95 latency at 1 and 2 torch threads;
* ``network`` and ``refined`` throughput (poses/s) at batch 1, 16, 256, 1024, 4096, and
  ``solve_batch()`` at 256;
* the same ``network``/``refined``/``solve`` rows with the network run by onnxruntime
  (``IKSolver.load(runtime="onnx")``, :mod:`smplik.onnx_runtime`; keys prefixed ``onnx_``), when
  onnxruntime is installed: ``--onnx FILE`` (default: exported in memory). As in the solver, calls of at
  most 16 effector tokens then run in the numba kernel (:mod:`smplik.network_numba`) when numba is installed, and
  large batches as 128-row chunks over the threads; the one-pose latency rows prefixed ``onnx_session_``
  run every call through the onnxruntime session instead (``small_batches=False``);
* ``onnx_intraop_network@2/bB`` (B >= 256): the same graph in a plain onnxruntime session with two intra-op
  threads, called once on the whole batch: the comparison for the chunks;
* the refinement alone (:func:`smplik.refine.refine_output` on the network's output), ``"reference"``
  (torch) against ``"fast"`` (numba, :mod:`smplik.refine_fast`; when numba is installed) at batch 1 and
  1024, at 1 and 2 threads (``refinement`` in the JSON; ``refine_backend`` says which one the solver rows
  above ran);
* the optimization-IK baseline (:class:`smplik.benchmark.OptimizationIK`, default iterations) per
  solve: one pose alone, and per pose within a batch of 256, at 1 and 2 threads.

Run it on an otherwise idle machine: a second busy process makes the 2-thread numbers meaningless
(the load average at start is saved with the results).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save, time_call  # noqa: E402

from smplik.benchmark import BenchmarkSet, OptimizationIK, PosePrior  # noqa: E402
from smplik.effectors import Effector, EffectorBatch  # noqa: E402
from smplik.kinematics import forward_kinematics  # noqa: E402
from smplik.onnx_runtime import CHUNK_ROWS, INPUT_NAMES, onnxruntime_available  # noqa: E402
from smplik.paths import pose_cache  # noqa: E402
from smplik.refine import NO_REFINEMENT, numba_available, refine_output, resolve_backend  # noqa: E402
from smplik.rotations import axis_angle_to_matrix  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402

N_EFFECTORS = 8
BATCHES = (1, 16, 256, 1024, 4096)
TARGETS = {"network_single_p50_ms_1thread": 0.3, "solve_single_p50_ms_1thread": 1.0,
           "network_b1024_poses_per_s_2threads": 50_000, "refined_b1024_poses_per_s_2threads": 15_000}
"""Issue 15's targets (8 effectors; single: one thread; batched: 2 threads, batch 1024)."""


def example_inputs(solver: IKSolver, batch: int, seed: int = 0):
    """Effectors from random plausible poses: 4 limb positions + pelvis rotation + head look-at + 2 positions."""
    g = torch.Generator().manual_seed(seed)
    aa = torch.randn(batch, 24, 3, generator=g) * 0.25
    R_local = axis_angle_to_matrix(aa)
    betas = torch.randn(batch, 10, generator=g)
    gender = torch.randint(0, 3, (batch,), generator=g)
    J_rest = solver.bodies.rest_joints(betas, gender)
    R_world, p_world = forward_kinematics(R_local, J_rest, torch.randn(batch, 3, generator=g) * 0.3)
    joints = torch.tensor([20, 21, 7, 8, 0, 15, 12, 4])
    kinds = torch.tensor([0, 0, 0, 0, 1, 2, 0, 0])
    rows = torch.arange(batch)[:, None]
    p, R = p_world[rows, joints], R_world[rows, joints]
    data = torch.cat([p, torch.zeros_like(p)], -1)
    data[:, 4] = torch.cat([R[:, 4, :, 0], R[:, 4, :, 1]], -1)
    data[:, 5] = torch.cat([p[:, 5] + 2.0 * R[:, 5, :, 2], torch.tensor([0.0, 0.0, 1.0]).expand(batch, 3)], -1)
    eff = EffectorBatch(joints.expand(batch, -1).clone(), kinds.expand(batch, -1).clone(), data,
                        torch.zeros(batch, N_EFFECTORS), torch.ones(batch, N_EFFECTORS, dtype=torch.bool))
    return eff, betas, gender, R_local, p_world


def to_effectors(eff: EffectorBatch, row: int = 0) -> list[Effector]:
    out = []
    for j, t, d in zip(eff.joint[row].tolist(), eff.type[row].tolist(), eff.data[row].double().numpy(), strict=True):
        if t == 0:
            out.append(Effector.position(j, d[:3]))
        elif t == 1:
            c0, c1 = d[:3], d[3:]
            out.append(Effector.rotation(j, np.stack([c0, c1, np.cross(c0, c1)], axis=1)))
        else:
            out.append(Effector.look_at(j, d[:3], d[3:]))
    return out


def intra_op_runner(model: bytes, threads: int, eff: EffectorBatch, betas: torch.Tensor, gender: torch.Tensor):
    """A call of a plain onnxruntime session (``intra_op_num_threads=threads``) on the whole batch at once,
    the comparison for :class:`~smplik.onnx_runtime.OnnxNetwork`'s chunks spread over Python threads."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.log_severity_level = 3
    session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    feeds = dict(zip(INPUT_NAMES, (eff.joint.numpy(), eff.type.numpy(), eff.data.numpy(), eff.tolerance.numpy(),
                                   eff.mask.numpy(), betas.numpy(), gender.numpy()), strict=True))
    return lambda: session.run(None, feeds)


def percentiles(times: list[float]) -> dict[str, float]:
    ms = np.asarray(times) * 1e3
    return {"p50_ms": float(np.percentile(ms, 50)), "p95_ms": float(np.percentile(ms, 95)), "calls": len(ms)}



def _print_table(title: str, rows: dict, columns: list[tuple[str, str, int, str]], note: str = "") -> None:
    """One table: ``title`` then the column headers, one row per key of ``rows`` (name, then each column's value)."""
    print(f"{title:<28}" + "".join(f"{head:>{width}}" for head, _, width, _ in columns) + note)
    for k, v in rows.items():
        print(f"{k:<28}" + "".join(f"{v[key]:>{width}{fmt}}" for _, key, width, fmt in columns))

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default=None, help="Model file (default: the packaged model).")
    parser.add_argument("--data", default=str(pose_cache()),
                        help="Pose cache whose train split fits the optimization baseline's prior "
                             "(default: $SMPLIK_POSE_CACHE, else <cache>/cmu30.npz; a generic prior is used if it "
                             "is missing).")
    parser.add_argument("--min-time", type=float, default=1.0, help="Seconds per latency measurement.")
    parser.add_argument("--onnx", default=None, help="ONNX file of the model (`smplik export-model --onnx`; "
                                                     "default: exported in memory).")
    parser.add_argument("--batches", default=",".join(map(str, BATCHES)),
                        help="Comma-separated batch sizes of the throughput rows (256 and 1024 are always measured).")
    parser.add_argument("--note", default="", help="Free text saved with the results (e.g. how busy the machine was).")
    parser.add_argument("--name", default="speed", help="Results file benchmarks/results/NAME.json (default speed).")
    args = parser.parse_args()
    batches = sorted({256, 1024, *(int(b) for b in args.batches.split(","))})

    load_at_start = os.getloadavg()
    solver = IKSolver.load(args.checkpoint, runtime="torch")
    onnx_solver = IKSolver.load(args.checkpoint, runtime="onnx", onnx_file=args.onnx) if onnxruntime_available() \
        else None
    session_solver = IKSolver.load(args.checkpoint, runtime="onnx", onnx_file=args.onnx, small_batches=False) \
        if onnx_solver is not None else None
    if onnx_solver is None:
        print("onnxruntime is not installed: no onnx_* rows (pip install 'smplik[fast]').")

    def backends(threads: int) -> list[tuple[str, IKSolver]]:
        """("", torch solver) and ("onnx_", the onnxruntime solver with ``threads`` threads)."""
        if onnx_solver is None:
            return [("", solver)]
        return [("", solver), ("onnx_", dataclasses.replace(onnx_solver,
                                                           network=onnx_solver.network.with_threads(threads)))]

    by_threads = {threads: backends(threads) for threads in (1, 2)}
    eff1, betas1, gender1, _, _ = example_inputs(solver, 1)
    objects = to_effectors(eff1)
    dicts = [e.to_dict() for e in objects]
    beta_np, gender_name = betas1[0].numpy().astype(np.float64), ["neutral", "male", "female"][int(gender1[0])]

    latency: dict[str, dict] = {}
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for prefix, sv in by_threads[threads]:
            latency[f"{prefix}network@{threads}"] = percentiles(time_call(
                lambda sv=sv: sv.solve_tensors(eff1, betas1, gender1, refine=NO_REFINEMENT), min_time=args.min_time,
                warmup=20))
            latency[f"{prefix}refined@{threads}"] = percentiles(time_call(
                lambda sv=sv: sv.solve_tensors(eff1, betas1, gender1), min_time=args.min_time, warmup=20))
            latency[f"{prefix}solve_effectors@{threads}"] = percentiles(time_call(
                lambda sv=sv: sv.solve(objects, betas=beta_np, gender=gender_name), min_time=args.min_time,
                warmup=20))
            net_only = dataclasses.replace(sv, refine=NO_REFINEMENT)
            latency[f"{prefix}solve_network@{threads}"] = percentiles(time_call(
                lambda sv=net_only: sv.solve(objects, betas=beta_np, gender=gender_name), min_time=args.min_time,
                warmup=20))
            if prefix and session_solver is not None:
                session = dataclasses.replace(session_solver, network=session_solver.network.with_threads(threads))
                latency[f"onnx_session_network@{threads}"] = percentiles(time_call(
                    lambda sv=session: sv.solve_tensors(eff1, betas1, gender1, refine=NO_REFINEMENT),
                    min_time=args.min_time, warmup=20))
                latency[f"onnx_session_solve_effectors@{threads}"] = percentiles(time_call(
                    lambda sv=session: sv.solve(objects, betas=beta_np, gender=gender_name), min_time=args.min_time,
                    warmup=20))
            if not prefix:
                latency[f"solve_dicts@{threads}"] = percentiles(time_call(
                    lambda: solver.solve(dicts, betas=beta_np, gender=gender_name), min_time=args.min_time,
                    warmup=20))

    throughput: dict[str, dict] = {}
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for batch in batches:
            eff, betas, gender, _, _ = example_inputs(solver, batch, seed=batch)
            for (prefix, sv), (name, refine) in itertools.product(
                    by_threads[threads], (("network", NO_REFINEMENT), ("refined", None))):
                times = time_call(lambda eff=eff, betas=betas, gender=gender, refine=refine, sv=sv: sv.solve_tensors(
                    eff, betas, gender, refine=refine), min_time=args.min_time, warmup=2)
                med = statistics.median(times)
                throughput[f"{prefix}{name}@{threads}/b{batch}"] = {"median_ms": med * 1e3,
                                                                     "poses_per_s": batch / med}
        if onnx_solver is not None and threads > 1:  # the plain way: one call, onnxruntime's intra-op threads
            for batch in (b for b in batches if b >= 2 * CHUNK_ROWS):
                run = intra_op_runner(onnx_solver.network.model_bytes, threads, *example_inputs(solver, batch,
                                                                                                 seed=batch)[:3])
                med = statistics.median(time_call(run, min_time=args.min_time, warmup=2))
                throughput[f"onnx_intraop_network@{threads}/b{batch}"] = {"median_ms": med * 1e3,
                                                                          "poses_per_s": batch / med}
        eff, betas, gender, _, _ = example_inputs(solver, 256, seed=256)
        lists = [to_effectors(eff, r) for r in range(256)]
        b_np = betas.numpy().astype(np.float64)
        g_names = [["neutral", "male", "female"][int(g)] for g in gender]
        for prefix, sv in by_threads[threads]:
            times = time_call(lambda lists=lists, b_np=b_np, g_names=g_names, sv=sv: sv.solve_batch(
                lists, betas=b_np, gender=g_names), min_time=args.min_time, warmup=2)
            med = statistics.median(times)
            throughput[f"{prefix}solve_batch@{threads}/b256"] = {"median_ms": med * 1e3, "poses_per_s": 256 / med}

    refinement: dict[str, dict] = {}
    refine_backends = ("reference", "fast") if numba_available() else ("reference",)
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for batch in (1, 1024):
            eff, betas, gender, _, _ = example_inputs(solver, batch, seed=batch)
            with torch.inference_mode():
                net = solver.solve_tensors(eff, betas, gender, refine=NO_REFINEMENT)
                J_rest = solver.model.rest_joints(betas, gender)
            for backend in refine_backends:
                def refine(net=net, J_rest=J_rest, eff=eff, backend=backend):
                    with torch.inference_mode():
                        return refine_output(net, J_rest, eff, solver.refine, backend=backend)

                times = time_call(refine, min_time=args.min_time, warmup=20 if batch == 1 else 1)
                refinement[f"refine_{backend}@{threads}/b{batch}"] = {
                    **percentiles(times), "poses_per_s": batch / statistics.median(times)}
    with torch.inference_mode():
        net1 = solver.solve_tensors(eff1, betas1, gender1, refine=NO_REFINEMENT)
        refine_backend_used = resolve_backend(net1, solver.model.rest_joints(betas1, gender1))

    try:
        from smplik.data.dataset import load_cache

        prior = PosePrior.fit(load_cache(args.data).subset("train").pose)
        prior_source = args.data
    except (FileNotFoundError, ValueError):
        prior = PosePrior(torch.tensor([1.0, 0, 0, 0, 1.0, 0]).repeat(24, 1), torch.full((24, 6), 0.3))
        prior_source = "generic (identity mean, std 0.3)"
    optim = OptimizationIK(solver.bodies, prior)
    optim_rows = {}
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for batch in (1, 256):
            eff, betas, gender, R_local, p_world = example_inputs(solver, batch, seed=7)
            bset = BenchmarkSet("speed", "random", N_EFFECTORS, R_local, torch.zeros(batch, 3), betas, gender,
                                p_world, eff)
            times = []
            for _ in range(3 if batch == 1 else 1):
                t0 = time.perf_counter()
                optim(bset)
                times.append(time.perf_counter() - t0)
            optim_rows[f"optim@{threads}/b{batch}"] = {"ms_per_pose": statistics.median(times) * 1e3 / batch,
                                                       "iterations": optim.iterations}

    summary = {
        "network_single_solve_p50_ms_1thread": latency["network@1"]["p50_ms"],
        "refined_single_solve_p50_ms_1thread": latency["refined@1"]["p50_ms"],
        "full_solve_p50_ms_1thread": latency["solve_effectors@1"]["p50_ms"],
        "network_best_poses_per_s": max(v["poses_per_s"] for k, v in throughput.items() if k.startswith("network")),
        "refined_best_poses_per_s": max(v["poses_per_s"] for k, v in throughput.items() if k.startswith("refined")),
        "optim_ms_per_single_solve_1thread": optim_rows["optim@1/b1"]["ms_per_pose"],
    }
    for backend in refine_backends:
        summary[f"refine_{backend}_single_p50_ms_1thread"] = refinement[f"refine_{backend}@1/b1"]["p50_ms"]
        summary[f"refine_{backend}_b1024_ms_2threads"] = refinement[f"refine_{backend}@2/b1024"]["p50_ms"]
    prefixes = ["", "onnx_"] if onnx_solver is not None else [""]
    for prefix in prefixes:
        summary[f"{prefix}network_single_p50_ms_1thread"] = latency[f"{prefix}network@1"]["p50_ms"]
        summary[f"{prefix}refined_single_p50_ms_1thread"] = latency[f"{prefix}refined@1"]["p50_ms"]
        summary[f"{prefix}solve_single_p50_ms_1thread"] = latency[f"{prefix}solve_effectors@1"]["p50_ms"]
        summary[f"{prefix}solve_network_single_p50_ms_1thread"] = latency[f"{prefix}solve_network@1"]["p50_ms"]
        for name in ("network", "refined"):
            summary[f"{prefix}{name}_b1024_poses_per_s_2threads"] = throughput[f"{prefix}{name}@2/b1024"][
                "poses_per_s"]
            for threads in (1, 2):
                summary[f"{prefix}{name}_speedup_single_{threads}thread"] = (
                    optim_rows[f"optim@{threads}/b1"]["ms_per_pose"] / latency[f"{prefix}{name}@{threads}"]["p50_ms"])
                summary[f"{prefix}{name}_speedup_batched_256_{threads}thread"] = (
                    optim_rows[f"optim@{threads}/b256"]["ms_per_pose"]
                    * throughput[f"{prefix}{name}@{threads}/b256"]["poses_per_s"] / 1e3)
    targets = {}
    for key, target in TARGETS.items():
        measured = {"onnx" if p else "torch": summary[p + key] for p in prefixes}
        met = {rt: v <= target if key.endswith("_ms_1thread") else v >= target for rt, v in measured.items()}
        targets[key] = {"target": target, "measured": measured, "met": met}
    _print_table("measurement", latency, [("p50 ms", "p50_ms", 10, ".3f"), ("p95 ms", "p95_ms", 10, ".3f")])
    per_s = ("poses/s", "poses_per_s", 12, ".0f")
    print()
    _print_table("throughput", throughput, [("median ms", "median_ms", 10, ".2f"), per_s])
    print()
    _print_table("refinement alone", refinement, [("p50 ms", "p50_ms", 10, ".3f"), per_s],
                 note=f"   (solver rows ran: {refine_backend_used})")
    print()
    _print_table("optimization baseline", optim_rows, [("ms/pose", "ms_per_pose", 10, ".2f")])
    print("\nsummary:", {k: round(v, 3) for k, v in summary.items()})
    print("targets:", targets)
    path = save(args.name, {"checkpoint": solver.source, "step": solver.meta.get("step"),
                          "network": solver.meta.get("network"), "effectors_per_pose": N_EFFECTORS,
                          "refine": solver.refine.to_dict(), "refine_backend": refine_backend_used,
                          "latency": latency, "throughput": throughput, "refinement": refinement,
                          "optimization": optim_rows,
                          "optim_prior": prior_source, "summary": summary, "targets": targets,
                          "onnx": None if onnx_solver is None else {
                              "file": onnx_solver.network.source, "opset": onnx_solver.network.meta.get("opset"),
                              "small_batch_kernel": type(onnx_solver.network.small).__name__
                              if onnx_solver.network.small is not None else None,
                              "chunk_rows": CHUNK_ROWS,
                              "onnxruntime": __import__("onnxruntime").__version__},
                          "note": args.note,
                          "load_average_at_start": load_at_start, "load_average_at_end": os.getloadavg()})
    print("wrote", path)


if __name__ == "__main__":
    main()
