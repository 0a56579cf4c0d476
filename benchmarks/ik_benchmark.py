"""IK accuracy benchmark: make the files (if absent) and run all methods; results in benchmarks/results.

``python benchmarks/ik_benchmark.py [--data CACHE] [--files DIR] [--checkpoint FILE]`` is the same
as ``smplik benchmark make`` followed by ``smplik benchmark run --methods smplik,optim,nn,rest``;
it writes ``benchmarks/results/ik_benchmark.json`` and ``ik_benchmark.md`` (the README table).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, machine  # noqa: E402

from smplik.atomic import write_text_atomic  # noqa: E402
from smplik.benchmark import (  # noqa: E402
    MANIFEST,
    LearnedMethod,
    NearestNeighborMethod,
    OptimizationIK,
    PosePrior,
    RestPoseMethod,
    load_benchmark,
    make_benchmark,
    results_markdown,
    run_benchmark,
    save_results,
)
from smplik.body_model import BodyModelSet  # noqa: E402
from smplik.data.dataset import load_cache  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="/work/cache/cmu30.npz", help="Pose cache (test split + train split).")
    parser.add_argument("--files", default="/work/bench_files", help="Benchmark folder (made if absent).")
    parser.add_argument("--checkpoint", default=None, help="Model file (default: the packaged model).")
    parser.add_argument("--samples-per-count", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    if not (Path(args.files) / MANIFEST).is_file():
        make_benchmark(args.data, args.files, split="test", seed=args.seed, samples_per_count=args.samples_per_count)
    bench = load_benchmark(args.files)
    bodies = BodyModelSet.load()
    train_pose = load_cache(args.data).subset("train").pose
    solver = IKSolver.load(args.checkpoint)
    methods = {"smplik": LearnedMethod(solver), "optim": OptimizationIK(bodies, PosePrior.fit(train_pose)),
               "nn": NearestNeighborMethod.from_dataset(train_pose, bodies), "rest": RestPoseMethod(bodies)}
    results = run_benchmark(bench, methods, bodies, settings={
        "machine": machine(), "checkpoint": solver.source, "checkpoint_step": solver.meta.get("step"),
        "train_data": args.data}, progress=lambda m, s, r: print(f"{m:7s} {s:10s} {r.mpjpe_mm:7.1f} mm", flush=True))
    save_results(RESULTS / "ik_benchmark.json", results)
    table = results_markdown(results)
    write_text_atomic(RESULTS / "ik_benchmark.md", table)
    print(table)


if __name__ == "__main__":
    main()
